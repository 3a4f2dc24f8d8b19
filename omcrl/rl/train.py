"""PPO training runs: one generic trainer, used by the oracle, the student and any Box-observation env.

Run folder ``<run_root>/runs/<stage>/<name>/seed<k>/``::

    config.yaml      resolved config (omcrl.config.save_config)
    checkpoint.pt    latest resumable state, written atomically every ``rl.checkpoint_every`` env steps:
                     model, optimizer, RNG states, env-step count, update index, schedule state (α, lr)
    final.pt         the trained policy (omcrl.rl.policy format) + ``config_hash``; its presence = finished
    metrics.csv      tidy rows (step, metric, value)
    tb/              TensorBoard events

Step accounting: every vector step counts ``n_envs`` env steps (including next-step-autoreset dummy steps,
which are real env calls). A run performs ``ceil(total_steps / (rollout_len * n_envs))`` updates and so ends
at the same step count whether or not it was interrupted and resumed.
"""

from __future__ import annotations

import csv
import io
import math
import random
import shutil
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from omcrl.config import Config, config_hash, save_config
from omcrl.rl.guidance import Guide, PlannerGuide, PolicyGuide, alpha_from_config, info_at
from omcrl.rl.policy import (
    CheckpointError,
    Policy,
    load_policy,
    make_oracle_features,
    make_student_features,
    policy_payload,
    space_shapes,
)
from omcrl.rl.ppo import (
    ActorCritic,
    FeatureExtractor,
    IdentityFeatures,
    NonFiniteLossError,
    Rollout,
    compute_gae,
    ppo_update,
)
from omcrl.utils.io import atomic_save_torch, atomic_write_text, file_digest
from omcrl.utils.runtime import seed_everything, set_threads

METRIC_NAMES = (
    "episodic_return",
    "episode_length",
    "success_rate",
    "alpha",
    "kl",
    "policy_loss",
    "value_loss",
    "entropy",
    "loss",
    "lr",
    "clip_frac",
    "approx_kl_old",
    "steps_per_s",
)


# States per call of a batched guide: large enough to amortise reading the oracle's weights, small enough that
# the pending depth stacks stay small (256 · 3 · 224² float16 ≈ 77 MB at the paper's image size).
GUIDE_CHUNK = 256


class RunConfigMismatch(RuntimeError):
    """The run folder holds a checkpoint or final model of a different configuration."""


@dataclass
class Result:
    """What a training run produced. ``policy()`` loads the final policy for evaluation."""

    run_dir: Path
    final_path: Path
    steps: int
    skipped: bool
    metrics_path: Path

    def policy(self) -> Policy:
        return load_policy(self.final_path)

    def metrics(self) -> Any:
        import pandas as pd

        return pd.read_csv(self.metrics_path)


# ---------------------------------------------------------------- rollouts
def _autoreset_mode(env: Any) -> str:
    """'next' (gymnasium 1.x default) or 'same'; other modes are rejected."""
    mode = getattr(env, "metadata", {}).get("autoreset_mode", "NextStep")
    name = getattr(mode, "value", str(mode))
    if name == "NextStep":
        return "next"
    if name == "SameStep":
        return "same"
    raise ValueError(f"vector env autoreset_mode {name!r} is not supported (use NEXT_STEP or SAME_STEP)")


def _index_obs(obs: Any, idx: np.ndarray) -> Any:
    if isinstance(obs, dict):
        return {k: np.asarray(v)[idx] for k, v in obs.items()}
    return np.asarray(obs)[idx]


def _stack_final_obs(final_obs: np.ndarray, idx: np.ndarray) -> Any:
    items = [final_obs[i] for i in idx]
    if isinstance(items[0], dict):
        return {k: np.stack([np.asarray(it[k]) for it in items]) for k in items[0]}
    return np.stack([np.asarray(it) for it in items])


