"""Vector envs: env 0 steps in the calling process, the others in AsyncVectorEnv workers, in parallel.

gymnasium's AsyncVectorEnv runs every env in a worker and the calling process waits. On a small machine (2
cores, microVM) each step then pays a pipe round trip plus two process wake-ups (~0.9 ms measured against a
~2.9 ms step at 64 px), and the caller's core idles while it waits. :class:`SplitVectorEnv` sends the actions
to the workers first, steps env 0 itself meanwhile, then collects the workers' results, so the wait overlaps
useful work (see ``python -m omcrl.bench env``). Semantics are gymnasium 1.x's: NEXT_STEP autoreset (the step
after an episode ends returns the reset observation, its action is ignored; ``info["metrics"]`` arrives with
the step that ended the episode) and infos batched as arrays with ``_key`` masks.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector.utils import batch_space

from omcrl.envs.nav_env import make_env

# How long a waiting process spins on its pipe before blocking. A blocked process lets its vCPU halt, and
# waking it again is what costs most of a pipe round trip in a microVM; the spin covers the usual turnaround
# (one env step, ~3 ms at 64 px) and gives the core back quickly when nothing comes (during PPO updates).
SPIN_SECONDS = 0.005


def _spin_until_ready(conn: Any, seconds: float = SPIN_SECONDS) -> None:
    import time

    end = time.perf_counter() + seconds
    while not conn.poll(0) and time.perf_counter() < end:
        pass


class _SpinPipe:
    """A worker's pipe whose ``recv`` spins briefly before blocking (see ``SPIN_SECONDS``)."""

    def __init__(self, conn: Any) -> None:
        self._conn = conn

    def recv(self) -> Any:
        _spin_until_ready(self._conn)
        return self._conn.recv()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._conn, name)


def _spin_worker(index, env_fn, pipe, parent_pipe, shared_memory, error_queue, autoreset_mode, semaphore):
    """gymnasium's ``_async_worker`` with a spinning pipe; everything else is unchanged."""
    from gymnasium.vector.async_vector_env import _async_worker

    _async_worker(index, env_fn, _SpinPipe(pipe), parent_pipe, shared_memory, error_queue, autoreset_mode, semaphore)


def _factory(scene: str, seed: int, kwargs: dict) -> Any:
    def thunk() -> gym.Env:
        # Each worker is its own process with one core at most: keep its BLAS/torch single-threaded.
        import os

        os.environ.setdefault("OMP_NUM_THREADS", "1")
        return make_env(scene, seed=seed, **kwargs)

    return thunk


def _concat_obs(a: Any, b: Any) -> Any:
    if isinstance(a, dict):
        return {k: np.concatenate([a[k], b[k]]) for k in a}
    return np.concatenate([a, b])


def _merge_infos(a: dict, na: int, b: dict, nb: int) -> dict:
    """Merge batched infos of two vector envs (``na`` then ``nb`` envs) into one batched info dict."""
    out: dict = {}
    for key in list(a) + [k for k in b if k not in a]:
        va, vb = a.get(key), b.get(key)
        ref = va if va is not None else vb
        if isinstance(ref, dict):
            out[key] = _merge_infos(va or {}, na, vb or {}, nb)
            continue
        ref = np.asarray(ref)
        if ref.dtype == object or (
            va is not None and vb is not None and np.asarray(va).shape[1:] != np.asarray(vb).shape[1:]
        ):
            arr = np.empty(na + nb, dtype=object)
            arr[:] = None
        else:
            arr = np.zeros((na + nb, *ref.shape[1:]), dtype=ref.dtype)
        if va is not None:
            _fill(arr, slice(0, na), va)
        if vb is not None:
            _fill(arr, slice(na, na + nb), vb)
        out[key] = arr
    return out


def _fill(arr: np.ndarray, where: slice, values: Any) -> None:
    if arr.dtype == object:
        for i, v in zip(range(where.start, where.stop), values):
            arr[i] = v
    else:
        arr[where] = values


class _OneEnvInfo:
    """Batches one env's info exactly like a 1-env gymnasium vector env (``VectorEnv._add_info``)."""

    num_envs = 1
    _add_info = gym.vector.VectorEnv._add_info


