"""PyBullet world: scenes -> drone -> camera -> NavEnv (gymnasium) -> vector envs, wrappers.

Importing this package registers the gymnasium ids ``omcrl/Box-v0``, ``omcrl/Furniture-v0``, ``omcrl/Barrier-v0``
and ``omcrl/Tree-v0``: ``gymnasium.make("omcrl/Tree-v0", image_size=64)`` takes :class:`NavEnv`'s keyword
arguments.
"""

import gymnasium as _gym

from omcrl.envs.nav_env import Disturbance, NavEnv, make_env
from omcrl.envs.scenes import SCENES
from omcrl.envs.vec import make_vec_env
from omcrl.envs.wrappers import SB3Wrapper

GYM_IDS = {scene: f"omcrl/{scene.capitalize()}-v0" for scene in SCENES}
for _scene, _id in GYM_IDS.items():
    if _id not in _gym.registry:
        # No TimeLimit wrapper: the env truncates at its own max_steps (a config field).
        _gym.register(id=_id, entry_point="omcrl.envs.nav_env:NavEnv", kwargs={"scene": _scene})

__all__ = ["GYM_IDS", "SCENES", "Disturbance", "NavEnv", "SB3Wrapper", "make_env", "make_vec_env"]