class Runner:
    """Steps a gymnasium vector env with the current policy and fills :class:`Rollout` buffers.

    Keeps env state between rollouts (current observation, next-step-autoreset flags, running returns) and a
    list of finished episodes ``{"return", "length", **info["metrics"]}``.
    """

    def __init__(
        self, env: Any, agent: ActorCritic, guide: Guide | None, seed: int, guide_chunk: int | None = None
    ) -> None:
        self.env, self.agent, self.guide = env, agent, guide
        self.guide_batched = bool(getattr(guide, "batched", False))
        # Vector steps whose guide inputs are evaluated together (about ``guide_chunk`` states per call;
        # default GUIDE_CHUNK, read at run time so a benchmark can compare against per-step evaluation).
        chunk = GUIDE_CHUNK if guide_chunk is None else guide_chunk
        self.guide_every = max(1, chunk // env.num_envs)
        self.mode = _autoreset_mode(env)
        self.n = env.num_envs
        self.obs, self.infos = env.reset(seed=seed)
        self.stored = agent.features.preprocess(self.obs)
        self.starts = np.ones(self.n, bool)
        self.dummy = np.zeros(self.n, bool)  # next-step mode: this step only resets, the action is ignored
        self.ep_return = np.zeros(self.n)
        self.ep_len = np.zeros(self.n, int)
        self.episodes: list[dict] = []

    def collect(self, length: int, horizon: int, use_guide: bool) -> Rollout:
        n = self.n
        buf: dict[str, list] = {
            k: [] for k in ("obs", "act", "logp", "val", "rew", "term", "ends", "valid", "gm", "gs")
        }
        final_values: dict[tuple[int, int], float] = {}
        guided = use_guide and self.guide is not None
        pending: list[dict[str, torch.Tensor]] = []  # prepared guide inputs not evaluated yet (batched guides)
        for t in range(length):
            action, logp, value, _, _ = self.agent.step(self.stored)
            if guided and self.guide_batched:
                pending.append(self.guide.prepare(self.obs))
                if len(pending) == self.guide_every or t == length - 1:
                    self._flush_guide(pending, buf)
            elif guided:
                gm, gs = self.guide.distribution(self.obs, self.infos, self.starts)
                buf["gm"].append(torch.as_tensor(gm, dtype=torch.float32))
                buf["gs"].append(torch.as_tensor(gs, dtype=torch.float32))
            buf["obs"].append(self.stored)
            buf["act"].append(action)
            buf["logp"].append(logp)
            buf["val"].append(value)
            valid = ~self.dummy
            # The env sees the clipped action; the buffer keeps the unclipped sample (see ppo.py docstring).
            obs, rew, term, trunc, infos = self.env.step(np.clip(action.numpy(), -1.0, 1.0))
            rew = np.asarray(rew, dtype=np.float64)
            term, trunc = np.asarray(term, bool), np.asarray(trunc, bool)
            done = term | trunc
            buf["rew"].append(torch.as_tensor(rew, dtype=torch.float32))
            buf["term"].append(torch.as_tensor(term, dtype=torch.float32))
            cut = (t + 1) % horizon == 0 or t == length - 1
            buf["ends"].append(torch.as_tensor(done | cut, dtype=torch.float32))
            buf["valid"].append(torch.as_tensor(valid, dtype=torch.float32))
            self.ep_return[valid] += rew[valid]
            self.ep_len[valid] += 1
            ended = np.flatnonzero(done & valid)
            if self.mode == "same" and ended.size:
                # Same-step autoreset returns the reset obs; bootstrap truncations from the real final obs.
                with torch.no_grad():
                    fo = self.agent.features.preprocess(_stack_final_obs(infos["final_obs"], ended))
                    _, _, v_final = self.agent(fo)
                for j, i in enumerate(ended):
                    final_values[(t, int(i))] = float(v_final[j])
            src = infos.get("final_info", {}) if self.mode == "same" else infos
            for i in ended:
                ep = {"return": float(self.ep_return[i]), "length": int(self.ep_len[i])}
                ep.update(info_at(src, int(i)).get("metrics", {}) if src else {})
                self.episodes.append(ep)
                self.ep_return[i], self.ep_len[i] = 0.0, 0
            if self.mode == "next":
                self.starts, self.dummy = self.dummy.copy(), done & valid
            else:
                self.starts, self.dummy = done.copy(), np.zeros(n, bool)
            self.obs, self.infos = obs, infos
            self.stored = self.agent.features.preprocess(obs)
        with torch.no_grad():
            _, _, last_value = self.agent(self.stored)
        values = torch.stack(buf["val"])
        # V(s_{t+1}) is the next slot's value; in next-step mode that slot holds an ended episode's final obs.
        next_values = torch.cat([values[1:], last_value[None]], dim=0)
        for (t, i), v in final_values.items():
            next_values[t, i] = v
        obs_t = {k: torch.stack([s[k] for s in buf["obs"]]) for k in buf["obs"][0]}
        return Rollout(
            obs=obs_t,
            actions=torch.stack(buf["act"]),
            log_probs=torch.stack(buf["logp"]),
            values=values,
            next_values=next_values,
            rewards=torch.stack(buf["rew"]),
            terminated=torch.stack(buf["term"]),
            ends=torch.stack(buf["ends"]),
            valid=torch.stack(buf["valid"]),
            guide_mean=torch.stack(buf["gm"]) if buf["gm"] else None,
            guide_std=torch.stack(buf["gs"]) if buf["gs"] else None,
        )

    def _flush_guide(self, pending: list[dict[str, torch.Tensor]], buf: dict[str, list]) -> None:
        """Evaluate a batched guide on the pending steps at once and append one (N, A) row per step."""
        stored = {k: torch.cat([p[k] for p in pending]) for k in pending[0]}
        mean, std = self.guide.distribution_stored(stored)
        buf["gm"].extend(mean.split(self.n))
        buf["gs"].extend(std.split(self.n))
        pending.clear()


# ---------------------------------------------------------------- metrics output
class MetricsLog:
    """Tidy ``metrics.csv`` (step, metric, value) + TensorBoard; resuming drops rows past the checkpoint."""

    def __init__(self, run_dir: Path, resume_step: int | None) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self.path = run_dir / "metrics.csv"
        if resume_step is None or not self.path.exists():
            atomic_write_text(self.path, "step,metric,value\n")
        else:
            with open(self.path, newline="") as fh:
                rows = [r for r in csv.reader(fh)][1:]
            keep = io.StringIO()
            w = csv.writer(keep, lineterminator="\n")
            w.writerow(["step", "metric", "value"])
            w.writerows(r for r in rows if r and int(r[0]) <= resume_step)
            atomic_write_text(self.path, keep.getvalue())
        self.tb = SummaryWriter(str(run_dir / "tb"), purge_step=resume_step)

    def log(self, step: int, values: dict[str, float]) -> None:
        with open(self.path, "a", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            for k, v in values.items():
                if v is None or (isinstance(v, float) and math.isnan(v)):
                    continue
                w.writerow([step, k, f"{float(v):.6g}"])
                self.tb.add_scalar(k, float(v), step)

    def close(self) -> None:
        self.tb.flush()
        self.tb.close()


# ---------------------------------------------------------------- generic trainer
def _rng_state() -> dict:
    # The legacy global numpy RNG is saved because third-party code (envs, planners) may draw from it.
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}  # noqa: NPY002


def _set_rng_state(s: dict) -> None:
    torch.set_rng_state(s["torch"])
    np.random.set_state(s["numpy"])  # noqa: NPY002
    random.setstate(s["python"])


def run_dir_for(cfg: Config, stage: str, name: str) -> Path:
    return cfg.run_root / "runs" / stage / name / f"seed{cfg.seed}"


def train(
    cfg: Config,
    *,
    stage: str,
    name: str,
    make_env: Callable[[int], Any],
    build_features: Callable[[Any], FeatureExtractor],
    make_guide: Callable[[Any], Guide | None] | None = None,
    extra: dict | None = None,
    overwrite: bool = False,
    progress: bool = True,
    layer_norm: bool = True,
) -> Result:
    """Train (or resume, or skip) one PPO run; the single implementation behind every trainer.

    Parameters
    ----------
    cfg : resolved config; ``cfg.rl`` sets PPO and guidance, ``cfg.seed`` the seed.
    stage, name : run folder ``<run_root>/runs/<stage>/<name>/seed<k>``.
    make_env : ``seed -> vector env`` (gymnasium SyncVectorEnv/AsyncVectorEnv, ``cfg.rl.n_envs`` envs); the
        env is reset with ``seed``.
    build_features : ``single_observation_space -> FeatureExtractor``; may raise CheckpointError before
        training.
    make_guide : ``env -> guide or None``; None (or ``alpha_schedule == 'none'``) trains without the KL term.
    extra : identifying inputs beyond the config (e.g. encoder/oracle paths), part of the cache key.
    overwrite : delete a run folder of a different configuration instead of raising RunConfigMismatch.
    layer_norm : LayerNorm on the actor/critic inputs (paper V-D); see :class:`ActorCritic`.
    """
    rl = cfg.rl
    set_threads(rl.num_threads)
    run_dir = run_dir_for(cfg, stage, name)
    ckpt_path, final_path = run_dir / "checkpoint.pt", run_dir / "final.pt"
    key = config_hash(
        {
            "rl": asdict(rl),
            "env": asdict(cfg.env),
            "seed": cfg.seed,
            "stage": stage,
            "extra": {k: str(v) for k, v in (extra or {}).items()},
        }
    )

    for p in (final_path, ckpt_path):
        if p.exists():
            # final.pt is a policy file (tensors and plain containers); only checkpoint.pt also holds RNG states.
            found = torch.load(p, map_location="cpu", weights_only=p == final_path).get("config_hash")
            if found != key:
                if not overwrite:
                    raise RunConfigMismatch(
                        f"{p} belongs to a different configuration (hash {found} != {key}); "
                        "use another run name, delete the folder or pass overwrite=True"
                    )
                shutil.rmtree(run_dir)
                break
    if final_path.exists():
        step = int(torch.load(final_path, map_location="cpu", weights_only=True)["step"])
        return Result(run_dir, final_path, step, True, run_dir / "metrics.csv")

    ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=False) if ckpt_path.exists() else None
    if ckpt is None:
        seed_everything(cfg.seed)

    n_envs = rl.n_envs
    length = rl.buffer_size // n_envs if rl.buffer_size >= n_envs else rl.horizon
    per_update = length * n_envs
    n_updates = math.ceil(rl.total_steps / per_update)
    final_step = n_updates * per_update
    resumes = 0 if ckpt is None else ckpt["resumes"] + 1
    env = make_env(cfg.seed * 1000 + 100 * resumes)
    writer = None
    try:
        obs_space = env.single_observation_space
        features = build_features(obs_space)
        act_dim = int(np.prod(env.single_action_space.shape))
        agent = ActorCritic(features, act_dim, rl.hidden, rl.init_log_std, layer_norm=layer_norm)
        params = [p for p in agent.parameters() if p.requires_grad]
        optimizer = torch.optim.Adam(params, lr=rl.lr, eps=1e-5)
        guide = make_guide(env) if (make_guide is not None and rl.alpha_schedule != "none") else None
        # Only now, with encoder / oracle / env known to fit, does the run folder appear: a failed start
        # (missing or mismatched checkpoint) leaves nothing behind that looks like a run.
        run_dir.mkdir(parents=True, exist_ok=True)
        save_config(cfg, run_dir)
        step, update = 0, 0
        if ckpt is not None:
            agent.load_state_dict(ckpt["model"])
            optimizer.load_state_dict(ckpt["optimizer"])
            step, update = int(ckpt["step"]), int(ckpt["update"])
            _set_rng_state(ckpt["rng"])
        writer = MetricsLog(run_dir, step if ckpt is not None else None)
        shapes = space_shapes(obs_space)
        runner = Runner(env, agent, guide, seed=cfg.seed * 1000 + 100 * resumes)
        recent = deque(maxlen=50)
        bar = _progress(progress, final_step, step, f"{stage}/{name}")
        last_ckpt = step
        while update < n_updates:
            alpha = alpha_from_config(step, rl) if guide is not None else 0.0
            lr = rl.lr * max(0.0, 1.0 - step / max(final_step, 1))  # linear decay to 0 over the run
            for g in optimizer.param_groups:
                g["lr"] = lr
            t0 = time.perf_counter()
            n_done = len(runner.episodes)
            agent.eval()
            rollout = runner.collect(length, rl.horizon, use_guide=alpha > 0.0)
            adv, ret = compute_gae(
                rollout.rewards,
                rollout.values,
                rollout.next_values,
                rollout.terminated,
                rollout.ends,
                rl.gamma,
                rl.gae_lambda,
            )
            rollout.advantages, rollout.returns = adv, ret
            agent.train()
            try:
                stats = ppo_update(
                    agent,
                    optimizer,
                    rollout,
                    epochs=rl.epochs,
                    minibatch=rl.minibatch,
                    alpha=alpha,
                    beta=rl.beta,
                    clip=rl.clip,
                    value_coef=rl.value_coef,
                    entropy_coef=rl.entropy_coef,
                    max_grad_norm=rl.max_grad_norm,
                    step=step,
                )
            except NonFiniteLossError as e:
                where = f"last good checkpoint: {ckpt_path}" if ckpt_path.exists() else "no checkpoint was written"
                raise NonFiniteLossError(f"{stage}/{name} seed {cfg.seed}: {e}; {where}") from None
            step += per_update
            update += 1
            dt = time.perf_counter() - t0
            eps = runner.episodes[n_done:]
            recent.extend(eps)
            row = {**stats, "alpha": alpha, "lr": lr, "steps_per_s": per_update / max(dt, 1e-9)}
            if eps:
                row["episodic_return"] = float(np.mean([e["return"] for e in eps]))
                row["episode_length"] = float(np.mean([e["length"] for e in eps]))
                succ = [float(e["success"]) for e in eps if "success" in e]
                if succ:
                    row["success_rate"] = float(np.mean(succ))
            writer.log(step, row)
            if bar is not None:
                rs = [float(e["success"]) for e in recent if "success" in e]
                bar.update(per_update)
                bar.set_postfix(
                    sps=f"{row['steps_per_s']:.0f}",
                    sr=f"{np.mean(rs):.2f}" if rs else "-",
                    ret=f"{np.mean([e['return'] for e in recent]):.2f}" if recent else "-",
                )
            if step // rl.checkpoint_every > last_ckpt // rl.checkpoint_every and update < n_updates:
                atomic_save_torch(
                    {
                        "model": agent.state_dict(),
                        "optimizer": optimizer.state_dict(),
                        "step": step,
                        "update": update,
                        "rng": _rng_state(),
                        "resumes": resumes,
                        "schedule": {"alpha": alpha, "lr": lr},
                        "config_hash": key,
                    },
                    ckpt_path,
                )
                last_ckpt = step
        if bar is not None:
            bar.close()
        payload = policy_payload(
            agent,
            shapes,
            step,
            meta={
                "stage": stage,
                "name": name,
                "seed": cfg.seed,
                **{k: str(v) for k, v in (extra or {}).items()},
            },
        )
        payload["config_hash"] = key
        atomic_save_torch(payload, final_path)
        ckpt_path.unlink(missing_ok=True)  # finished: final.pt is the artifact, the resumable state is obsolete
    finally:
        if writer is not None:
            writer.close()
        env.close()
    return Result(run_dir, final_path, step, False, run_dir / "metrics.csv")


