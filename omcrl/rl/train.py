"""PPO training runs: one training loop (:func:`train`) behind every RL method (oracle, ours, baselines).

Run folder (:mod:`omcrl.runs`) ``<run_root>/runs/rl/<method>-<key>/seed<k>/``::

    run.json         identity: method, seed, key and what the key hashes (config fields, upstream digests)
    config.yaml      resolved config (omcrl.runs.Run.write_config: its digest in run.json)
    checkpoint.pt    latest resumable state, written atomically every ``rl.checkpoint_every`` env steps:
                     model, optimizer, RNG states (tensors and plain containers: loads with weights_only=True),
                     env-step count, update index, schedule state (α, lr)
    final.pt         the trained policy (omcrl.rl.policy format); its presence = finished
    metrics.csv      tidy rows (step, metric, value)
    tb/              TensorBoard events

Step accounting: every vector step counts ``n_envs`` env steps (including next-step-autoreset dummy steps,
which are real env calls). A run performs ``ceil(total_steps / (rollout_len * n_envs))`` updates and so ends
at the same step count whether or not it was interrupted and resumed. A resumed run is *not* bit-identical to
an uninterrupted one: model, optimiser and RNG states are restored exactly, but the vector env is re-created
and reset with a new seed (``seed·1000 + 100·resumes``), so episodes after the resume differ.
"""

from __future__ import annotations

import copy
import math
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import closing, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from omcrl.config import GUIDANCE_FIELDS, Config, field_default, section_identity
from omcrl.envs import make_vec_env
from omcrl.envs.render import env_identity
from omcrl.models.actor_critic import ActorCritic
from omcrl.models.features import FeatureExtractor, IdentityFeatures
from omcrl.planners import HybridAPF
from omcrl.rl.guidance import Guide, PlannerGuide, PolicyGuide, alpha_from_config
from omcrl.rl.policy import (
    CheckpointError,
    Policy,
    load_policy,
    make_oracle_features,
    make_pixel_features,
    make_student_features,
    policy_payload,
    space_shapes,
)
from omcrl.rl.ppo import NonFiniteLossError, compute_gae, ppo_update
from omcrl.rl.rollout import Runner
from omcrl.runs import (
    Callback,
    Run,
    RunConfigMismatch,
    make_run,
    read_identity,
    read_metrics,
    rng_state,
    set_rng_state,
)
from omcrl.utils.io import file_digest, load_torch
from omcrl.utils.precision import section_precision
from omcrl.utils.runtime import cpu_count, resolve_device, seed_everything, set_threads

__all__ = [
    "Result",
    "RunConfigMismatch",
    "oracle_config",
    "oracle_run",
    "policy_run",
    "rl_identity",
    "rl_run",
    "rollout_geometry",
    "train",
    "train_oracle",
    "train_ppo",
    "train_visuomotor",
    "visuomotor_parts",
]


@dataclass
class Result:
    """What a training run produced. ``policy()`` loads the final policy for evaluation."""

    run: Run
    final_path: Path
    steps: int
    skipped: bool
    start: int = 0  # the env step this call began at: a resumed run's checkpoint step (its earlier part not timed)

    @property
    def run_dir(self) -> Path:
        return self.run.dir

    @property
    def metrics_path(self) -> Path:
        return self.run.metrics_path

    def policy(self) -> Policy:
        return load_policy(self.final_path)

    def metrics(self) -> Any:

        return read_metrics(self.metrics_path)


def rollout_geometry(rl: Any) -> tuple[int, int, int, int]:
    """``(rollout_len, env_steps_per_update, n_updates, final_step)`` for an :class:`~omcrl.config.RLConfig`."""
    n_envs = rl.n_envs
    length = rl.buffer_size // n_envs if rl.buffer_size >= n_envs else rl.horizon
    per_update = length * n_envs
    n_updates = math.ceil(rl.total_steps / per_update)
    return length, per_update, n_updates, n_updates * per_update


