"""``python -m omcrl.bench rl``: how much PPO training costs on top of stepping the envs.

At the quick preset's shape (64 px, ``rl.n_envs`` envs, encoder of the quick ``feature_dim`` / crop; a random-
init encoder artifact, so no pretraining is needed) it measures, in env steps per second over all envs:

* ``(a) vec env``       bare ``AsyncVectorEnv`` steps with random actions (resets included);
* ``(b) env+encoder``   the same plus one batched frozen-encoder forward per vector step (the student's
  feature computation, :meth:`StudentFeatures.preprocess`);
* ``(c) student``       ``train_student`` for ``--steps`` env steps with oracle guidance (an untrained oracle of
  the right shape: the guide's cost does not depend on its weights), rollout + PPO updates;
* ``(c0) student α≡0``  the same without guidance (``rl.alpha_schedule=none``);
* ``(d) oracle``        ``train_oracle`` for ``--steps`` env steps;
* ``(c) before``        with ``--baseline``: (c) with the guide evaluated every vector step (the loop before
  the guide was batched; ``omcrl.rl.rollout.GUIDE_CHUNK = 1``).

Training throughput is taken from the run's own clock (Σ update steps / steps_per_s: rollouts and updates,
without process start-up): ``steps_per_s`` over all updates, ``steady_sps`` without the first update (first
calls of every kernel, page-in); ``wall_s`` adds start-up (worker processes, model build). The target is
(c) / (b) >= 0.7: PPO updates and bookkeeping may add at most 30 % to the unavoidable env + encoder cost.
All numbers depend on what else runs on the machine: compare rows of one invocation, not across runs.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from omcrl.bench import parser, write_results
from omcrl.config import Config, load_config


def _vec_env_rate(cfg: Config, vec_steps: int, encoder_path: Path | None) -> float:
    """Env steps/s of random-action vector steps, optionally with the student's encoder forward per step."""
    from omcrl.envs import make_vec_env
    from omcrl.rl.policy import make_student_features

    env = make_vec_env(cfg.env.scene, cfg.rl.n_envs, seed=0, config=cfg.env)
    try:
        feats = make_student_features(encoder_path, env.single_observation_space) if encoder_path else None
        rng = np.random.default_rng(0)
        obs, _ = env.reset(seed=0)
        for i in range(vec_steps + 10):  # the first 10 steps warm up (page-in, allocator)
            if i == 10:
                t0 = time.perf_counter()
            if feats is not None:
                feats.preprocess(obs)
            obs, *_ = env.step(rng.uniform(-1, 1, (cfg.rl.n_envs, 3)).astype(np.float32))
        return vec_steps * cfg.rl.n_envs / (time.perf_counter() - t0)
    finally:
        env.close()


def _untrained_oracle(cfg: Config, path: Path) -> Path:
    """An oracle policy file with the env's observation shapes and fresh weights."""
    from omcrl.envs import make_env
    from omcrl.rl.policy import make_oracle_features, policy_payload, space_shapes
    from omcrl.rl.ppo import ActorCritic

    env = make_env(cfg.env.scene, seed=0, config=cfg.env)
    space = env.observation_space
    env.close()
    agent = ActorCritic(make_oracle_features(space, cfg.pretrain.feature_dim, cfg.env.far), 3, cfg.rl.hidden)
    torch.save(policy_payload(agent, space_shapes(space), 0), path)
    return path


def _train_rate(label: str, fn: callable) -> dict:
    from omcrl.viz.rl import run_summary

    t0 = time.perf_counter()
    res = fn()
    wall = time.perf_counter() - t0
    s = run_summary(res.metrics_path)
    m = pd.read_csv(res.metrics_path)
    sps = m[m.metric == "steps_per_s"].sort_values("step")
    later = sps.iloc[1:] if len(sps) > 1 else sps
    steps = np.diff(np.concatenate([[0], sps.step.to_numpy()]))[len(sps) - len(later) :]
    steady = float(steps.sum() / (steps / later.value.to_numpy()).sum())
    return {
        "case": label,
        "env_steps": int(res.steps),
        "steps_per_s": s["steps_per_s"],
        "steady_sps": steady,
        "wall_s": wall,
    }


