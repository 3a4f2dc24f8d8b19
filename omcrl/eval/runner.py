"""Evaluation runner: roll a policy (learned or planner) for N episodes in one scene, one row per episode."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from omcrl.eval.metrics import REQUIRED
from omcrl.utils.progress import Progress

# Per-episode fields kept from ``info["metrics"]``: what summarize() needs plus where the episode came from.
METRIC_FIELDS = (*REQUIRED, "out_of_arena", "scene", "seed")


def start_episode(agent: Any, info: dict) -> None:
    """Tell a policy or planner that a new episode starts, handing over the reset ``info`` if it takes it.

    ``agent.reset(info)`` when its ``reset`` accepts a positional argument (e.g. :class:`omcrl.planners.HybridAPF`,
    which needs the episode's ``pose``, ``goal`` and ``path``), ``agent.reset()`` when it takes none (stateless
    policies), nothing when there is no ``reset``. Shared by :func:`evaluate` and the planner guide of the RL
    trainers, so a planner behaves the same in evaluation and as an NPE guide.
    """
    reset = getattr(agent, "reset", None)
    if reset is None:
        return
    try:
        params = inspect.signature(reset).parameters.values()
    except (TypeError, ValueError):  # builtins without a signature: call without the info
        params = []
    P = inspect.Parameter
    if any(p.kind in (P.POSITIONAL_ONLY, P.POSITIONAL_OR_KEYWORD, P.VAR_POSITIONAL) for p in params):
        reset(info)
    else:
        reset()


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
    env_kwargs : forwarded to ``make_env`` (``image_size``, ``config``, ``disturbance``, ...).

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
    job = (policy, scene, make_env, env_kwargs, labels)
    desc = f"eval/{method}/{scene}"
    if isinstance(workers, EvalPool):
        return workers.run(job, seeds, desc, progress)
    if workers > 1 and episodes > 1:
        with EvalPool(workers) as pool:
            return pool.run(job, seeds, desc, progress)
    with Progress(episodes, desc, unit="ep", enabled=progress) as bar:
        return pd.DataFrame(_episodes(job, list(enumerate(seeds)), on_episode=bar.update))


# Episodes per task handed to a worker: small enough to balance episodes of unequal length and to move the
# progress bar, large enough that sending the policy with each task costs little.
_CHUNK = 4


# A worker keeps its env between tasks of the same scene and env arguments (making one costs ~0.1-0.5 s);
# every episode is reset with its own seed, so what ran in the env before does not matter.
_WORKER: dict[str, Any] = {"in_worker": False, "key": None, "env": None}


def _worker_env(scene: str, make_env: Callable[..., Any] | None, env_kwargs: dict, seed: int) -> Any:
    import pickle

    key = pickle.dumps((scene, make_env, env_kwargs))
    if _WORKER["key"] != key:
        if _WORKER["env"] is not None:
            _WORKER["env"].close()
        _WORKER["env"], _WORKER["key"] = None, None
        _WORKER["env"] = _make(scene, make_env, env_kwargs, seed)
        _WORKER["key"] = key
    return _WORKER["env"]


def _make(scene: str, make_env: Callable[..., Any] | None, env_kwargs: dict, seed: int) -> Any:
    if make_env is None:
        from omcrl.envs import make_env
    return make_env(scene, seed=seed, **env_kwargs)


def _episodes(job: tuple, items: list[tuple[int, int]], on_episode: Callable[[], Any] | None = None) -> list[dict]:
    """Rows of the episodes ``items`` = [(episode index, reset seed)] of ``job``, in one env."""
    policy, scene, make_env, env_kwargs, labels = job
    pooled = _WORKER["in_worker"]
    env = (_worker_env if pooled else _make)(scene, make_env, env_kwargs, items[0][1])
    if hasattr(policy, "bind"):
        policy.bind(env)
    rows = []
    try:
        for i, s in items:
            obs, info = env.reset(seed=s)
            start_episode(policy, info)
            traj = [_xy(info)] if "pose" in info else []
            total, done = 0.0, False
            while not done:
                action = np.asarray(policy.act(obs, info), dtype=np.float32)
                obs, reward, term, trunc, info = env.step(action)
                total += float(reward)
                if "pose" in info:
                    traj.append(_xy(info))
                done = bool(term or trunc)
            m = info.get("metrics")
            if m is None:
                raise RuntimeError(f"env for scene {scene!r} ended an episode without info['metrics']")
            row = {k: m.get(k) for k in METRIC_FIELDS}
            row.update(**labels, eval_seed=s, episode=i, **{"return": total}, trajectory=traj)
            rows.append(row)
            if on_episode is not None:
                on_episode()
    finally:
        if not pooled:
            env.close()
    return rows


def _init_worker() -> None:
    # One torch thread per worker: the workers already use every core between them.
    from omcrl.utils.runtime import set_threads

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
        from omcrl.utils.runtime import cpu_count

        self.workers = int(workers) or cpu_count()
        self._ex: Any = None

    def __enter__(self) -> EvalPool:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
        self._ex = ProcessPoolExecutor(self.workers, mp_context=mp.get_context(method), initializer=_init_worker)
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
        chunks = [items[lo : lo + _CHUNK] for lo in range(0, len(items), _CHUNK)]
        futures = [self._ex.submit(_episodes, job, c) for c in chunks]
        rows: list[dict] = []
        with Progress(len(items), desc, unit="ep", enabled=progress) as bar:
            for fut, c in zip(futures, chunks):  # in order: the bar lags a little, the rows need no sorting
                rows += fut.result()
                bar.update(len(c))
        return pd.DataFrame(rows)


def _xy(info: dict) -> tuple[float, float]:
    p = info["pose"]
    return float(p[0]), float(p[1])
