"""Decision latency of a deployed policy: ONNX (onnxruntime) next to torch, one CPU thread, at the model's size.

``python -m omcrl.bench deploy [--policy RUN] [--image-size 64] [--out FILE] [--quick]``

One decision = the policy's forward pass on one (RGB stack, state) observation: encoder + actor, with the
preprocessing inside (what runs on the on-board or ground computer each control tick). Both runtimes get one
intra-op thread and the same observations, interleaved in blocks so drift of the host affects both alike.
``max_vs_period`` is the slowest decision over the control period ``1 / control_hz`` (the loop's budget per tick:
it must stay well below 1; the control loop logs each tick's latency in its flight CSV).
Without ``--policy`` a fresh policy with the kit's architecture at ``--image-size`` (quick preset sizes) is
exported first; the latency does not depend on the weights.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from omcrl.bench import parser, write_results
from omcrl.config import load_config, save_config
from omcrl.deploy import OnnxPolicy, export_onnx
from omcrl.envs import make_env
from omcrl.models import ActorCritic, random_encoder, save_encoder
from omcrl.models.features import make_student_features
from omcrl.rl import load_policy
from omcrl.rl.policy import policy_payload


def _fresh_policy(root: Path, image_size: int) -> Path:
    """A run folder with an untrained ``ours``-shaped policy (random frozen encoder) at ``image_size``."""
    import torch

    crop = image_size - image_size // 8
    cfg = load_config("quick", overrides=[f"env.image_size={image_size}", f"pretrain.crop_from={image_size}",
                                          f"pretrain.crop_to={crop}"])  # fmt: skip
    enc = random_encoder(cfg, seed=0)
    enc_path = save_encoder(root / "encoder.pt", enc.f, enc.phi, cfg)
    env = make_env("box", seed=0, config=cfg.env)
    space = env.observation_space
    env.close()
    agent = ActorCritic(make_student_features(enc_path, space), 3, cfg.rl.hidden)
    run = root / "run"
    run.mkdir()
    torch.save(policy_payload(agent, {k: list(s.shape) for k, s in space.spaces.items()}, 0), run / "final.pt")
    save_config(cfg, run)
    return run


def measure(run: Path, seconds: float, blocks: int = 10) -> list[dict]:
    import torch

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:  # never write into the user's run folder
        onnx_pol = OnnxPolicy(export_onnx(run, Path(tmp) / "bench.onnx"), threads=1)
    torch_pol = load_policy(Path(run) / "final.pt")
    s = onnx_pol.spec
    rng = np.random.default_rng(0)
    obs = {
        "rgb": rng.integers(0, 256, (s["frame_stack"], 3, s["image_size"], s["image_size"]), dtype=np.uint8),
        "state": rng.normal(size=12).astype(np.float32),
    }
    times: dict[str, list[float]] = {"onnxruntime": [], "torch": []}
    fns = {"onnxruntime": lambda: onnx_pol.act(obs), "torch": lambda: torch_pol.act(obs)}
    for fn in fns.values():  # warm up
        for _ in range(20):
            fn()
    per_block = seconds / blocks / len(fns)
    for _ in range(blocks):
        for name, fn in fns.items():
            end = time.perf_counter() + per_block
            while time.perf_counter() < end:
                t0 = time.perf_counter()
                fn()
                times[name].append((time.perf_counter() - t0) * 1e3)
    rows = []
    period = 1e3 / float(s["control_hz"])
    for name, t in times.items():
        a = np.asarray(t)
        rows.append({"runtime": name, "image_size": s["image_size"], "frame_stack": s["frame_stack"],
                     "calls": len(a), "median_ms": float(np.median(a)), "p99_ms": float(np.percentile(a, 99)),
                     "max_ms": float(a.max()), "mean_ms": float(a.mean()), "period_ms": period,
                     "max_vs_period": float(a.max()) / period})  # fmt: skip
    rows[0]["speedup_vs_torch"] = rows[1]["median_ms"] / rows[0]["median_ms"]
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("deploy", __doc__.splitlines()[0])
    ap.add_argument("--policy", default=None, help="run folder or final.pt to measure (default: a fresh one)")
    ap.add_argument("--image-size", type=int, default=64, help="image size of the fresh policy (px)")
    args = ap.parse_args(argv)
    seconds = 4.0 if args.quick else 20.0
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(args.policy) if args.policy else _fresh_policy(Path(tmp), args.image_size)
        if run.is_file():
            run = run.parent
        rows = measure(run, seconds)
    write_results("deploy", rows, args.out, seconds=seconds, threads=1)
    return 0
