"""``python -m omcrl.bench rl``: what each PPO trainer costs on top of stepping its envs.

At the quick preset's shape (64 px, ``rl.n_envs`` envs; random-init encoders and an untrained oracle of the right
shapes: costs do not depend on weights, so no pretraining is needed) it measures, in env steps per second over
all envs:

* ``(a) vec env``        bare vector-env steps with random actions (resets included);
* ``(b) env+<kind>``     the same plus the rollout's forward pass per vector step for each feature kind: the
  frozen encoder (``student``), the trainable pixel encoder and heads (``pixel``: ppo, npe), the depth encoder
  and heads (``oracle``), and the student with the oracle guide's forwards (``student+guide``, in chunks as the
  rollout runs them). This is each trainer's *limit*: stepping its envs and the forward passes it needs;
* the trainers for ``--steps`` env steps each: ``(c) student`` (oracle-guided), ``(c0) student α≡0``,
  ``(d) oracle`` (APF-guided), ``(e) ppo``, ``(f) npe`` (guided by its local APF), and with ``--threads`` ``(e1) ppo, 1
  thread`` (updates on one core, as before ``rl.update_threads``); with ``--baseline`` ``(c) before``
  (the guide evaluated every vector step instead of in chunks).

With ``--precision fp32,bf16`` every row is measured once per precision, one after the other in the same run
(``rl.precision`` and ``pretrain.precision``). Inference is fp32 in both, so the limits are the same forwards; the
trainers differ in their PPO updates.

For every trainer row: ``vs_limit`` = its rate / its (b) row; ``rollout_vs_limit`` = the rate of its
rollouts alone (Σ steps / Σ ``rollout_s``) / (b); ``update_share`` = Σ ``update_s`` / Σ (rollout_s +
update_s), the part of the run spent in PPO updates (GAE, epochs of minibatch SGD). Rates are over all updates
but the first (first calls of every kernel, page-in): ``steady_sps``; ``wall_s`` adds process start-up.
All numbers depend on what else runs on the machine: compare rows of one invocation, not across runs.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from omcrl.bench import parser, write_results
from omcrl.config import Config, load_config
from omcrl.envs import make_env, make_vec_env
from omcrl.models import random_encoder, save_encoder
from omcrl.models.actor_critic import ActorCritic
from omcrl.rl import train_oracle, train_visuomotor
from omcrl.rl.guidance import PolicyGuide
from omcrl.rl.methods import METHODS, planner_factory
from omcrl.rl.policy import (
    load_policy,
    make_oracle_features,
    make_pixel_features,
    make_student_features,
    policy_payload,
    space_shapes,
)
from omcrl.rl.rollout import GUIDE_CHUNK
from omcrl.utils.precision import section_precision
from omcrl.viz.rl import run_summary


def _vec_env_rate(cfg: Config, vec_steps: int, build: Callable[[Any], Any] | None, guide: Path | None = None) -> float:
    """Env steps/s of random-action vector steps, optionally with an agent's rollout forward per step.

    ``build``: ``single_observation_space -> FeatureExtractor``; the agent built on it runs
    ``agent.step(agent.prepare(obs))`` every vector step, exactly as the rollout does. ``guide``: an
    oracle policy file evaluated as the rollout evaluates its guide (inputs prepared every step, the network
    run once per chunk of :data:`omcrl.rl.rollout.GUIDE_CHUNK` states).
    """

    env = make_vec_env(cfg.env.scene, cfg.rl.n_envs, seed=0, config=cfg.env)
    try:
        agent = ActorCritic(build(env.single_observation_space), 3, cfg.rl.hidden).eval() if build else None
        if agent is not None:
            agent.precision = section_precision(cfg.rl)
        oracle = PolicyGuide(load_policy(guide).agent) if guide is not None else None
        every, pending = max(1, GUIDE_CHUNK // cfg.rl.n_envs), []
        rng = np.random.default_rng(0)
        obs, _ = env.reset(seed=0)
        for i in range(vec_steps + 10):  # the first 10 steps warm up (page-in, allocator)
            if i == 10:
                t0 = time.perf_counter()
            if agent is not None:
                with torch.no_grad():
                    agent.step(agent.prepare(obs))
            if oracle is not None:
                pending.append(oracle.prepare(obs))
                if len(pending) == every:
                    oracle.distribution_stored({k: torch.cat([p[k] for p in pending]) for k in pending[0]})
                    pending.clear()
            obs, *_ = env.step(rng.uniform(-1, 1, (cfg.rl.n_envs, 3)).astype(np.float32))
        return vec_steps * cfg.rl.n_envs / (time.perf_counter() - t0)
    finally:
        env.close()


def _untrained_oracle(cfg: Config, path: Path) -> Path:
    """An oracle policy file with the env's observation shapes and fresh weights."""

    env = make_env(cfg.env.scene, seed=0, config=cfg.env)
    space = env.observation_space
    env.close()
    agent = ActorCritic(make_oracle_features(space, cfg.pretrain.feature_dim, cfg.env.far), 3, cfg.rl.hidden)
    torch.save(policy_payload(agent, space_shapes(space), 0), path)
    return path