def rl_identity(cfg: Config, guide: str | None, **extra: Any) -> dict:
    """The identity of an RL run: the RL and env sections as the method reads them, and ``extra``.

    Both sections by :func:`~omcrl.config.section_identity` (fields off their defaults; execution-only fields
    never), precision and renderer resolved. Fields the method does not read are set to their defaults first:
    without a guide (``guide`` None, or ``alpha_schedule='none'``) the α/β fields and ``guide_std``, with
    ``alpha_schedule`` 'none'; ``guide_std`` unless the guide is a planner (``"planner"``; ``"policy"``: the
    oracle). The oracle's run passes its own config (:func:`oracle_config`: its guidance in ``rl``). ``extra``:
    upstream digests and the fields read from other sections (network sizes).
    """
    rl = cfg.rl
    unread: dict[str, Any] = {}
    if guide is None or rl.alpha_schedule == "none":
        unread = {name: field_default(rl, name) for name in GUIDANCE_FIELDS}
        unread["alpha_schedule"] = "none"
    elif guide != "planner":
        unread["guide_std"] = field_default(rl, "guide_std")
    rl_ident = section_identity(rl, precision=section_precision(rl), **unread)
    return {"rl": rl_ident, "env": env_identity(cfg.env), **extra}


def oracle_config(cfg: Config) -> Config:
    """``cfg`` as the oracle teacher trains on it (a copy): ``rl`` with the oracle's own guidance (``cfg.oracle``:
    its α schedule, β and planner std) in place of the student's, and no guidance with ``oracle.guide='none'``.

    So a change to a student's guidance (``rl.alpha_*``: the decay ablation) leaves the oracle, and the students
    that learn from it, where they were; the oracle's PPO budget and settings are ``rl``'s.
    """
    out = copy.deepcopy(cfg)
    for name in GUIDANCE_FIELDS:
        setattr(out.rl, name, getattr(cfg.oracle, name))
    if cfg.oracle.guide == "none":
        out.rl.alpha_schedule = "none"
    return out


def rl_run(cfg: Config, method: str, identity: dict) -> Run:
    """The run folder of an RL method (stage ``rl``)."""
    return make_run(cfg, "rl", method, identity)