def _progress(enabled: bool, total: int, initial: int, desc: str) -> Any:
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="step", dynamic_ncols=True)


# ---------------------------------------------------------------- stage entry points
def _default_make_env(cfg: Config) -> Callable[[int], Any]:
    def make(seed: int) -> Any:
        from omcrl.envs import make_vec_env

        return make_vec_env(cfg.env.scene, cfg.rl.n_envs, seed=seed, config=cfg.env)

    return make


def train_ppo(
    cfg: Config,
    make_env: Callable[[int], Any],
    *,
    stage: str = "ppo",
    name: str = "ppo",
    make_guide: Callable[[Any], Guide | None] | None = None,
    overwrite: bool = False,
    progress: bool = True,
    layer_norm: bool = False,
) -> Result:
    """PPO on a Box-observation vector env (feature = flattened observation).

    ``layer_norm`` defaults to False here: small raw observations lose their scale under LayerNorm (the
    paper's LayerNorm is kept for the oracle and student, whose inputs are wide feature vectors).
    """
    return train(
        cfg,
        stage=stage,
        name=name,
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
) -> Result:
    """Oracle teacher π^o: PPO on [DepthEncoder(depth stack), v, ω, θ, Δp ∈ R⁶] (paper IV-C).

    With ``rl.oracle_guide == 'apf'`` (default) the PPO loss gets the same decaying KL term as the student,
    towards the privileged HybridAPF planner (fixed std ``rl.guide_std``), so the oracle becomes an expert in
    a CPU budget; ``'none'`` is the paper's unguided PPO (see docs/DEVIATIONS.md for why and what it costs).
    """

    def make_guide(env: Any) -> Guide | None:
        if cfg.rl.oracle_guide == "none":
            return None
        from omcrl.planners import HybridAPF

        return PlannerGuide(lambda: HybridAPF(cfg.env), cfg.rl.guide_std, n_envs=env.num_envs)

    return train(
        cfg,
        stage="oracle",
        name=name,
        make_env=make_env or _default_make_env(cfg),
        build_features=lambda space: make_oracle_features(space, cfg.pretrain.feature_dim, cfg.env.far),
        make_guide=make_guide,
        overwrite=overwrite,
        progress=progress,
    )


