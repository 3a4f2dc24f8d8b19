"""Collect trajectory data for upstream pretraining (paper IV-B "Data Collection", V-D).

``collect_dataset(cfg, policy=None) -> CollectResult`` flies ``cfg.data.episodes`` episodes in ``cfg.data.scene`` with a
mix of behaviour sources and appends them to the HDF5 file ``cfg.data.file`` (``{preset}`` and ``{seed}``
substituted, a relative path is taken from the current directory — the repository root for the CLI and the
notebooks). What is flown depends on ``cfg.seed``, so the default path names the seed: every training seed
pretrains on data of its own.

Sources (proportions ``cfg.data.mix``)
--------------------------------------
``pilot``   the scripted :class:`~omcrl.planners.HybridAPF` (privileged map and obstacle distance) plus
            Gaussian action noise of std ``cfg.data.pilot_noise``. With probability ``cfg.data.detour_prob``
            per episode it makes a *yaw-sweep detour*: at a random step in [5, 40) it stops translating and
            turns in place at ±0.8 of the max yaw rate for 10–30 steps, then resumes the planner. We chose a
            sweep over a detour waypoint because it needs no map in the collector process (the map lives in
            the env workers), can never steer into an obstacle, and adds exactly what pure path following
            lacks: views that do not look along the direction of travel.
``random``  temporally correlated exploration: x_t = c·x_{t-1} + √(1−c²)·σ·ε_t (AR(1), c =
            ``cfg.data.random_corr``, σ = 0.6, ε ~ N(0, I)); the action is (0.3 + x₀, 0.5·x₁, x₂) clipped to
            [-1, 1], i.e. a forward bias so the drone travels through the scene instead of spinning in place.
``policy``  any callable ``policy(obs, info) -> action (3,)`` given to :func:`run`, or, with
            ``cfg.data.policy = "oracle"``, this config's trained oracle at ``cfg.seed`` (deterministic), which
            the collect stage (:func:`omcrl.pipeline.stages.collect_stage`, ``python -m omcrl collect``) finds
            and passes in; ``obs``/``info`` are those of a single env.

Determinism and ordering
------------------------
The source of dataset episode ``i`` is a fixed function of ``cfg.seed``, ``mix`` and ``i`` only
(:func:`assign_sources`), so a resumed collection continues the same sequence. Episodes are written in the
order they were *started* (finished ones wait in memory for their predecessors), so episode ``i`` in the file
has source ``assign_sources(...)[i]``, and a collection that runs uninterrupted is reproducible for a given seed
and ``n_envs``. A resumed one is not bit-identical to it: the sources of the appended episodes are the same, but
their envs start from fresh seeds, so their layouts and flights differ (every episode is still complete).

Resuming
--------
An existing valid file with fewer episodes is appended to (earlier episodes are never rewritten); one with
enough episodes is left alone; an unreadable file or one with another image size / frame stack raises
:class:`~omcrl.data.DatasetError` and is never overwritten.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from omcrl.config import Config, ConfigError
from omcrl.data.dataset import SOURCES, DatasetError, EpisodeBuffer, WriterProcess, open_dataset
from omcrl.envs import make_vec_env
from omcrl.envs.render import resolve_renderer
from omcrl.planners.apf import HybridAPF
from omcrl.utils.progress import Progress

log = logging.getLogger(__name__)

Policy = Callable[[dict, dict], np.ndarray]

RANDOM_SIGMA = 0.6  # stationary std of the AR(1) exploration process (action units)
DETOUR_START = (5, 40)  # detour begins at a step drawn from [lo, hi)
DETOUR_LENGTH = (10, 31)  # and lasts this many steps, drawn from [lo, hi)
DETOUR_YAW = 0.8  # yaw-rate command during the sweep, fraction of max_yaw_rate


@dataclass
class CollectResult:
    """What :func:`run` did.

    Attributes
    ----------
    path : the dataset file.
    episodes : complete episodes in the file now.
    added : episodes written by this call (0 when skipped).
    steps_added : environment steps written by this call.
    per_source : ``{source: episodes added}``.
    outcomes : ``{source: {"success": n, "collision": n, "timeout": n}}`` of the added episodes.
    wall_time_s : seconds spent in this call.
    skipped : the file already held enough episodes.
    """

    path: Path
    episodes: int
    added: int
    steps_added: int = 0
    per_source: dict[str, int] = field(default_factory=dict)
    outcomes: dict[str, dict[str, int]] = field(default_factory=dict)
    wall_time_s: float = 0.0
    skipped: bool = False

    def success_rate(self, source: str = "pilot") -> float:
        """Share of the added ``source`` episodes that reached the goal (NaN if there were none)."""
        o = self.outcomes.get(source, {})
        n = sum(o.values())
        return o.get("success", 0) / n if n else float("nan")


def dataset_path(cfg: Config) -> Path:
    """``cfg.data.file`` with ``{preset}`` and ``{seed}`` substituted (:attr:`omcrl.config.Config.data_path`)."""
    return cfg.data_path


def assign_sources(mix: dict[str, float], n: int, seed: int) -> list[str]:
    """Source of each of the first ``n`` episodes; prefix-stable (episode i never depends on ``n``).

    A deficit rule keeps every prefix close to the mix: episode i goes to the source with the largest
    ``p_s·(i+1) − count_s + u_s``, where ``u_s ~ U[0, 1)`` is a per-source phase drawn from ``seed`` (so the
    interleaving depends on the seed while counts stay within about one episode of ``p_s·n``).

    Parameters
    ----------
    mix : ``{source: weight}``, weights >= 0 with a positive sum (normalised here); sources in ``SOURCES``.
    n : number of episodes.
    seed : ``cfg.seed``.
    """
    unknown = set(mix) - set(SOURCES)
    if unknown:
        raise ConfigError(f"data.mix: unknown sources {sorted(unknown)}; allowed: {list(SOURCES)}")
    w = np.array([float(mix.get(s, 0.0)) for s in SOURCES])
    if np.any(w < 0) or w.sum() <= 0:
        raise ConfigError(f"data.mix: got {mix}, expected non-negative weights with a positive sum")
    p = w / w.sum()
    phase = np.random.default_rng([seed, 0xC011EC7]).uniform(0.0, 1.0, len(SOURCES)) * (p > 0)
    counts = np.zeros(len(SOURCES))
    out = []
    for i in range(n):
        score = np.where(p > 0, p * (i + 1) - counts + phase, -np.inf)
        k = int(np.argmax(score))
        counts[k] += 1
        out.append(SOURCES[k])
    return out


def episode_outcomes(ds: Any) -> list[str]:
    """``"success" | "collision" | "timeout"`` per episode of an open dataset, from the stored rewards.

    The last reward of an episode carries ``goal_reward`` on success and ``collision_penalty`` on a collision
    (or leaving the arena); the per-step terms are two orders of magnitude smaller, so half of each is a safe
    threshold. Uses the env config stored in the file (defaults 10 and −1).
    """
    goal = float(ds.env_config.get("goal_reward", 10.0))
    crash = float(ds.env_config.get("collision_penalty", -1.0))
    out = []
    for ep in range(len(ds)):
        n = int(ds.episode_lengths[ep])
        r = float(ds.read(ep, "reward", n - 1, n)[0])
        out.append("success" if r >= 0.5 * goal else "collision" if r <= 0.5 * crash else "timeout")
    return out


# ---------------------------------------------------------------- behaviour sources
class _Source:
    """One episode's behaviour in one env: ``act(obs, info) -> (3,)`` float32 in [-1, 1]."""

    def act(self, obs: dict, info: dict) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError


