"""Vector envs over gymnasium's AsyncVectorEnv (one process per worker, shared-memory observations)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from omcrl.envs.nav_env import make_env


def _factory(scene: str, seed: int, kwargs: dict) -> Any:
    def thunk() -> gym.Env:
        # Each worker is its own process with one core at most: keep its BLAS/torch single-threaded.
        import os

        os.environ.setdefault("OMP_NUM_THREADS", "1")
        return make_env(scene, seed=seed, **kwargs)

    return thunk


def make_vec_env(
    scene: str, n_envs: int, seed: int = 0, asynchronous: bool = True, **env_kwargs: Any
) -> gym.vector.VectorEnv:
    """``n_envs`` copies of ``make_env(scene, ...)``; worker i is seeded with ``seed + i``.

    Autoreset follows gymnasium 1.x's default ``NEXT_STEP`` mode: the step after an episode ends returns the
    reset observation (its action is ignored) and ``info["metrics"]`` arrives with the step that ended it.
    ``asynchronous=False`` gives a SyncVectorEnv (same semantics, one process), useful for debugging.
    """
    if n_envs < 1:
        raise ValueError(f"n_envs: got {n_envs}, expected >= 1")
    fns = [_factory(scene, seed + i, env_kwargs) for i in range(n_envs)]
    if asynchronous:
        # copy=False: observations are views of the shared buffers; the caller consumes them before the next
        # step (rollouts convert to tensors at once), which saves a full copy of every image batch.
        return gym.vector.AsyncVectorEnv(fns, shared_memory=True, copy=False, context="fork")
    return gym.vector.SyncVectorEnv(fns)