def _train_rate(label: str, limit: str, fn: Callable[[], Any]) -> dict:

    t0 = time.perf_counter()
    res = fn()
    wall = time.perf_counter() - t0
    s = run_summary(res.metrics_path)
    m = pd.read_csv(res.metrics_path)
    sps = m[m.metric == "steps_per_s"].sort_values("step")
    later = sps.iloc[1:] if len(sps) > 1 else sps
    steps = np.diff(np.concatenate([[0], sps.step.to_numpy()]))[len(sps) - len(later) :]
    steady = float(steps.sum() / (steps / later.value.to_numpy()).sum())
    roll = m[m.metric == "rollout_s"].sort_values("step").value.to_numpy()[len(sps) - len(later) :]
    upd = m[m.metric == "update_s"].sort_values("step").value.to_numpy()[len(sps) - len(later) :]
    return {
        "case": label,
        "limit": limit,
        "env_steps": int(res.steps),
        "steps_per_s": s["steps_per_s"],
        "steady_sps": steady,
        "rollout_sps": float(steps.sum() / roll.sum()),
        "update_share": float(upd.sum() / (upd.sum() + roll.sum())),
        "wall_s": wall,
    }


def measure(
    cfg: Config, steps: int, vec_steps: int, root: Path, baseline: bool = False, threads: bool = False
) -> list[dict]:
    import importlib

    rollout = importlib.import_module("omcrl.rl.rollout")  # where the runner reads GUIDE_CHUNK

    enc = random_encoder(cfg, seed=0)
    enc_path = save_encoder(root / "encoder.pt", enc.f, enc.phi, cfg)
    oracle_path = _untrained_oracle(cfg, root / "oracle.pt")
    p = cfg.pretrain
    limits = {
        "student": lambda s: make_student_features(enc_path, s),
        "pixel": lambda s: make_pixel_features(s, p.crop_to, p.feature_dim),
        "oracle": lambda s: make_oracle_features(s, p.feature_dim, cfg.env.far),
    }
    rows = [{"case": "(a) vec env", "steps_per_s": _vec_env_rate(cfg, vec_steps, None)}]
    rows += [{"case": f"(b) env+{k}", "steps_per_s": _vec_env_rate(cfg, vec_steps, b)} for k, b in limits.items()]
    guided = _vec_env_rate(cfg, vec_steps, limits["student"], oracle_path)
    rows.append({"case": "(b) env+student+guide", "steps_per_s": guided})

    def config(*extra: str) -> Config:
        prec = [f"rl.precision={cfg.rl.precision}", f"pretrain.precision={cfg.pretrain.precision}"]
        return load_config(cfg.preset, overrides=[f"results_dir={root}", f"rl.total_steps={steps}", *prec, *extra])

    run, apf = config(), planner_factory(cfg, METHODS["npe"].guide)
    rows.append(
        _train_rate(
            "(c) student",
            "student+guide",
            lambda: train_visuomotor(run, enc_path, oracle_path, name="ours", progress=False),
        )
    )
    rows.append(
        _train_rate(
            "(c0) student α≡0",
            "student",
            lambda: train_visuomotor(config("rl.alpha_schedule=none"), enc_path, None, name="noOT", progress=False),
        )
    )
    rows.append(_train_rate("(d) oracle", "oracle", lambda: train_oracle(run, progress=False)))
    rows.append(_train_rate("(e) ppo", "pixel", lambda: train_visuomotor(run, None, None, name="ppo", progress=False)))
    rows.append(
        _train_rate(
            "(f) npe",
            "pixel",
            lambda: train_visuomotor(run, None, None, name="npe", planner_factory=apf, progress=False),
        )
    )
    if threads:
        one = config("rl.update_threads=1")
        rows.append(
            _train_rate(
                "(e1) ppo, 1 update thread",
                "pixel",
                lambda: train_visuomotor(one, None, None, name="ppo1", progress=False),
            )
        )
    if baseline:
        chunk = rollout.GUIDE_CHUNK
        rollout.GUIDE_CHUNK = 1
        try:
            rows.append(
                _train_rate(
                    "(c) before",
                    "student+guide",
                    lambda: train_visuomotor(run, enc_path, oracle_path, name="before", progress=False),
                )
            )
        finally:
            rollout.GUIDE_CHUNK = chunk
    limit_sps = {r["case"].split("+", 1)[1]: r["steps_per_s"] for r in rows if r["case"].startswith("(b)")}
    base = rows[0]["steps_per_s"]
    for r in rows:
        r["vs_(a)"] = r["steps_per_s"] / base
        if "limit" in r:
            lim = limit_sps[r.pop("limit")]
            r["vs_limit"] = r["steady_sps"] / lim
            r["rollout_vs_limit"] = r.pop("rollout_sps") / lim
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("rl", __doc__ or "")
    ap.add_argument("--preset", default="quick", help="shape to measure at (default: quick)")
    ap.add_argument("--steps", type=int, default=4096, help="env steps per training run (default: 4096)")
    ap.add_argument("--vec-steps", type=int, default=400, help="vector steps for (a) and (b) (default: 400)")
    ap.add_argument("--baseline", action="store_true", help="also time (c) with the per-step guide (before)")
    ap.add_argument("--threads", action="store_true", help="also time (e) with one update thread (before)")
    ap.add_argument("--keep", default=None, help="keep the run folders here instead of a temporary folder")
    ap.add_argument(
        "--precision",
        default="fp32",
        help="comma-separated precisions measured one after the other in this run (fp32,bf16; default fp32)",
    )
    args = ap.parse_args(argv)
    steps, vec_steps = (1024, 150) if args.quick else (args.steps, args.vec_steps)
    rows = []
    for prec in args.precision.split(","):
        cfg = load_config(args.preset, overrides=[f"rl.precision={prec}", f"pretrain.precision={prec}"])
        torch.set_num_threads(cfg.rl.num_threads)
        if args.keep:
            root = Path(args.keep) / prec
            root.mkdir(parents=True, exist_ok=True)
            got = measure(cfg, steps, vec_steps, root, args.baseline, args.threads)
        else:
            with tempfile.TemporaryDirectory(prefix="omcrl-bench-rl-") as tmp:
                got = measure(cfg, steps, vec_steps, Path(tmp), args.baseline, args.threads)
        rows += [{"precision": prec, **r} for r in got]
    ratios = {f"{r['case']} {r['precision']}": round(r["vs_limit"], 3) for r in rows if "vs_limit" in r}
    write_results(
        "rl",
        rows,
        args.out,
        preset=args.preset,
        image_size=cfg.env.image_size,
        n_envs=cfg.rl.n_envs,
        train_steps=steps,
        vs_limit=ratios,
        target=0.8,
    )
    print("# trainer / its limit (target >= 0.8): " + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items()))
    return 0