def train(
    cfg: Config,
    *,
    run: Run,
    make_env: Callable[[int], Any],
    build_features: Callable[[Any], FeatureExtractor],
    make_guide: Callable[[Any], Guide | None] | None = None,
    overwrite: bool = False,
    progress: bool = True,
    layer_norm: bool = True,
    meta: dict | None = None,
    callbacks: Sequence[Callback] = (),
) -> Result:
    """Train (or resume, or skip) one PPO run: the one training loop behind every RL method, read top to bottom.

    Each iteration: schedules, a rollout, GAE, PPO's epochs (the guide's KL is a term of
    :func:`omcrl.rl.ppo.ppo_loss`), a log row, a checkpoint every ``rl.checkpoint_every`` env steps. The run's
    bookkeeping is not in the loop: :meth:`~omcrl.runs.Run.claimed` holds the folder and writes the config,
    :meth:`~omcrl.runs.Run.session` keeps the metrics, the progress bar, the checkpoints and the callbacks.

    Parameters
    ----------
    cfg : resolved config; ``cfg.rl`` sets PPO and guidance, ``cfg.seed`` the seed.
    run : where the run lives and what identifies it (:func:`rl_run`).
    make_env : ``seed -> vector env`` (gymnasium SyncVectorEnv/AsyncVectorEnv, ``cfg.rl.n_envs`` envs); the
        env is reset with ``seed``.
    build_features : ``single_observation_space -> FeatureExtractor``; may raise CheckpointError before
        training.
    make_guide : ``env -> guide or None``; None (or ``alpha_schedule == 'none'``) trains without the KL term.
    overwrite : delete a run folder of a different identity instead of raising RunConfigMismatch.
    layer_norm : LayerNorm on the actor/critic inputs (paper V-D); see :class:`ActorCritic`.
    meta : plain values stored in the policy file's ``meta``.
    callbacks : :class:`omcrl.runs.Callback` s, called at the start, after every update, after every checkpoint
        and at the end; one whose ``on_step`` returns False stops the run early: its last checkpoint stays, and the
        result's ``final_path`` is that checkpoint.
    """
    rl = cfg.rl
    rollout_threads = set_threads(rl.num_threads)
    update_threads = rl.update_threads or cpu_count()
    device = resolve_device(rl.device)
    if not overwrite and (done := _skipped(run)) is not None:
        return done
    ckpt, resumes, env_seed = _start(run, cfg.seed)
    length, per_update, _, final_step = rollout_geometry(rl)
    with closing(make_env(env_seed)) as env:
        agent, optimizer, guide = _learner(rl, env, build_features, make_guide, layer_norm, device)
        with run.claimed(cfg, overwrite):  # only now, with encoder, oracle and env known to fit
            step, update = _resume(run, ckpt, agent, optimizer, env_seed)
            start = step  # where this call began: a resumed run's earlier part is not timed
            runner = Runner(env, agent, guide, seed=env_seed)
            recent: deque = deque(maxlen=50)  # the last 50 episodes, for the progress bar
            with run.session(total=final_step, start=step, unit="step", progress=progress, callbacks=callbacks) as s:
                while step < final_step:
                    # Schedules: α decays from the run's start (paper Eq. 8); the learning rate linearly to 0.
                    alpha = alpha_from_config(step, rl) if guide is not None else 0.0
                    lr = rl.lr * max(0.0, 1.0 - step / max(final_step, 1))
                    for g in optimizer.param_groups:
                        g["lr"] = lr

                    # Collect: rl.buffer_size env steps; the guide is queried only while its term has weight.
                    t0 = time.perf_counter()
                    n_done = len(runner.episodes)
                    agent.eval()
                    batch = runner.collect(length, rl.horizon, use_guide=alpha > 0.0)
                    t_rollout = time.perf_counter() - t0

                    # Advantages (GAE), then the PPO epochs. The env workers sleep during the update, so the
                    # learner may use their cores (the rollout's batch-of-n_envs forwards do not gain from threads).
                    with _threads(update_threads, rollout_threads), _named_nonfinite(run):
                        batch.advantages, batch.returns = compute_gae(batch.rewards, batch.values, batch.next_values,
                            batch.terminated, batch.ends, float(rl.gamma), float(rl.gae_lambda))  # fmt: skip
                        agent.train()
                        stats = ppo_update(agent, optimizer, batch, rl, alpha=alpha, step=step)
                    before, step, update = step, step + per_update, update + 1

                    # Log: the update's losses, the schedules, speed and the episodes that ended in this rollout.
                    dt = time.perf_counter() - t0
                    eps = runner.episodes[n_done:]
                    recent.extend(eps)
                    row = {**stats, "alpha": alpha, "lr": lr, "steps_per_s": per_update / max(dt, 1e-9),
                           "rollout_s": t_rollout, "update_s": dt - t_rollout, **episode_means(eps)}  # fmt: skip
                    s.log(step, row, per_update, **_shown(recent), steps_per_s=f"{row['steps_per_s']:.0f}")

                    # Checkpoint: everything a resume needs (the env's episodes in flight excepted, see _start).
                    if s.due(before, step, rl.checkpoint_every):
                        s.checkpoint(step, {"model": agent.state_dict(), "optimizer": optimizer.state_dict(),
                                            "step": step, "update": update, "rng": rng_state(), "resumes": resumes,
                                            "schedule": {"alpha": alpha, "lr": lr}, "key": run.key})  # fmt: skip
                    if not s.keep_going(step, row):
                        break
            # Finished: the policy file; stopped early (a callback): the last checkpoint is the result.
            final = run.finish(_policy_file(run, agent, env, step, meta)) if s.ended else run.checkpoint_path
    return Result(run, final, step, False, start)


def _skipped(run: Run) -> Result | None:
    """The result of a run that is already finished (its folder holds this run's key and a verified ``final.pt``),
    else None; RunConfigMismatch when the folder holds another run."""
    run.check()
    if (final := run.finished()) is None:
        return None
    return Result(run, final, int(load_torch(final, "policy file", CheckpointError)["step"]), True)


def _start(run: Run, seed: int) -> tuple[dict | None, int, int]:
    """``(checkpoint or None, resumes, env seed)`` of a run about to train. A fresh run seeds every RNG with
    ``seed``; a resumed one gets its RNG states back from the checkpoint (:func:`_resume`). An episode in flight
    cannot be checkpointed: a resumed run restarts its envs with a seed of its own, ``seed·1000 + 100·resumes``."""
    ckpt = run.load("checkpoint", CheckpointError)
    if ckpt is None:
        seed_everything(seed)
    resumes = 0 if ckpt is None else ckpt["resumes"] + 1
    return ckpt, resumes, seed * 1000 + 100 * resumes