class _Pilot(_Source):
    def __init__(self, planner: Any, info: dict, noise: float, detour: bool, rng: np.random.Generator) -> None:
        self.planner, self.noise, self.rng = planner, noise, rng
        self.planner.reset(info)  # the reset info carries the shortest path
        self.t = 0
        self.detour = (0, 0)
        if detour:
            start = int(rng.integers(*DETOUR_START))
            self.detour = (start, start + int(rng.integers(*DETOUR_LENGTH)))
            self.turn = float(rng.choice([-1.0, 1.0])) * DETOUR_YAW

    def act(self, obs: dict, info: dict) -> np.ndarray:
        # The planner runs every step (its carrot must keep advancing) even when its action is overridden.
        a = self.planner.act(obs, info)
        if self.detour[0] <= self.t < self.detour[1]:
            a = np.array([0.0, 0.0, self.turn], np.float32)
        self.t += 1
        a = a + self.rng.normal(0.0, self.noise, 3) if self.noise > 0 else a
        return np.clip(a, -1.0, 1.0).astype(np.float32)


class _Random(_Source):
    def __init__(self, corr: float, rng: np.random.Generator) -> None:
        self.c, self.rng = corr, rng
        self.x = rng.normal(0.0, RANDOM_SIGMA, 3)  # start in the stationary distribution

    def act(self, obs: dict, info: dict) -> np.ndarray:
        a = np.array([0.3 + self.x[0], 0.5 * self.x[1], self.x[2]])
        self.x = self.c * self.x + np.sqrt(1.0 - self.c**2) * RANDOM_SIGMA * self.rng.normal(size=3)
        return np.clip(a, -1.0, 1.0).astype(np.float32)


