"""``python -m omcrl.bench env``: render and env-step throughput.

For each image size (64 and 128 px) and scene it measures, on the same scene and camera:

* ``raw_fps`` — bare ``getCameraImage`` calls (TinyRenderer, no shadows, no segmentation);
* ``step_sps`` — ``NavEnv.step`` with one process, episode resets excluded from the clock;
* ``step_sps_with_resets`` — the same with resets (new layouts) included, what training sees;
* ``vec2_sps`` — a 2-worker ``AsyncVectorEnv`` (resets included), total env steps per second;

and the two ratios the kit is held to: ``step/raw`` (target >= 0.8 at 64 px) and ``vec2/single`` (>= 1.6,
both with resets included). Actions are a slow random walk so episodes last long enough to be typical.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import pybullet as pb

from omcrl.bench import parser, timeit, write_results
from omcrl.envs import make_env, make_vec_env


def _walk(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) smooth random actions in [-1, 1]."""
    a = np.zeros((n, 3))
    for i in range(1, n):
        a[i] = np.clip(0.9 * a[i - 1] + 0.3 * rng.normal(size=3), -1, 1)
    a[:, 0] = np.abs(a[:, 0]) * 0.6
    return a.astype(np.float32)


def measure(scene: str, size: int, seconds: float, n_vec: int = 2) -> dict:
    env = make_env(scene, seed=0, image_size=size)
    env.reset(seed=0)
    cid, proj, pos, yaw = env._client, env._proj, env._pos, env._yaw
    view = pb.computeViewMatrix(pos.tolist(), [pos[0] + np.cos(yaw), pos[1] + np.sin(yaw), pos[2]], [0, 0, 1])

    def raw() -> None:
        pb.getCameraImage(
            size,
            size,
            view,
            proj,
            renderer=pb.ER_TINY_RENDERER,
            shadow=0,
            flags=pb.ER_NO_SEGMENTATION_MASK,
            physicsClientId=cid,
        )

    raw_fps = timeit(raw, seconds)["per_s"]
    acts = _walk(np.random.default_rng(0), 100_000)
    step_time = 0.0
    reset_time = 0.0
    steps = 0
    t_end = time.perf_counter() + seconds * 2
    while time.perf_counter() < t_end:
        t0 = time.perf_counter()
        _, _, term, trunc, _ = env.step(acts[steps % len(acts)])
        step_time += time.perf_counter() - t0
        steps += 1
        if term or trunc:
            t0 = time.perf_counter()
            env.reset()
            reset_time += time.perf_counter() - t0
    env.close()
    vec = make_vec_env(scene, n_vec, seed=0, image_size=size)
    vec.reset(seed=0)
    va = np.stack([acts] * n_vec, 1)
    for i in range(20):  # warm-up
        vec.step(va[i])
    t0 = time.perf_counter()
    k = 0
    while time.perf_counter() - t0 < seconds * 2:
        vec.step(va[k % len(va)])
        k += 1
    vec_sps = k * n_vec / (time.perf_counter() - t0)
    vec.close()
    step_sps = steps / step_time
    with_resets = steps / (step_time + reset_time)
    return {
        "scene": scene,
        "px": size,
        "raw_fps": raw_fps,
        "step_sps": step_sps,
        "step_sps_with_resets": with_resets,
        f"vec{n_vec}_sps": vec_sps,
        "step/raw": step_sps / raw_fps,
        f"vec{n_vec}/single": vec_sps / with_resets,
        "reset_ms": 1e3 * reset_time / max(1, steps),
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("env", __doc__ or "")
    ap.add_argument("--scenes", default="box", help="comma-separated scenes (default: box)")
    ap.add_argument("--sizes", default="64,128", help="comma-separated image sizes (px)")
    ap.add_argument("--seconds", type=float, default=5.0, help="timing window per measurement (s)")
    args = ap.parse_args(argv)
    seconds = 1.0 if args.quick else args.seconds
    rows = []
    for scene in args.scenes.split(","):
        for size in (int(s) for s in args.sizes.split(",")):
            rows.append(measure(scene, size, seconds))
    for r in rows:
        r["reset_ms_per_step"] = r.pop("reset_ms")
    write_results("env", rows, args.out)
    return 0
