"""Checks of an exported model against its torch policy: parity on recorded observations, evaluation parity."""

from __future__ import annotations

from typing import Any

import numpy as np

from omcrl.envs import make_env


def record_observations(policy: Any, env_config: Any, n: int, seed: int = 0, scene: str = "box") -> list[dict]:
    """``n`` observations met while ``policy`` flies in ``scene`` (episodes from evaluation-range seeds).

    Returns a list of ``{"rgb": (L, 3, H, W) uint8, "state": (12,) float32}`` copies.
    """

    env = make_env(scene, seed=seed, config=env_config)
    out: list[dict] = []
    try:
        episode = 0
        while len(out) < n:
            obs, info = env.reset(seed=1_000_000 + seed * 10_000 + episode)
            done = False
            while not done and len(out) < n:
                out.append({"rgb": obs["rgb"].copy(), "state": obs["state"].copy()})
                obs, _, term, trunc, info = env.step(policy.act(obs, info))
                done = term or trunc
            episode += 1
    finally:
        env.close()
    return out


def parity(onnx_policy: Any, torch_policy: Any, observations: list[dict]) -> dict[str, float]:
    """Max and mean absolute difference between the two policies' actions over ``observations``."""
    d = np.array([np.abs(onnx_policy.act(o) - torch_policy.act(o)).max() for o in observations])
    return {"observations": len(d), "max_abs_diff": float(d.max()), "mean_abs_diff": float(d.mean())}