def train_student(
    cfg: Config,
    encoder_path: str | Path,
    oracle_path: str | Path | None = None,
    *,
    name: str = "omc",
    planner_factory: Callable[[], Any] | None = None,
    make_env: Callable[[int], Any] | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> Result:
    """Visuomotor student: PPO on [frozen f(rgb stack), v, ω, θ, Δp_goal] with guide KL (paper IV-C, Eq. 9).

    Guide: the oracle at ``oracle_path`` (its mean and learned std on the privileged obs), else a planner from
    ``planner_factory`` with fixed std ``rl.guide_std`` (NPE), else none. ``rl.alpha_schedule='none'`` gives
    the "w/o OT" variant. Encoder and oracle are checked against the env before any training step.
    """
    # Resolved paths (the CLI passes relative ones, notebooks absolute ones: same run) and content digests (a
    # retrained encoder or oracle at the same path must not reuse this run).
    extra = {
        "encoder": Path(encoder_path).resolve(),
        "encoder_digest": file_digest(encoder_path),
        "oracle": Path(oracle_path).resolve() if oracle_path is not None else "",
        "oracle_digest": file_digest(oracle_path) if oracle_path is not None else "",
        "planner": getattr(planner_factory, "__name__", "") if planner_factory else "",
    }

    def make_guide(env: Any) -> Guide | None:
        if oracle_path is not None:
            oracle = load_policy(oracle_path, expect_kind="oracle", obs_space=env.single_observation_space)
            return PolicyGuide(oracle.agent)
        if planner_factory is not None:
            return PlannerGuide(planner_factory, cfg.rl.guide_std, n_envs=env.num_envs)
        return None

    if oracle_path is not None and not Path(oracle_path).exists():
        raise CheckpointError(f"oracle checkpoint {oracle_path} does not exist (train the oracle first)")
    return train(
        cfg,
        stage="student",
        name=name,
        make_env=make_env or _default_make_env(cfg),
        build_features=lambda space: make_student_features(encoder_path, space),
        make_guide=make_guide,
        extra=extra,
        overwrite=overwrite,
        progress=progress,
    )


def run_student(cfg: Config, *, progress: bool = True) -> Result:
    """CLI stage ``student``: the OMC student from this preset's pretraining and oracle runs.

    The encoder is ``omcrl.pretrain.run_dir(cfg) / "encoder.pt"`` and the oracle
    ``results/<preset>/runs/oracle/oracle/seed<k>/final.pt``; with ``rl.alpha_schedule=none`` it trains the
    unguided "w/o OT" twin (run name ``omc-noOT``), which needs no oracle.
    """
    from omcrl import pretrain

    encoder = pretrain.run_dir(cfg) / "encoder.pt"
    if not encoder.exists():
        raise CheckpointError(f"encoder {encoder} does not exist (run the pretrain stage first)")
    if cfg.rl.alpha_schedule == "none":
        return train_student(cfg, encoder, None, name="omc-noOT", progress=progress)
    oracle = run_dir_for(cfg, "oracle", "oracle") / "final.pt"
    return train_student(cfg, encoder, oracle, name="omc", progress=progress)
