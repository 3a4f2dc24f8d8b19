"""Evaluation runner: roll a policy (learned or planner) for N episodes in one scene, one row per episode."""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from omcrl.agent import start_episode
from omcrl.eval.metrics import REQUIRED
from omcrl.utils.progress import Progress
from omcrl.utils.runtime import cpu_count, exit_with_parent, set_threads

# Per-episode fields kept from ``info["metrics"]``: what summarize() needs plus where the episode came from.
METRIC_FIELDS = (*REQUIRED, "out_of_arena", "scene", "seed")


def eval_seeds(episodes: int, seed: int, seed_offset: int) -> list[int]:
    """Episode seeds ``seed_offset + seed * episodes + i``: disjoint from training (which resets with seeds
    ``< seed_offset``) and from other evaluation seeds for ``episodes`` fixed."""
    return [seed_offset + seed * episodes + i for i in range(episodes)]


def evaluate(
    policy: Any,
    scene: str,
    episodes: int,
    seed: int = 0,
    *,
    seed_offset: int = 1_000_000,
    method: str | None = None,
    checkpoint: str | None = None,
    make_env: Callable[..., Any] | None = None,
    progress: bool = False,
    workers: int | EvalPool = 1,
    lanes: int = 1,
    **env_kwargs: Any,
) -> pd.DataFrame:
    """Run ``episodes`` deterministic episodes of ``policy`` in ``scene``.

    Parameters
    ----------
    policy : anything with ``act(obs, info) -> action (3,)`` (a :class:`omcrl.rl.Policy`, a planner). If it
        has ``bind(env)`` it is bound to the evaluation env once (HybridAPF then replans on the true map with
        its safety margin); if it has ``reset`` it is called before each episode with the reset info (see
        :func:`start_episode`).
    scene : one of ``omcrl.envs.SCENES``.
    episodes : number of episodes; episode ``i`` resets with seed ``seed_offset + seed * episodes + i``
        (pass ``cfg.eval.seed_offset``), so evaluation never reuses training layouts.
    method, checkpoint : labels stored in every row (default: ``policy.name`` / ``policy.checkpoint``).
    make_env : ``(scene, seed=..., **env_kwargs) -> env``; default ``omcrl.envs.make_env``.
    workers : processes that run episodes in parallel (1: in this process), or an open :class:`EvalPool` to
        reuse across calls. Every episode is reset with its own seed and the policy is deterministic, so the
        rows are identical for any number of workers (tested).
    lanes : envs that each process steps in lock-step, with one batched forward of the policy per step
        (``policy.act_batch``); policies without ``act_batch`` (planners) step one env. A batched forward
        amortises the encoder's weights over the lanes, but rounds differently from a forward of one
        observation (action means differ by ~1e-8), so rows can depend on ``lanes``; they never depend on
        ``workers``: episodes are grouped into the same chunks and lanes in this process as in a pool.
    env_kwargs : forwarded to ``make_env`` (``image_size``, ``config``, ``disturbance``, ...). A policy whose
        ``uses_camera`` is False flies the default env with ``camera=False`` (no frames rendered; the same rows).

    Returns
    -------
    DataFrame, one row per episode in episode order: the env's ``info["metrics"]`` fields (final_distance,
    min_distance, success, collision, path_length, optimal_path_length, steps, scene, seed) plus ``method``,
    ``checkpoint``, ``eval_seed``, ``episode``, ``return`` and ``trajectory`` (list of (x, y) from
    ``info["pose"]``, m).
    """
    seeds = eval_seeds(episodes, seed, seed_offset)
    method = method if method is not None else getattr(policy, "name", type(policy).__name__)
    checkpoint = checkpoint if checkpoint is not None else getattr(policy, "checkpoint", "")
    labels = {"method": method, "checkpoint": str(checkpoint)}
    lanes = int(lanes)
    if lanes < 1:
        raise ValueError(f"lanes must be >= 1, got {lanes}")
    if not callable(getattr(policy, "act_batch", None)):
        lanes = 1  # planners keep per-episode state: one env each
    if make_env is None and not getattr(policy, "uses_camera", True):
        # A pilot that never reads a frame (HybridAPF, the blind pilot) flies the same episodes without them: the
        # renders were ~70 % of its time.
        env_kwargs = {**env_kwargs, "camera": False}
    job = (policy, scene, make_env, env_kwargs, labels, lanes)
    desc = f"eval/{method}/{scene}"
    if isinstance(workers, EvalPool):
        return workers.run(job, seeds, desc, progress)
    if workers > 1 and episodes > 1:
        with EvalPool(workers) as pool:
            return pool.run(job, seeds, desc, progress)
    with Progress(episodes, desc, unit="ep", enabled=progress) as bar:
        return pd.DataFrame(_episodes(job, list(enumerate(seeds)), on_episode=bar.update))


