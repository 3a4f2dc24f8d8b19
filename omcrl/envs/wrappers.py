"""Wrappers that fit :class:`~omcrl.envs.NavEnv` to other libraries' conventions."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class SB3Wrapper(gym.ObservationWrapper):
    """NavEnv as Stable-Baselines3 expects it: what the visuomotor policy sees, as an image and a vector.

    Observation: ``{"image": (3L, H, W) uint8`` — the RGB stack, channel-first (L frames oldest first, each
    RGB), which SB3 recognises as an image and feeds to its CNN — ``"state": (12,) float32}`` (v, ω, θ,
    Δp_goal). The privileged depth and obstacle vectors are dropped: an SB3 policy gets the same inputs as the
    kit's visuomotor methods. Use it with ``MultiInputPolicy``; SB3 needs images of at least 36 px.

    Example
    -------
    >>> from stable_baselines3 import PPO                                    # doctest: +SKIP
    >>> env = SB3Wrapper(make_env("box", image_size=64))                    # doctest: +SKIP
    >>> PPO("MultiInputPolicy", env).learn(10_000)                           # doctest: +SKIP
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        rgb = env.observation_space["rgb"]
        frames, c, h, w = rgb.shape
        self.observation_space = spaces.Dict(
            {
                "image": spaces.Box(0, 255, (frames * c, h, w), np.uint8),
                "state": env.observation_space["state"],
            }
        )

    def observation(self, observation: dict[str, Any]) -> dict[str, np.ndarray]:
        rgb = np.asarray(observation["rgb"])
        return {"image": rgb.reshape(-1, *rgb.shape[-2:]), "state": np.asarray(observation["state"], np.float32)}
