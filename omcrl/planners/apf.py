"""Hybrid APF: global shortest path on the privileged map + artificial potential field local control.

The paper's classical baseline (Hybrid APF, [pan2021improved]) and our scripted pilot for data collection.
It has privileged access: the global path comes from the occupancy map of the true scene (the env hands the
any-angle shortest path over in the reset ``info["path"]``; with ``bind(env)`` it replans on the map with its
own safety margin), and the repulsive field uses the true nearest obstacle point (``obs["privileged"][:3]``).
Local control follows a carrot on the path under an attractive pull plus a repulsive push (Khatib's
``k (1/d - 1/d0) / d^2`` law), so it keeps the classical weakness the paper reports: in narrow gaps and
pockets the forces can cancel or oscillate.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from omcrl.config import EnvConfig
from omcrl.planners.grid import OccupancyGrid, shortest_path


class HybridAPF:
    """Policy ``act(obs, info) -> action`` (float32 (3,) in [-1, 1]) for one :class:`~omcrl.envs.NavEnv`.

    Parameters
    ----------
    env_config : the env's limits (max_speed m/s, max_yaw_rate rad/s); defaults to ``EnvConfig()``.
    lookahead : carrot distance along the global path, m.
    influence : repulsion acts within this distance of an obstacle surface, m.
    k_rep : repulsion gain.
    margin : extra clearance (m) on top of the drone radius when replanning on a bound env's map.
    speed : cruise speed as a fraction of max_speed.
    """

    name = "HybridAPF"

    def __init__(
        self,
        env_config: EnvConfig | None = None,
        lookahead: float = 0.8,
        influence: float = 0.7,
        k_rep: float = 0.25,
        margin: float = 0.15,
        speed: float = 0.8,
    ) -> None:
        self.cfg = env_config or EnvConfig()
        self.lookahead, self.influence, self.k_rep = lookahead, influence, k_rep
        self.margin, self.speed = margin, speed
        self.path = np.zeros((0, 2))
        self.idx = 0
        self._env: Any = None
        self._reset_info: dict | None = None  # the info the current episode started from

    def bind(self, env: Any) -> HybridAPF:
        """Give the planner the env itself, so it replans on the true map with its own clearance margin."""
        self._env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.cfg = self._env.cfg
        return self

    def reset(self, info: dict | None = None) -> None:
        """Start a new episode from the reset ``info`` (pose, goal and the env's shortest path).

        Without ``info`` it only forgets the old path; the next ``act`` with a reset info (or any info, when
        no path is held) plans anew.
        """
        self._reset_info = info
        if info is None:
            self.path = np.zeros((0, 2))
            return
        pose, goal = np.asarray(info["pose"], np.float64), np.asarray(info["goal"], np.float64)
        path = np.asarray(info.get("path", np.zeros((0, 2))), np.float64)
        grid: OccupancyGrid | None = getattr(self._env, "grid", None)
        if grid is not None:
            # Plan with a margin, so the potential field is not fighting a path that grazes obstacles.
            safe = OccupancyGrid(grid.origin, grid.res, grid.dist, grid.dist <= self.cfg.drone_radius + self.margin)
            if safe.free(pose[:2]) and safe.free(goal):
                p, length = shortest_path(safe, pose[:2], goal)
                if math.isfinite(length):
                    path = p
        self.path = path if len(path) else np.stack([pose[:2], goal])
        self.idx = 1

    def act(self, obs: dict, info: dict) -> np.ndarray:
        """Action for one step. A reset ``info`` (it carries ``path``) starts a new episode, unless ``reset``
        was already called with that very info (callers that announce episodes must not cause a second plan)."""
        if ("path" in info and info is not self._reset_info) or len(self.path) == 0:
            self.reset(info)
        x, y, yaw = (float(v) for v in info["pose"])
        pos = np.array([x, y])
        # Advance the carrot: skip waypoints already within the lookahead distance.
        while self.idx < len(self.path) - 1 and np.linalg.norm(self.path[self.idx] - pos) < self.lookahead:
            self.idx += 1
        carrot = self.path[self.idx]
        to_c = carrot - pos
        dist_c = float(np.linalg.norm(to_c))
        vmax = self.cfg.max_speed * self.speed
        # Attractive: unit pull toward the carrot, slowing down in the last metre before the goal.
        goal_d = float(np.linalg.norm(np.asarray(info["goal"], np.float64) - pos))
        v = to_c / max(dist_c, 1e-6) * vmax * min(1.0, 0.4 + goal_d)
        # Repulsive from the true nearest obstacle: magnitude from the 3-D distance, direction projected on
        # the flight plane, so a table top just below (or a canopy just above) barely pushes sideways.
        ob = np.asarray(obs["privileged"][:3], np.float64)
        d = float(np.linalg.norm(ob))
        c, s = math.cos(yaw), math.sin(yaw)
        if 1e-6 < d < self.influence:
            push = self.k_rep * (1.0 / d - 1.0 / self.influence) / d**2
            ob_w = np.array([c * ob[0] - s * ob[1], s * ob[0] + c * ob[1]])
            v = v - ob_w / d * push
        n = float(np.linalg.norm(v))
        if n > self.cfg.max_speed:
            v *= self.cfg.max_speed / n
        vb = np.array([c * v[0] + s * v[1], -s * v[0] + c * v[1]])
        # Face the direction of travel so the camera sees what is ahead.
        heading = math.atan2(v[1], v[0]) if n > 0.05 else yaw
        err = (heading - yaw + math.pi) % (2 * math.pi) - math.pi
        wz = 2.5 * err
        a = np.array([vb[0] / self.cfg.max_speed, vb[1] / self.cfg.max_speed, wz / self.cfg.max_yaw_rate])
        return np.clip(a, -1.0, 1.0).astype(np.float32)
