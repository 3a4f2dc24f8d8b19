"""PyBullet world: scenes -> drone -> camera -> NavEnv (gymnasium) -> vector envs."""

from omcrl.envs.nav_env import Disturbance, NavEnv, make_env
from omcrl.envs.scenes import SCENES
from omcrl.envs.vec import make_vec_env

__all__ = ["SCENES", "Disturbance", "NavEnv", "make_env", "make_vec_env"]
