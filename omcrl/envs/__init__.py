"""PyBullet world: scene specs -> drone -> camera -> NavEnv (gymnasium) -> vector envs, wrappers.

Importing this package registers a Gymnasium id for every scene of :mod:`omcrl.scenes`
(``omcrl/Box-v0``, ``omcrl/Furniture-v1``, ``omcrl/Furniture-v0``, ``omcrl/Barrier-v0``, ``omcrl/Tree-v0``):
``gymnasium.make("omcrl/Tree-v0", image_size=64)`` takes :class:`NavEnv`'s keyword arguments. The env classes
load on first use, so the scene registry (which the config validates against) does not load PyBullet.
"""

from __future__ import annotations

import importlib
from typing import Any

import gymnasium as _gym

from omcrl.scenes import PAPER_SUITE, SCENE_SPECS, SCENES, STRESS_SCENES, SceneSpec, scene_id, scene_spec

GYM_IDS = {spec.id: spec.gym_id for spec in SCENE_SPECS.values()}
for _scene, _id in GYM_IDS.items():
    if _id not in _gym.registry:
        # No TimeLimit wrapper: the env truncates at its own max_steps (a config field).
        _gym.register(id=_id, entry_point="omcrl.envs.nav_env:NavEnv", kwargs={"scene": _scene})

_LAZY = {
    "Disturbance": "omcrl.envs.nav_env",
    "NavEnv": "omcrl.envs.nav_env",
    "make_env": "omcrl.envs.nav_env",
    "make_vec_env": "omcrl.envs.vec",
    "SB3Wrapper": "omcrl.envs.wrappers",
}


def __getattr__(name: str) -> Any:
    # PEP 562: PyBullet, OpenCV and SciPy load with the env classes, not with the scene registry (0.4 s).
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'omcrl.envs' has no attribute {name!r}")


__all__ = [
    "GYM_IDS",
    "PAPER_SUITE",
    "SCENES",
    "SCENE_SPECS",
    "STRESS_SCENES",
    "Disturbance",
    "NavEnv",
    "SB3Wrapper",
    "SceneSpec",
    "make_env",
    "make_vec_env",
    "scene_id",
    "scene_spec",
]