def _policy_file(run: Run, agent: ActorCritic, env: Any, step: int, meta: dict | None) -> dict:
    """The finished policy's payload (:func:`omcrl.rl.policy.policy_payload`), its ``meta`` naming the run."""
    meta = {"method": run.method, "name": run.method, "seed": run.seed, "key": run.key, **(meta or {})}
    return {**policy_payload(agent, space_shapes(env.single_observation_space), step, meta=meta), "key": run.key}


def _learner(
    rl: Any,
    env: Any,
    build_features: Callable[[Any], FeatureExtractor],
    make_guide: Callable[[Any], Guide | None] | None,
    layer_norm: bool,
    device: torch.device,
) -> tuple[ActorCritic, torch.optim.Optimizer, Guide | None]:
    """The actor-critic on ``build_features(env's observation space)`` and its Adam (trainable parameters only: a
    frozen encoder's are not), and the guide (None without one or with ``rl.alpha_schedule == 'none'``)."""
    act_dim = int(np.prod(env.single_action_space.shape))
    agent = ActorCritic(build_features(env.single_observation_space), act_dim, rl.hidden, rl.init_log_std,
                        layer_norm=layer_norm).to(device)  # fmt: skip
    agent.precision = section_precision(rl)
    optimizer = torch.optim.Adam([p for p in agent.parameters() if p.requires_grad], lr=float(rl.lr), eps=1e-5)
    guide = make_guide(env) if (make_guide is not None and rl.alpha_schedule != "none") else None
    if guide is not None and hasattr(guide, "to"):
        guide.to(device)
    return agent, optimizer, guide


def _resume(
    run: Run, ckpt: dict | None, agent: ActorCritic, optimizer: torch.optim.Optimizer, env_seed: int
) -> tuple[int, int]:
    """(env step, update) to go on from: a checkpoint's, its weights, optimizer and random state restored; (0, 0)
    for a fresh run. Each stretch of training and the env seed it flew go into run.json: a resumed run's episodes
    follow from these, not from its config alone (scripts/render_fault_audit.py replays them)."""
    step, update, earlier = 0, 0, []
    if ckpt is not None:
        agent.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        set_rng_state(ckpt["rng"])
        step, update = int(ckpt["step"]), int(ckpt["update"])
        earlier = (read_identity(run.dir) or {}).get("segments", [])
    run.record(segments=[*earlier, {"from_step": step, "env_seed": env_seed}])
    return step, update


@contextmanager
def _threads(inside: int, after: int) -> Iterator[None]:
    """torch's intra-op threads set to ``inside`` for the block, then to ``after``."""
    set_threads(inside)
    try:
        yield
    finally:
        set_threads(after)


@contextmanager
def _named_nonfinite(run: Run) -> Iterator[None]:
    """A :class:`~omcrl.rl.ppo.NonFiniteLossError` raised in the block names the run and its last good checkpoint."""
    try:
        yield
    except NonFiniteLossError as e:
        path = run.checkpoint_path
        where = f"last good checkpoint: {path}" if path.exists() else "no checkpoint was written"
        raise NonFiniteLossError(f"{run.method} seed {run.seed}: {e}; {where}") from None


def episode_means(eps: Sequence[dict]) -> dict[str, float]:
    """Mean return and length of finished episodes (``{"return", "length", ...}`` rows), and their success rate
    when they report one; {} when there are none."""
    if not eps:
        return {}
    row = {
        "episodic_return": float(np.mean([e["return"] for e in eps])),
        "episode_length": float(np.mean([e["length"] for e in eps])),
    }
    succ = [float(e["success"]) for e in eps if "success" in e]
    if succ:
        row["success_rate"] = float(np.mean(succ))
    return row


def _shown(recent: Sequence[dict]) -> dict[str, str]:
    """Success rate and return of the recent episodes, as the progress bar shows them."""
    rs = [float(e["success"]) for e in recent if "success" in e]
    return {
        "sr": f"{np.mean(rs):.2f}" if rs else "-",
        "ret": f"{np.mean([e['return'] for e in recent]):.2f}" if recent else "-",
    }


# ---------------------------------------------------------------- trainers
def _default_make_env(cfg: Config) -> Callable[[int], Any]:
    def make(seed: int) -> Any:

        return make_vec_env(cfg.env.scene, cfg.rl.n_envs, seed=seed, config=cfg.env)

    return make