class _Given(_Source):
    def __init__(self, policy: Policy) -> None:
        self.policy = policy

    def act(self, obs: dict, info: dict) -> np.ndarray:
        a = np.asarray(self.policy(obs, info), np.float32).reshape(-1)
        if a.shape != (3,):
            raise ValueError(f"policy returned an action of shape {a.shape}, expected (3,)")
        return np.clip(a, -1.0, 1.0)


# ---------------------------------------------------------------- vector-env helpers
def _env_info(infos: dict, j: int) -> dict:
    """Info of env ``j`` from a gymnasium vector info dict (arrays + ``_key`` masks, nested for metrics)."""
    out = {}
    for k, v in infos.items():
        if k.startswith("_") or not infos.get(f"_{k}", np.ones(j + 1, bool))[j]:
            continue
        out[k] = _env_info(v, j) if isinstance(v, dict) else v[j]
    return out


def _snapshot(obs: dict, j: int) -> dict:
    """Copy what the dataset stores of env ``j``'s observation (the buffers are reused by the next step)."""
    return {
        "rgb": obs["rgb"][j][-1:].copy(),
        "depth": obs["depth"][j][-1:].copy(),
        "state": obs["state"][j].copy(),
        "privileged": obs["privileged"][j].copy(),
    }


def _check(cfg: Config, policy: Policy | None) -> None:
    if cfg.env.image_size != cfg.pretrain.crop_from:
        raise ConfigError(
            f"env.image_size is {cfg.env.image_size} but pretrain.crop_from is {cfg.pretrain.crop_from}: "
            f"the data is stored at the env image size and pretraining crops from it, so they must be equal "
            f"(e.g. --set pretrain.crop_from={cfg.env.image_size})"
        )
    if cfg.data.mix.get("policy", 0.0) > 0 and policy is None:
        hint = (
            " (data.policy='oracle': the collect stage passes the oracle, omcrl.pipeline.stages.collect_stage)"
            if cfg.data.policy == "oracle"
            else ""
        )
        raise ConfigError(f"data.mix gives 'policy' weight {cfg.data.mix['policy']} but no policy was passed{hint}")