# Episodes per task handed to a worker: small enough to balance episodes of unequal length and to move the
# progress bar, large enough that sending the policy with each task costs little. With ``lanes`` > 1 a
# chunk is also the group of episodes that share batched forwards (at least ``lanes`` episodes).
_CHUNK = 4


def _chunks(items: list, lanes: int) -> list[list]:
    size = max(_CHUNK, lanes)
    return [items[lo : lo + size] for lo in range(0, len(items), size)]


# A worker keeps its envs between tasks of the same scene and env arguments (making one costs ~0.1-0.5 s);
# every episode is reset with its own seed, so what ran in an env before does not matter.
_WORKER: dict[str, Any] = {"in_worker": False, "key": None, "envs": []}


def _worker_envs(scene: str, make_env: Callable[..., Any] | None, env_kwargs: dict, seed: int, n: int) -> list:
    import pickle

    key = pickle.dumps((scene, make_env, env_kwargs))
    if _WORKER["key"] != key:
        for env in _WORKER["envs"]:
            env.close()
        _WORKER["envs"], _WORKER["key"] = [], key  # an env that fails to build is built again next time
    while len(_WORKER["envs"]) < n:
        _WORKER["envs"].append(_make(scene, make_env, env_kwargs, seed))
    return _WORKER["envs"][:n]


def _make(scene: str, make_env: Callable[..., Any] | None, env_kwargs: dict, seed: int) -> Any:
    if make_env is None:
        # PyBullet loads in the worker that flies, not with omcrl.eval: the tables, the summary and the
        # notebooks read results through this package, and PyBullet would add ~1.8 s to each of them.
        from omcrl.envs.nav_env import make_env as make_scene_env

        make_env = make_scene_env
    return make_env(scene, seed=seed, **env_kwargs)


def _episodes(job: tuple, items: list[tuple[int, int]], on_episode: Callable[[], Any] | None = None) -> list[dict]:
    """Rows of the episodes ``items`` = [(episode index, reset seed)] of ``job``, in episode order.

    Items run chunk by chunk (:func:`_chunks`); within a chunk ``lanes`` envs step in lock-step, each taking the
    chunk's next episode when its own ends, with one ``act_batch`` over the running lanes per step.
    """
    policy, scene, make_env, env_kwargs, labels, lanes = job
    pooled = _WORKER["in_worker"]
    n = min(lanes, len(items))
    if pooled:
        envs = _worker_envs(scene, make_env, env_kwargs, items[0][1], n)
    else:
        envs = [_make(scene, make_env, env_kwargs, items[0][1]) for _ in range(n)]
    rows: list[dict] = []
    try:
        for chunk in _chunks(items, lanes):
            rows += _chunk_episodes(policy, scene, labels, envs[: min(n, len(chunk))], chunk, on_episode)
    finally:
        if not pooled:
            for env in envs:
                env.close()
    return sorted(rows, key=lambda r: r["episode"])


class _Lane:
    """One env's running episode: what a row needs when it ends."""

    def __init__(self, env: Any, item: tuple[int, int], policy: Any) -> None:
        self.env, (self.i, self.seed) = env, item
        if hasattr(policy, "bind"):
            policy.bind(env)
        self.obs, self.info = env.reset(seed=self.seed)
        start_episode(policy, self.info)
        self.traj = [_xy(self.info)] if "pose" in self.info else []
        self.total = 0.0

    def step(self, action: np.ndarray) -> bool:
        """Step the env; True when the episode ended."""
        self.obs, reward, term, trunc, self.info = self.env.step(np.asarray(action, dtype=np.float32))
        self.total += float(reward)
        if "pose" in self.info:
            self.traj.append(_xy(self.info))
        return bool(term or trunc)

    def row(self, scene: str, labels: dict) -> dict:
        m = self.info.get("metrics")
        if m is None:
            raise RuntimeError(f"env for scene {scene!r} ended an episode without info['metrics']")
        row = {k: m.get(k) for k in METRIC_FIELDS}
        row.update(**labels, eval_seed=self.seed, episode=self.i, **{"return": self.total}, trajectory=self.traj)
        return row