def train_ppo(
    cfg: Config,
    make_env: Callable[[int], Any],
    *,
    name: str = "ppo-flat",
    make_guide: Callable[[Any], Guide | None] | None = None,
    overwrite: bool = False,
    progress: bool = True,
    layer_norm: bool = False,
) -> Result:
    """PPO on a Box-observation vector env (feature = flattened observation); for custom envs and tests.

    The env is the caller's, so the run is identified by ``name`` and the config (not by the env's code).
    ``layer_norm`` defaults to False here: small raw observations lose their scale under LayerNorm (the
    paper's LayerNorm is kept for the image policies, whose inputs are wide feature vectors).
    """
    ident = rl_identity(cfg, "planner" if make_guide is not None else None, layer_norm=layer_norm)
    return train(
        cfg,
        run=rl_run(cfg, name, ident),
        make_env=make_env,
        build_features=lambda space: IdentityFeatures(int(np.prod(space.shape))),
        make_guide=make_guide,
        overwrite=overwrite,
        progress=progress,
        layer_norm=layer_norm,
    )


def train_oracle(
    cfg: Config,
    *,
    name: str = "oracle",
    make_env: Callable[[int], Any] | None = None,
    overwrite: bool = False,
    progress: bool = True,
    callbacks: Sequence[Callback] = (),
) -> Result:
    """Oracle teacher π^o: PPO on [DepthEncoder(depth stack), v, ω, θ, Δp ∈ R⁶] (paper IV-C).

    With ``oracle.guide == 'apf'`` (default) the PPO loss gets the same decaying KL term as a student has,
    towards the privileged HybridAPF planner, with the oracle's own schedule and planner std (``cfg.oracle``, put
    in ``rl`` by :func:`oracle_config`), so the oracle becomes an expert in a CPU budget; ``'none'`` is the
    paper's unguided PPO (see docs/DEVIATIONS.md for why and what it costs). The depth encoder's width is
    ``pretrain.feature_dim`` (the same d as the student's features), which is therefore part of the run's
    identity.
    """
    cfg = oracle_config(cfg)

    def make_guide(env: Any) -> Guide | None:
        return PlannerGuide(lambda: HybridAPF(cfg.env), cfg.rl.guide_std, n_envs=env.num_envs)

    return train(
        cfg,
        run=_oracle_run(cfg, name, custom_env=make_env is not None),
        make_env=make_env or _default_make_env(cfg),
        build_features=lambda space: make_oracle_features(space, cfg.pretrain.feature_dim, cfg.env.far),
        make_guide=make_guide,
        overwrite=overwrite,
        progress=progress,
        callbacks=callbacks,
    )


def _guide_maker(
    cfg: Config, oracle_path: str | Path | None, planner_factory: Callable[[], Any] | None
) -> Callable[[Any], Guide | None]:
    """env -> guide for an oracle file, a planner factory, or neither."""
    if oracle_path is not None and not Path(oracle_path).exists():
        raise CheckpointError(f"oracle checkpoint {oracle_path} does not exist (train the oracle first)")

    def make_guide(env: Any) -> Guide | None:
        if oracle_path is not None:
            oracle = load_policy(oracle_path, expect_kind="oracle", obs_space=env.single_observation_space)
            return PolicyGuide(oracle.agent)
        if planner_factory is not None:
            return PlannerGuide(planner_factory, cfg.rl.guide_std, n_envs=env.num_envs)
        return None

    return make_guide


def oracle_run(cfg: Config, name: str = "oracle", *, custom_env: bool = False) -> Run:
    """The run of the oracle for ``cfg``: ``rl`` and ``env`` with the oracle's guidance (:func:`oracle_config`);
    its depth encoder's width ``pretrain.feature_dim`` is part of it."""
    return _oracle_run(oracle_config(cfg), name, custom_env=custom_env)


def _oracle_run(ocfg: Config, name: str, *, custom_env: bool) -> Run:
    # The oracle section's guidance fields are in ``rl`` (oracle_config); its other fields off their defaults
    # (``guide='none'``, any added later) enter here, under their section's name.
    own = {k: v for k, v in section_identity(ocfg.oracle).items() if k not in GUIDANCE_FIELDS}
    extra = {"feature_dim": ocfg.pretrain.feature_dim, **({"oracle": own} if own else {}), **_custom(custom_env)}
    return rl_run(ocfg, name, rl_identity(ocfg, "planner", **extra))