def _open_existing(path: Path, cfg: Config) -> int:
    """Episodes already in ``path`` (0 if absent); raises DatasetError for an unusable file (left as is)."""
    if not path.exists():
        return 0
    try:
        with open_dataset(path, image_size=cfg.env.image_size, frame_stack=cfg.env.frame_stack) as ds:
            stored = ds.env_config.get("look", "own")
            if stored != cfg.data.look:
                raise DatasetError(
                    f"{path}: collected with data.look={stored!r}, the config asks for {cfg.data.look!r}"
                )
            return len(ds)
    except DatasetError as e:
        raise DatasetError(
            f"{e}\ncollect will not overwrite it: delete or move the file, or set data.file to another path"
        ) from None


def collection_env(cfg: Config) -> Any:
    """The env section data is flown in: ``cfg.env`` in ``data.scene`` with ``data.max_steps`` as its horizon."""
    return dataclasses.replace(cfg.env, scene=cfg.data.scene, max_steps=cfg.data.max_steps)


def collect_dataset(cfg: Config, policy: Policy | None = None, *, progress: bool = True) -> CollectResult:
    """Collect ``cfg.data.episodes`` episodes into ``cfg.data.file`` (appending to a shorter existing file).

    Parameters
    ----------
    cfg : resolved configuration. Uses ``cfg.data`` (scene, episodes, n_envs, mix, pilot_noise,
        detour_prob, random_corr, max_steps, file), ``cfg.env`` (image_size must equal
        ``cfg.pretrain.crop_from``; frame_stack) and ``cfg.seed``.
    policy : ``policy(obs, info) -> action (3,)`` for the ``"policy"`` share of the mix (single-env obs/info).
    progress : show progress over episodes (:class:`omcrl.utils.progress.Progress`).

    Returns
    -------
    :class:`CollectResult`.

    Raises
    ------
    ConfigError : image size mismatch with pretraining, or a policy share without a policy.
    DatasetError : the existing file is unreadable or was collected with another image size / frame stack.
    """

    t_start = time.perf_counter()
    _check(cfg, policy)
    d = cfg.data
    path = dataset_path(cfg)
    have = _open_existing(path, cfg)
    if have >= d.episodes:
        log.info("collect: %s already holds %d >= %d episodes, skipping", path, have, d.episodes)
        return CollectResult(path, have, 0, skipped=True, wall_time_s=time.perf_counter() - t_start)
    n_new = d.episodes - have
    sources = assign_sources(d.mix, d.episodes, cfg.seed)[have:]
    env_cfg = collection_env(cfg)
    # Seeds depend on where this call starts, so an appended batch of episodes gets new layouts.
    ss = np.random.SeedSequence([cfg.seed, have])
    env_seed = int(ss.generate_state(1)[0] % (2**31 - 1 - d.n_envs))
    rng = np.random.default_rng(ss.spawn(1)[0])
    n_envs = min(d.n_envs, n_new)

    look = {"disturbance": {"randomize_look": True, "seed": env_seed}} if d.look == "randomized" else {}
    vec = make_vec_env(d.scene, n_envs, seed=env_seed, config=env_cfg, max_steps=d.max_steps, **look)
    planners = [HybridAPF(env_cfg) for _ in range(n_envs)]
    behaviours: list[_Source | None] = [None] * n_envs
    episode_of: list[int] = [-1] * n_envs  # index (relative to this call) of the episode each env is flying
    buffers: list[EpisodeBuffer | None] = [None] * n_envs
    seeds: list[int] = [0] * n_envs
    pending_reset = [False] * n_envs  # the next step of this env returns the reset observation
    finished: dict[int, tuple[EpisodeBuffer, int, str]] = {}  # done, waiting for earlier episodes
    started = written = steps_added = 0
    per_source: dict[str, int] = {}
    outcomes: dict[str, dict[str, int]] = {}

    def start(j: int, info: dict) -> None:
        nonlocal started
        if started >= n_new:  # enough episodes under way: this env idles until the end
            episode_of[j], behaviours[j], buffers[j] = -1, None, None
            return
        src = sources[started]
        if src == "pilot":
            behaviours[j] = _Pilot(planners[j], info, d.pilot_noise, bool(rng.random() < d.detour_prob), rng)
        elif src == "random":
            behaviours[j] = _Random(d.random_corr, rng)
        else:
            behaviours[j] = _Given(policy)  # type: ignore[arg-type]
        episode_of[j], buffers[j], seeds[j] = started, EpisodeBuffer(), int(info.get("layout_seed", -1))
        started += 1

    bar = Progress(n_new, f"collect/{d.scene}", unit="ep", enabled=progress)
    try:
        meta = dataclasses.asdict(env_cfg) | {"renderer": resolve_renderer(env_cfg.renderer)}
        meta |= {"look": d.look} if d.look != "own" else {}
        with WriterProcess(path, cfg.env.image_size, cfg.env.frame_stack, meta) as w:
            obs, infos = vec.reset(seed=env_seed)
            # One per-env info dict per vector step, shared by start() and act(): the planner recognises the
            # reset info it started from and does not plan the episode twice.
            env_infos = [_env_info(infos, j) for j in range(n_envs)]
            for j in range(n_envs):
                start(j, env_infos[j])
            actions = np.zeros((n_envs, 3), np.float32)
            while written < n_new:
                snaps: list[dict | None] = [None] * n_envs
                actions[:] = 0.0  # ignored for idle envs and for envs about to be reset
                for j in range(n_envs):
                    b = behaviours[j]
                    if b is not None and not pending_reset[j]:
                        actions[j] = b.act({k: v[j] for k, v in obs.items()}, env_infos[j])
                        snaps[j] = _snapshot(obs, j)
                obs, rewards, term, trunc, infos = vec.step(actions)
                env_infos = [_env_info(infos, j) for j in range(n_envs)]
                for j in range(n_envs):
                    if pending_reset[j]:  # NEXT_STEP autoreset: this is the reset obs/info of a new episode
                        pending_reset[j] = False
                        start(j, env_infos[j])
                        continue
                    snap, buf = snaps[j], buffers[j]
                    if snap is None or buf is None:
                        continue
                    end = bool(term[j] or trunc[j])
                    buf.add(snap, actions[j].copy(), float(rewards[j]), end)
                    if not end:
                        continue
                    pending_reset[j] = True
                    src = sources[episode_of[j]]
                    m = env_infos[j].get("metrics", {})
                    kind = "success" if m.get("success") else "collision" if term[j] else "timeout"
                    o = outcomes.setdefault(src, {"success": 0, "collision": 0, "timeout": 0})
                    o[kind] += 1
                    finished[episode_of[j]] = (buf, seeds[j], src)
                    behaviours[j] = buffers[j] = None
                    # Write in start order so file episode i has source sources[i] (see module docstring).
                    while written in finished:
                        b_, seed_, src_ = finished.pop(written)
                        w.add_episode(**b_.arrays(), scene=d.scene, seed=seed_, source=src_)
                        per_source[src_] = per_source.get(src_, 0) + 1
                        steps_added += len(b_)
                        written += 1
                        bar.update(1)
    finally:
        bar.close()
        vec.close()
    return CollectResult(
        path,
        have + written,
        written,
        steps_added,
        per_source,
        outcomes,
        time.perf_counter() - t_start,
    )


def summarize(path: str | Path, sources: Sequence[str] = SOURCES) -> dict:
    """Dataset summary for reports: :meth:`TrajectoryDataset.summary` plus outcome counts per source.

    Returns ``{..., "outcomes": {source: {"success", "collision", "timeout"}}, "success_rate": {source: x}}``.
    """
    with open_dataset(path) as ds:
        s = ds.summary()
        oc = episode_outcomes(ds)
        per: dict[str, dict[str, int]] = {}
        for src, o in zip(ds.sources, oc):
            c = per.setdefault(src, {"success": 0, "collision": 0, "timeout": 0})
            c[o] += 1
    s["outcomes"] = per
    s["success_rate"] = {k: v["success"] / max(1, sum(v.values())) for k, v in per.items()}
    return s
