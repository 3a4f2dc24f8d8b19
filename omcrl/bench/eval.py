"""``python -m omcrl.bench eval``: evaluation throughput against the vector env's rate.

In rounds, side by side (so whatever else the machine does weighs on every row alike), at the quick shape:

* ``(a) vec env`` — a ``cfg.rl.n_envs``-env ``make_vec_env`` stepped with a slow random walk, resets included,
  in env steps per second over all envs: what the hardware gives a batch of envs;
* ``(b) vec env+student`` — the same with the student's batched forward every vector step (lock-step batched
  evaluation could not beat it);
* for each policy (a student on a random-init frozen encoder; the privileged Hybrid APF), the same episodes
  evaluated ``in-process`` (``workers=1``) and ``parallel`` (``workers=0``: one process per core, one
  :class:`~omcrl.eval.runner.EvalPool` kept across rounds as the evaluation stage keeps it), in env steps
  per second and episodes per second; for the student also ``parallel, <k> lanes`` (``--lanes``): each worker
  steps k envs in lock-step with one batched forward per step (``evaluate(..., lanes=k)``).

Each rate is the median over rounds; ``vs_(a)`` is a row's rate over (a)'s (target >= 0.8 for ``parallel``).
Episodes reset with new layouts (and Hybrid APF plans an A* path per episode), so resets are in every rate.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from omcrl.bench import parser, write_results
from omcrl.bench.env import _walk
from omcrl.bench.rl import _vec_env_rate
from omcrl.config import Config, load_config
from omcrl.envs import make_env, make_vec_env
from omcrl.eval.runner import EvalPool, evaluate
from omcrl.models import random_encoder, save_encoder
from omcrl.models.actor_critic import ActorCritic
from omcrl.planners import make_planner
from omcrl.rl import load_policy
from omcrl.rl.policy import make_student_features, policy_payload, space_shapes


def _student_policy(cfg: Config, root: Path) -> Path:
    """A student policy file on a random-init frozen encoder (its cost does not depend on its weights)."""
    import torch

    enc = random_encoder(cfg, seed=0)
    enc_path = save_encoder(root / "encoder.pt", enc.f, enc.phi, cfg)
    env = make_env(cfg.env.scene, seed=0, config=cfg.env)
    space = env.observation_space
    env.close()
    agent = ActorCritic(make_student_features(enc_path, space), 3, cfg.rl.hidden)
    path = root / "student.pt"
    torch.save(policy_payload(agent, space_shapes(space), 0), path)
    return path


def measure(
    cfg: Config, episodes: int, rounds: int, vec_seconds: float, root: Path, lanes: Sequence[int] = (1,)
) -> list[dict]:

    student = _student_policy(cfg, root)
    enc_path = root / "encoder.pt"
    vec_steps = max(50, int(vec_seconds * 100))
    makers = {"student": lambda: load_policy(student, name="student"), "hybrid-apf": lambda: make_planner("hybrid-apf")}
    n = cfg.rl.n_envs
    vec = make_vec_env(cfg.env.scene, n, seed=0, config=cfg.env)
    vec.reset(seed=0)
    acts = np.stack([_walk(np.random.default_rng(0), 100_000)] * n, 1)
    k = 0
    rates: dict[str, list[tuple[float, float]]] = {}
    shape = {"(a) vec env": (n, 1), "(b) vec env+student": (n, 1)}  # case -> (processes, envs per process)

    def vec_block() -> float:
        nonlocal k
        steps, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < vec_seconds:
            vec.step(acts[k % len(acts)])
            k += 1
            steps += n
        return steps / (time.perf_counter() - t0)

    try:
        with EvalPool(0) as pool:
            for r in range(rounds + 1):  # round 0 warms up (worker start, first layouts) and is not counted
                row = {"(a) vec env": (vec_block(), float("nan"))}
                if r:
                    b = _vec_env_rate(cfg, vec_steps, lambda s: make_student_features(enc_path, s))
                    row["(b) vec env+student"] = (b, float("nan"))
                for name, make in makers.items():
                    modes = [("in-process", 1, 1), ("parallel", pool, 1)]
                    if name == "student":  # planners step one env per process whatever lanes says
                        modes += [(f"parallel, {m} lanes", pool, m) for m in lanes if m > 1]
                    for mode, procs, m in modes:
                        t0 = time.perf_counter()
                        df = evaluate(make(), cfg.env.scene, episodes, r, workers=procs, lanes=m, config=cfg.env)
                        dt = time.perf_counter() - t0
                        row[f"{name} {mode}"] = (float(df.steps.sum()) / dt, episodes / dt)
                        shape[f"{name} {mode}"] = (1 if procs == 1 else pool.workers, m)
                if r:
                    for case, v in row.items():
                        rates.setdefault(case, []).append(v)
    finally:
        vec.close()
    base = float(np.median([v[0] for v in rates["(a) vec env"]]))
    out = []
    for case, vs in rates.items():
        sps = float(np.median([v[0] for v in vs]))
        eps = float(np.median([v[1] for v in vs]))
        out.append(
            {
                "case": case,
                "env_steps_per_s": sps,
                "episodes_per_s": None if np.isnan(eps) else eps,
                "vs_(a)": sps / base,
                "workers": shape[case][0],
                "envs_per_worker": shape[case][1],
            }
        )
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("eval", __doc__ or "")
    ap.add_argument("--preset", default="quick", help="shape to measure at (default: quick)")
    ap.add_argument("--episodes", type=int, default=16, help="episodes per evaluation (default: 16)")
    ap.add_argument("--rounds", type=int, default=3, help="measured rounds (default: 3)")
    ap.add_argument("--vec-seconds", type=float, default=5.0, help="vector-env block per round (s)")
    ap.add_argument(
        "--lanes", default="2,4", help="comma-separated lane counts of extra 'student parallel' rows (default: 2,4)"
    )
    args = ap.parse_args(argv)
    try:
        lanes = sorted({int(k) for k in args.lanes.split(",") if k.strip()})
    except ValueError:
        ap.error(f"--lanes: expected comma-separated integers, got {args.lanes!r}")
    if any(k < 1 for k in lanes):
        ap.error(f"--lanes: lane counts must be >= 1, got {args.lanes!r}")
    cfg = load_config(args.preset)
    episodes, rounds, vec_s = (6, 1, 2.0) if args.quick else (args.episodes, args.rounds, args.vec_seconds)
    with tempfile.TemporaryDirectory(prefix="omcrl-bench-eval-") as tmp:
        rows = measure(cfg, episodes, rounds, vec_s, Path(tmp), lanes)
    write_results("eval", rows, args.out, preset=args.preset, episodes=episodes, rounds=rounds, target=0.8)
    for r in rows:
        if r["case"].startswith("student parallel"):
            print(f"# {r['case']} / vec env = {r['vs_(a)']:.2f} (target >= 0.8)")
    return 0