def policy_run(
    cfg: Config,
    name: str,
    encoder_path: str | Path | None,
    oracle_path: str | Path | None = None,
    planner_factory: Callable[[], Any] | None = None,
    *,
    custom_env: bool = False,
) -> Run:
    """The run of a visuomotor policy: on the frozen encoder at ``encoder_path``, or end to end when None.

    Upstream artifacts enter by content digest, not path: a retrained oracle or encoder at the same path must
    not reuse a run, and the same file reached by a relative (CLI) or absolute (notebook) path must.
    """
    kind = "policy" if oracle_path is not None else "planner" if planner_factory is not None else None
    if encoder_path is not None:
        feats = {"features": "frozen", "encoder_digest": file_digest(encoder_path)}
    else:
        feats = {"features": "pixel", "crop": cfg.pretrain.crop_to, "feature_dim": cfg.pretrain.feature_dim}
    guide = {}
    if kind is not None and cfg.rl.alpha_schedule != "none":
        guide = {
            "oracle_digest": file_digest(oracle_path) if oracle_path is not None else "",
            "planner": getattr(planner_factory, "__name__", "") if planner_factory else "",
        }
    return rl_run(cfg, name, rl_identity(cfg, kind, **feats, **_custom(custom_env), **guide))


def _custom(custom_env: bool) -> dict:
    """``{"custom_env": True}`` for a run on a caller's env factory (its env is not the config's), else nothing."""
    return {"custom_env": True} if custom_env else {}


def visuomotor_parts(
    cfg: Config,
    encoder_path: str | Path | None,
    oracle_path: str | Path | None = None,
    *,
    name: str,
    planner_factory: Callable[[], Any] | None = None,
    make_env: Callable[[int], Any] | None = None,
) -> dict[str, Any]:
    """What every visuomotor policy (paper IV-C, V-C) is made of: :func:`train`'s ``run``, ``make_env``,
    ``build_features``, ``make_guide`` and ``meta`` for PPO on [f(rgb stack), v, ω, θ, Δp_goal].

    Features: the frozen pretrained encoder (f and φ) at ``encoder_path`` (``ours``, ``curl``, ...), or, when it is
    None, a pixel encoder f of the same architecture trained end to end with the policy (``ppo``, ``npe``, ...),
    which sees the centre ``pretrain.crop_to`` px of the env's frames (what the frozen encoders see) and has
    ``pretrain.feature_dim`` outputs (both then part of the run's identity). Guide: the oracle at ``oracle_path`` (its
    mean and learned std on the privileged obs), else a planner from ``planner_factory`` with fixed std
    ``rl.guide_std`` (``npe``), else none (``ours-noOT``, ``curl``, ``ppo``); ``rl.alpha_schedule='none'`` also
    trains without the KL term. Encoder and oracle are checked against the env before any training step.
    ``make_env``: a caller's ``seed -> vector env`` in place of the config's scene (then part of the identity)."""
    if encoder_path is not None and not Path(encoder_path).exists():
        raise CheckpointError(f"encoder checkpoint {encoder_path} does not exist (run the pretraining stage first)")
    if encoder_path is not None:
        build = lambda space: make_student_features(encoder_path, space)  # noqa: E731
    else:
        crop, dim = cfg.pretrain.crop_to, cfg.pretrain.feature_dim
        build = lambda space: make_pixel_features(space, crop, dim)  # noqa: E731
    return {
        "run": policy_run(cfg, name, encoder_path, oracle_path, planner_factory, custom_env=make_env is not None),
        "make_env": make_env or _default_make_env(cfg),
        "build_features": build,
        "make_guide": _guide_maker(cfg, oracle_path, planner_factory),
        "meta": {"encoder": str(encoder_path or ""), "oracle": str(oracle_path or "")},
    }


def train_visuomotor(
    cfg: Config,
    encoder_path: str | Path | None,
    oracle_path: str | Path | None = None,
    *,
    overwrite: bool = False,
    progress: bool = True,
    callbacks: Sequence[Callback] = (),
    **parts: Any,
) -> Result:
    """Train a visuomotor policy on the encoder and oracle files given: :func:`train` on :func:`visuomotor_parts`
    (``parts``: its ``name``, ``planner_factory``, ``make_env``). The method recipes hand the loop the same parts
    of the files a method needs (:meth:`omcrl.rl.methods.Recipe.train`)."""
    made = visuomotor_parts(cfg, encoder_path, oracle_path, **parts)
    return train(cfg, **made, overwrite=overwrite, progress=progress, callbacks=callbacks)
