"""Evaluation runner: roll a policy (learned or planner) for N episodes in one scene, one row per episode."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from omcrl.eval.metrics import REQUIRED
from omcrl.utils.progress import track

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
    env_kwargs : forwarded to ``make_env`` (``image_size``, ``config``, ``disturbance``, ...).

    Returns
    -------
    DataFrame, one row per episode: the env's ``info["metrics"]`` fields (final_distance, min_distance,
    success, collision, path_length, optimal_path_length, steps, scene, seed) plus ``method``, ``checkpoint``,
    ``eval_seed``, ``episode``, ``return`` and ``trajectory`` (list of (x, y) from ``info["pose"]``, m).
    """
    if make_env is None:
        from omcrl.envs import make_env
    seeds = eval_seeds(episodes, seed, seed_offset)
    env = make_env(scene, seed=seeds[0], **env_kwargs)
    if hasattr(policy, "bind"):
        policy.bind(env)
    method = method if method is not None else getattr(policy, "name", type(policy).__name__)
    checkpoint = checkpoint if checkpoint is not None else getattr(policy, "checkpoint", "")
    rows = []
    it = track(range(episodes), episodes, desc=f"eval/{method}/{scene}", unit="ep", enabled=progress)
    try:
        for i in it:
            obs, info = env.reset(seed=seeds[i])
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
            row.update(
                method=method,
                checkpoint=str(checkpoint),
                eval_seed=seeds[i],
                episode=i,
                **{"return": total},
                trajectory=traj,
            )
            rows.append(row)
    finally:
        env.close()
    return pd.DataFrame(rows)


def _xy(info: dict) -> tuple[float, float]:
    p = info["pose"]
    return float(p[0]), float(p[1])