def _chunk_episodes(
    policy: Any, scene: str, labels: dict, envs: list, chunk: list, on_episode: Callable[[], Any] | None
) -> list[dict]:
    queue, rows = list(chunk), []
    lanes: list[_Lane | None] = [_Lane(env, queue.pop(0), policy) for env in envs]
    while any(lane is not None for lane in lanes):
        live = [lane for lane in lanes if lane is not None]
        if len(envs) == 1:  # one env: the unbatched call, bit for bit what a lone episode gets
            actions = [policy.act(live[0].obs, live[0].info)]
        else:
            actions = list(policy.act_batch(_stack([lane.obs for lane in live]), [lane.info for lane in live]))
        for lane, action in zip(live, actions):
            if lane.step(action):
                rows.append(lane.row(scene, labels))
                if on_episode is not None:
                    on_episode()
                j = lanes.index(lane)
                lanes[j] = _Lane(lane.env, queue.pop(0), policy) if queue else None
    return rows


def _init_worker(parent: int) -> None:
    # First, importing nothing (a child can hang in its first import, and importing torch below takes seconds on a
    # loaded machine): a worker must not outlive its parent (a killed evaluation left ~540 MB workers running).
    exit_with_parent(parent)
    # One torch thread per worker: the workers already use every core between them.
    set_threads(1)
    _WORKER["in_worker"] = True


class EvalPool:
    """Worker processes that run evaluation episodes in parallel (``with EvalPool(n) as pool: ...``).

    Reuse one pool across methods and scenes. Workers are forked where the platform can (Linux), as torch's
    DataLoader does, and run torch with one thread (a forked child must not use the parent's thread pool);
    forking needs no ``if __name__ == "__main__"`` guard in the caller's script. Elsewhere they are spawned.
    The policy, the env factory and its arguments travel to the workers pickled in memory (never through a
    file), so they must be picklable: a lambda ``make_env`` is not, and gets a clear error before any episode
    runs.

    Parameters
    ----------
    workers : processes; 0 means one per core (:func:`omcrl.utils.runtime.cpu_count`).
    """

    def __init__(self, workers: int = 0) -> None:
        self.workers = int(workers) or cpu_count()
        self._ex: Any = None

    def __enter__(self) -> EvalPool:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
        self._ex = ProcessPoolExecutor(
            self.workers, mp_context=mp.get_context(method), initializer=_init_worker, initargs=(os.getpid(),)
        )
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        if self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=True)
            self._ex = None

    def run(self, job: tuple, seeds: list[int], desc: str, progress: bool) -> pd.DataFrame:
        """Rows of every episode of ``job`` (see :func:`evaluate`), in episode order."""
        import pickle

        if self._ex is None:
            raise RuntimeError("EvalPool is not open: use it as a context manager")
        try:
            pickle.dumps(job)
        except Exception as e:
            raise TypeError(
                f"{desc}: the policy, make_env and env arguments must be picklable to run in worker processes "
                f"({e}); pass workers=1 to evaluate in this process"
            ) from e
        items = list(enumerate(seeds))
        chunks = _chunks(items, job[-1])
        futures = [self._ex.submit(_episodes, job, c) for c in chunks]
        rows: list[dict] = []
        with Progress(len(items), desc, unit="ep", enabled=progress) as bar:
            for fut, c in zip(futures, chunks):  # in order: the bar lags a little, the rows need no sorting
                rows += fut.result()
                bar.update(len(c))
        return pd.DataFrame(rows)


def _stack(obs: list) -> Any:
    """Observations of the lanes -> one batched observation (a dict of (N, ...) arrays, or an (N, ...) array)."""
    if isinstance(obs[0], dict):
        return {k: np.stack([o[k] for o in obs]) for k in obs[0]}
    return np.stack(obs)


def _xy(info: dict) -> tuple[float, float]:
    p = info["pose"]
    return float(p[0]), float(p[1])
