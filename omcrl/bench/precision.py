"""``python -m omcrl.bench precision``: float32 against bfloat16 autocast, unit by unit, side by side.

Every unit is timed in both precisions in interleaved rounds (fp32, bf16, fp32, bf16, ...) in one process, so the
ratio ``fp32 / bf16`` (the speed-up) is taken under the same machine load. Networks have random weights (costs do
not depend on them) and the shapes of ``--preset`` (default quick):

* ``ppo update <kind>``: one PPO update (GAE, ``rl.epochs`` epochs of minibatch SGD over ``rl.buffer_size``
  transitions) of the actor-critic on ``pixel`` features (``ppo``, ``npe``: the conv encoder is trained), the
  oracle's ``depth`` encoder, and ``frozen`` student features (``ours``, ``curl``: heads only); seconds per update;
* ``rollout forward <kind>``: 32 × ``agent.step`` on a batch of ``rl.n_envs`` observations in one autocast region
  (what a rollout does per vector step; seconds per 32), for the student with the frozen encoder's forward
  (``agent.prepare``);
* ``eval forward student``: the deterministic action of 8 observations (``eval.lanes``), s;
* ``pretrain omc`` / ``pretrain curl``: one optimisation step of the contrastive learner (batch, sequence,
  crop and d of ``pretrain``), ms.

The two inference rows force autocast on: the kit runs inference in fp32 whatever the precision, because these
rows measured bf16 slower there (``omcrl.models.actor_critic.ActorCritic``); they show what bf16 would cost.

With ``--paper`` the same units at the paper preset's shapes (224 px, crop 192, d = 384) at smaller batches
(``--paper-batch`` transitions per PPO minibatch, 2 sequences per pretraining step): their CPU per-unit cost.
"""

from __future__ import annotations

import copy
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from omcrl.bench import parser, write_results
from omcrl.config import Config, load_config
from omcrl.envs import make_env
from omcrl.models import random_encoder, save_encoder
from omcrl.models.actor_critic import ActorCritic
from omcrl.models.features import make_oracle_features, make_pixel_features, make_student_features
from omcrl.pretrain.learner import ContrastiveLearner
from omcrl.rl.ppo import Rollout, compute_gae, ppo_update
from omcrl.utils.precision import autocast, native_bf16
from omcrl.utils.runtime import cpu_count

PRECISIONS = ("fp32", "bf16")


def _space(cfg: Config) -> Any:

    env = make_env(cfg.env.scene, seed=0, config=cfg.env)
    space = env.observation_space
    env.close()
    return space