class SplitVectorEnv(gym.vector.VectorEnv):
    """``n`` envs: env 0 stepped directly in this process, envs 1..n-1 in an AsyncVectorEnv.

    Env 0 follows the same NEXT_STEP autoreset rule as gymnasium's vector envs (the step after an episode
    ends resets it, with reward 0 and no flags) and its info is batched with gymnasium's own ``_add_info``,
    so results equal ``SyncVectorEnv``'s exactly (``tests/test_envs.py``). Stepping it without a
    SyncVectorEnv wrapper saves ~0.2 ms of bookkeeping per step, which is ~6% at 64 px.

    Parameters
    ----------
    env_fns : ``n >= 2`` zero-argument env constructors.
    """

    def __init__(self, env_fns: list) -> None:
        if len(env_fns) < 2:
            raise ValueError(f"SplitVectorEnv needs at least 2 envs, got {len(env_fns)}")
        # copy=False: the workers' observations are concatenated into fresh arrays right away.
        self.remote = gym.vector.AsyncVectorEnv(
            env_fns[1:], shared_memory=True, copy=False, context="fork", worker=_spin_worker
        )
        self.local = env_fns[0]()
        self._autoreset = False
        self._batch = _OneEnvInfo()
        self.num_envs = len(env_fns)
        self.metadata = dict(self.remote.metadata)
        self.single_observation_space = self.local.observation_space
        self.single_action_space = self.local.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self.closed = False

    def reset(self, *, seed: int | list | None = None, options: dict | None = None) -> tuple[Any, dict]:
        if isinstance(seed, int):
            seed = [seed + i for i in range(self.num_envs)]
        s_local, s_remote = (seed[0], seed[1:]) if seed is not None else (None, None)
        self.remote.reset_async(seed=s_remote, options=options)
        lo, li = self.local.reset(seed=s_local, options=options)
        self._autoreset = False
        ro, ri = self.remote.reset_wait()
        return _concat_obs(_one(lo), ro), _merge_infos(self._batch._add_info({}, li, 0), 1, ri, self.num_envs - 1)

    def step(self, actions: np.ndarray) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict]:
        actions = np.asarray(actions)
        self.remote.step_async(actions[1:])
        if self._autoreset:
            lo, li = self.local.reset()
            lr, lt, ltr = 0.0, False, False
        else:
            lo, lr, lt, ltr, li = self.local.step(actions[0])
        self._autoreset = bool(lt or ltr)
        for conn in self.remote.parent_pipes:
            _spin_until_ready(conn)
        ro, rr, rt, rtr, ri = self.remote.step_wait()
        return (
            _concat_obs(_one(lo), ro),
            np.concatenate([np.array([lr], np.float64), rr]),
            np.concatenate([np.array([lt], np.bool_), rt]),
            np.concatenate([np.array([ltr], np.bool_), rtr]),
            _merge_infos(self._batch._add_info({}, li, 0), 1, ri, self.num_envs - 1),
        )

    def close_extras(self, **kwargs: Any) -> None:
        self.local.close()
        self.remote.close(**kwargs)


def _one(obs: Any) -> Any:
    """A single env's observation with a leading batch axis of 1."""
    if isinstance(obs, dict):
        return {k: np.asarray(v)[None] for k, v in obs.items()}
    return np.asarray(obs)[None]


def make_vec_env(
    scene: str, n_envs: int, seed: int = 0, asynchronous: bool = True, **env_kwargs: Any
) -> gym.vector.VectorEnv:
    """``n_envs`` copies of ``make_env(scene, ...)``; env i is seeded with ``seed + i``.

    ``asynchronous=True`` (default) runs them in parallel with :class:`SplitVectorEnv` (env 0 in this
    process, the rest in worker processes); ``False`` gives a SyncVectorEnv (one process, same semantics),
    useful for debugging. One env is always a SyncVectorEnv.
    """
    if n_envs < 1:
        raise ValueError(f"n_envs: got {n_envs}, expected >= 1")
    fns = [_factory(scene, seed + i, env_kwargs) for i in range(n_envs)]
    if asynchronous and n_envs > 1:
        return SplitVectorEnv(fns)
    return gym.vector.SyncVectorEnv(fns)