def measure(cfg: Config, steps: int, vec_steps: int, root: Path, baseline: bool = False) -> list[dict]:
    import importlib

    from omcrl.models import random_encoder, save_encoder
    from omcrl.rl import train_oracle, train_student

    rollout = importlib.import_module("omcrl.rl.rollout")  # where the runner reads GUIDE_CHUNK

    enc = random_encoder(cfg, seed=0)
    enc_path = save_encoder(root / "encoder.pt", enc.f, enc.phi, cfg)
    oracle_path = _untrained_oracle(cfg, root / "oracle.pt")
    rows = [
        {"case": "(a) vec env", "steps_per_s": _vec_env_rate(cfg, vec_steps, None)},
        {"case": "(b) env+encoder", "steps_per_s": _vec_env_rate(cfg, vec_steps, enc_path)},
    ]
    run = load_config(cfg.preset, overrides=[f"results_dir={root}", f"rl.total_steps={steps}"])
    unguided = load_config(
        run.preset, overrides=[f"results_dir={root}", f"rl.total_steps={steps}", "rl.alpha_schedule=none"]
    )
    rows.append(_train_rate("(c) student", lambda: train_student(run, enc_path, oracle_path, progress=False)))
    rows.append(
        _train_rate("(c0) student α≡0", lambda: train_student(unguided, enc_path, None, name="noOT", progress=False))
    )
    rows.append(_train_rate("(d) oracle", lambda: train_oracle(run, progress=False)))
    if baseline:
        chunk = rollout.GUIDE_CHUNK
        rollout.GUIDE_CHUNK = 1
        try:
            rows.append(
                _train_rate(
                    "(c) before", lambda: train_student(run, enc_path, oracle_path, name="before", progress=False)
                )
            )
        finally:
            rollout.GUIDE_CHUNK = chunk
    base = rows[1]["steps_per_s"]
    for r in rows:
        r["vs_(b)"] = r["steps_per_s"] / base
        if "steady_sps" in r:
            r["steady_vs_(b)"] = r["steady_sps"] / base
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("rl", __doc__ or "")
    ap.add_argument("--preset", default="quick", help="shape to measure at (default: quick)")
    ap.add_argument("--steps", type=int, default=4096, help="env steps per training run (default: 4096)")
    ap.add_argument("--vec-steps", type=int, default=400, help="vector steps for (a) and (b) (default: 400)")
    ap.add_argument("--baseline", action="store_true", help="also time (c) with the per-step guide (before)")
    ap.add_argument("--keep", default=None, help="keep the run folders here instead of a temporary folder")
    args = ap.parse_args(argv)
    cfg = load_config(args.preset)
    steps, vec_steps = (1024, 150) if args.quick else (args.steps, args.vec_steps)
    torch.set_num_threads(cfg.rl.num_threads)
    if args.keep:
        root = Path(args.keep)
        root.mkdir(parents=True, exist_ok=True)
        rows = measure(cfg, steps, vec_steps, root, args.baseline)
    else:
        with tempfile.TemporaryDirectory(prefix="omcrl-bench-rl-") as tmp:
            rows = measure(cfg, steps, vec_steps, Path(tmp), args.baseline)
    ratio = next(r["vs_(b)"] for r in rows if r["case"] == "(c) student")
    write_results(
        "rl",
        rows,
        args.out,
        preset=args.preset,
        image_size=cfg.env.image_size,
        n_envs=cfg.rl.n_envs,
        train_steps=steps,
        student_over_env_encoder=ratio,
        target=0.7,
    )
    print(f"# (c)/(b) = {ratio:.2f} (target >= 0.7)")
    return 0