def _obs(space: Any, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` random observations of the env's shapes (uint8 frames, depth in [0, far], states)."""
    s = space.spaces
    return {
        "rgb": rng.integers(0, 256, (n, *s["rgb"].shape), dtype=np.uint8),
        "depth": rng.uniform(0.2, 8.0, (n, *s["depth"].shape)).astype(np.float32),
        "state": rng.normal(size=(n, *s["state"].shape)).astype(np.float32),
        "privileged": rng.normal(size=(n, *s["privileged"].shape)).astype(np.float32),
    }


def _agents(cfg: Config, space: Any, root: Path) -> dict[str, Any]:
    """``{kind: ActorCritic}`` with fresh weights for the three feature kinds (the frozen encoder is written to
    ``root`` and loaded as a student loads it)."""

    p = cfg.pretrain
    torch.manual_seed(0)
    enc = random_encoder(cfg, seed=0)
    enc_path = save_encoder(root / f"encoder-{cfg.preset}.pt", enc.f, enc.phi, cfg)
    return {
        "pixel": ActorCritic(make_pixel_features(space, p.crop_to, p.feature_dim), 3, cfg.rl.hidden),
        "depth": ActorCritic(make_oracle_features(space, p.feature_dim, cfg.env.far), 3, cfg.rl.hidden),
        "frozen": ActorCritic(make_student_features(enc_path, space), 3, cfg.rl.hidden),
    }


def _rollout(agent: Any, space: Any, cfg: Config, transitions: int, rng: np.random.Generator) -> Any:
    """A :class:`~omcrl.rl.ppo.Rollout` of ``transitions`` random transitions (T × n_envs) for ``agent``."""

    n = cfg.rl.n_envs
    t = max(1, transitions // n)
    stored = agent.prepare(_obs(space, t * n, rng))
    obs = {k: v.reshape(t, n, *v.shape[1:]) for k, v in stored.items()}
    z = lambda *shape: torch.zeros(t, n, *shape)  # noqa: E731
    return Rollout(
        obs=obs,
        actions=torch.randn(t, n, 3),
        log_probs=torch.randn(t, n) - 3.0,
        values=torch.randn(t, n),
        next_values=torch.randn(t, n),
        rewards=torch.randn(t, n) * 0.1,
        terminated=z(),
        ends=z(),
        valid=torch.ones(t, n),
    )


def _update(agent: Any, opt: Any, roll: Any, rl: Any) -> None:
    """One PPO update as the training loop makes it (omcrl.rl.train.train): GAE, then the minibatch epochs."""
    roll.advantages, roll.returns = compute_gae(
        roll.rewards, roll.values, roll.next_values, roll.terminated, roll.ends, float(rl.gamma), float(rl.gae_lambda)
    )
    agent.train()
    ppo_update(agent, opt, roll, rl, alpha=0.0)


ROLLOUT_BLOCK = 32


def _forced(agent: Any, fn: Callable[[], Any]) -> Any:
    """``fn()`` under autocast of ``agent.precision`` (inference is fp32 in the kit; this measures bf16's)."""

    with torch.no_grad(), autocast(agent.precision):
        return fn()


def _steps(agent: Any, batch: dict[str, np.ndarray]) -> None:
    """``ROLLOUT_BLOCK`` rollout forwards (batch ``rl.n_envs``) in one autocast region of ``agent.precision``.

    The kit runs inference in fp32 whatever the precision (the agent's own rule); this region forces bf16 on it,
    so the row measures what bf16 inference would cost: the reason for that rule."""

    with autocast(agent.precision):
        for _ in range(ROLLOUT_BLOCK):
            agent.step(agent.prepare(batch))


def _interleaved(units: dict[str, dict[str, Callable[[], Any]]], rounds: int) -> list[dict]:
    """Time every ``units[name][precision]()`` once per round, precisions alternating; median seconds per call."""
    times: dict[tuple[str, str], list[float]] = {}
    for name, fns in units.items():
        for p in PRECISIONS:
            fns[p]()  # warm-up: first calls of every kernel, page-in
        for _ in range(rounds):
            for p in PRECISIONS:
                t0 = time.perf_counter()
                fns[p]()
                times.setdefault((name, p), []).append(time.perf_counter() - t0)
    rows = []
    for name in units:
        fp, bf = (float(np.median(times[(name, p)])) for p in PRECISIONS)
        rows.append({"unit": name, "fp32_s": fp, "bf16_s": bf, "speedup": fp / bf, "rounds": rounds})
    return rows


def units(cfg: Config, root: Path, paper_batch: int | None = None) -> dict[str, dict[str, Callable[[], Any]]]:
    """The timed callables, ``{unit: {precision: fn}}``; ``paper_batch`` shrinks the PPO batch and pretraining
    batch (the paper's shapes on a CPU)."""

    rng = np.random.default_rng(0)
    space = _space(cfg)
    agents = _agents(cfg, space, root)
    rl = copy.deepcopy(cfg.rl)
    if paper_batch:
        rl.buffer_size, rl.minibatch, rl.epochs = paper_batch, paper_batch, 1
    out: dict[str, dict[str, Callable[[], Any]]] = {}
    for kind, base in agents.items():
        ppo_fns, step_fns = {}, {}
        batch = _obs(space, rl.n_envs, rng)
        for p in PRECISIONS:
            agent = copy.deepcopy(base)
            agent.precision = p
            opt = torch.optim.Adam([q for q in agent.parameters() if q.requires_grad], lr=float(rl.lr), eps=1e-5)
            roll = _rollout(agent, space, cfg, rl.buffer_size, rng)
            ppo_fns[p] = lambda agent=agent, opt=opt, roll=roll: _update(agent, opt, roll, rl)
            step_fns[p] = lambda agent=agent, batch=batch: _steps(agent, batch)
        out[f"ppo update {kind}"] = ppo_fns
        out[f"rollout forward {kind}"] = step_fns
    lanes = _obs(space, 8, rng)
    eval_fns = {}
    for p in PRECISIONS:
        agent = copy.deepcopy(agents["frozen"]).eval()
        agent.precision = p
        eval_fns[p] = lambda agent=agent: _forced(agent, lambda: agent.distribution(agent.prepare(lanes)))
    out["eval forward student (8 lanes)"] = eval_fns
    pc = copy.deepcopy(cfg.pretrain)
    if paper_batch:
        pc.batch_size = 2
    L, side = cfg.env.frame_stack, pc.crop_to
    for method in ("omc", "curl"):
        pc.method, pc.use_projection = method, method == "omc"
        fns = {}
        for p in PRECISIONS:
            torch.manual_seed(0)
            learner = ContrastiveLearner(copy.deepcopy(pc), L)
            learner.precision = p
            opt = torch.optim.Adam(learner.param_groups())
            seq = torch.randint(0, 256, (pc.batch_size, pc.seq_len, 3 * L, side, side), dtype=torch.uint8)

            def step(learner: Any = learner, opt: Any = opt, seq: torch.Tensor = seq, method: str = method) -> None:
                if method == "omc":
                    loss, _ = learner.omc_loss(seq.float())
                else:
                    flat = seq.flatten(0, 1).float()
                    loss, _ = learner.curl_loss(flat, flat.flip(0))
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                learner.momentum_update()

            fns[p] = step
        out[f"pretrain {method}"] = fns
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("precision", __doc__ or "")
    ap.add_argument("--preset", default="quick", help="shapes to measure at (default: quick)")
    ap.add_argument("--rounds", type=int, default=5, help="timed calls per unit and precision (default: 5)")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (default: one per core)")
    ap.add_argument("--paper", action="store_true", help="also the paper preset's shapes at small batches")
    ap.add_argument("--paper-batch", type=int, default=64, help="PPO transitions per update at --paper (64)")
    args = ap.parse_args(argv)

    torch.set_num_threads(args.threads or cpu_count())
    rounds = 2 if args.quick else args.rounds
    cfg = load_config(args.preset)
    with tempfile.TemporaryDirectory(prefix="omcrl-bench-precision-") as tmp:
        rows = [{"shape": args.preset, **r} for r in _interleaved(units(cfg, Path(tmp)), rounds)]
        if args.paper:
            paper = load_config("paper")
            paper_units = units(paper, Path(tmp), args.paper_batch)
            rows += [{"shape": "paper", **r} for r in _interleaved(paper_units, max(1, rounds // 2))]
    native, why = native_bf16("cpu")
    write_results(
        "precision",
        rows,
        args.out,
        preset=args.preset,
        threads=torch.get_num_threads(),
        native_bf16=native,
        detected=why,
    )
    print(f"# fp32 / bf16 time per unit (speed-up), interleaved rounds; bf16 native here: {native} ({why})")
    return 0
