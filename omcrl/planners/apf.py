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

import itertools
import math
from typing import Any

import numpy as np

from omcrl.config import EnvConfig
from omcrl.envs.grid import OccupancyGrid, shortest_path


def edge_mask(grid: OccupancyGrid, clearance: float) -> np.ndarray:
    """(G, G) bool: cells whose centre lies within ``clearance`` m of the arena's edge (the grid's border)."""
    x = grid.to_world(np.arange(grid.size)[:, None].repeat(2, 1))[:, 0]
    half = -grid.origin
    near = np.abs(x) > half - clearance
    return near[:, None] | near[None, :]


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
    # Whether act() reads the camera (obs["rgb"] / obs["depth"]): this one plans on the true map and is pushed by
    # the privileged nearest obstacle, so an evaluation may fly it in an env that renders nothing.
    uses_camera = False

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
            # Plan with a margin, so the potential field is not fighting a path that grazes obstacles, and with
            # the arena edge as an obstacle: leaving the arena ends the episode like a collision.
            clear = self.cfg.drone_radius + self.margin
            safe = OccupancyGrid(grid.origin, grid.res, grid.dist, (grid.dist <= clear) | edge_mask(grid, clear))
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
        # Repulsion from the true nearest obstacle point (privileged), body frame.
        return self._control(info, np.asarray(obs["privileged"][:3], np.float64))

    def _control(self, info: dict, ob: np.ndarray) -> np.ndarray:
        """Carrot-following on ``self.path`` with repulsion from the obstacle point ``ob`` (3,) m, body frame.

        Shared by the privileged and the perceptive form, which differ only in where the path and ``ob``
        come from.
        """
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
        # Repulsive from the nearest obstacle: magnitude from the 3-D distance, direction projected on the
        # flight plane, so a table top just below (or a canopy just above) barely pushes sideways.
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


class PerceptiveHybridAPF(HybridAPF):
    """Hybrid APF as a real robot could run it: the map is only what its depth camera has seen.

    Each step the newest depth frame (``obs["depth"][-1]``, z-depth in m) is back-projected through the
    camera (FOV ``env.fov_deg``, at the drone's pose and flight altitude); points within ``sense_range`` m
    whose height is within ``height_band`` m of the flight altitude are obstacles. They are added to a map of
    the arena (cells of ``env.grid_resolution`` m, the arena edge counted as an obstacle), unknown space is
    taken as free, and the global path is an any-angle shortest path on that map inflated by the drone radius
    plus ``margin``; it is replanned whenever a newly seen obstacle blocks it. The repulsive field acts from
    the nearest obstacle point sensed in the current frame or remembered on the map (within ``influence``).
    Pose and goal come from ``info`` (on the Tello: the motion-capture system), as for the learned policies'
    state vector.

    Parameters
    ----------
    sense_range : m, depth beyond this is ignored (a stereo/ToF sensor's usable range).
    height_band : m, obstacle points kept within this height of the flight altitude.
    Others as :class:`HybridAPF`.
    """

    uses_camera = True  # its map is what its depth frames have shown

    name = "HybridAPF-perceptive"

    def __init__(
        self, env_config: EnvConfig | None = None, sense_range: float = 4.0, height_band: float = 0.4, **kw: Any
    ) -> None:
        super().__init__(env_config, **kw)
        self.sense_range, self.height_band = float(sense_range), float(height_band)
        self.known: np.ndarray | None = None  # (G, G) bool, obstacle cells seen so far
        self._rays: np.ndarray | None = None

    def bind(self, env: Any) -> PerceptiveHybridAPF:
        """Only the env's configuration is taken (camera and limits), never its map."""
        self.cfg = (env.unwrapped if hasattr(env, "unwrapped") else env).cfg
        return self

    def _grid_shape(self) -> tuple[float, float, int]:
        c = self.cfg
        res = c.grid_resolution
        return -c.arena_half, res, math.floor(2 * c.arena_half / res) + 1

    def reset(self, info: dict | None = None) -> None:
        self._reset_info = info
        origin, res, g = self._grid_shape()
        self.known = np.zeros((g, g), bool)
        # The arena edge is a wall for planning: leaving the arena ends the episode like a collision.
        self.known[[0, -1], :] = True
        self.known[:, [0, -1]] = True
        self._grid: OccupancyGrid | None = None
        self._fallback = False
        self.path = np.zeros((0, 2))
        if info is not None:
            self._replan(np.asarray(info["pose"], np.float64)[:2], np.asarray(info["goal"], np.float64))

    def _camera_rays(self, side: int) -> np.ndarray:
        """(side*side, 3) ray directions per pixel for unit z-depth in the body frame (forward, left, up)."""
        if self._rays is None or len(self._rays) != side * side:
            f = (side / 2.0) / math.tan(math.radians(self.cfg.fov_deg) / 2.0)
            c = (np.arange(side) + 0.5 - side / 2.0) / f
            up, right = np.meshgrid(-c, c, indexing="ij")  # image rows go down, columns go right
            self._rays = np.stack([np.ones_like(up), -right, up], -1).reshape(-1, 3)
        return self._rays

    def sense(self, depth: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """Obstacle points (K, 3) in the body frame (m) seen in one depth frame (H, W) z-depth in m."""
        pts = self._camera_rays(depth.shape[-1]) * np.asarray(depth, np.float64).reshape(-1, 1)
        keep = (pts[:, 0] < self.sense_range) & (np.abs(pts[:, 2]) <= self.height_band)
        return pts[keep]

    def _replan(self, pos: np.ndarray, goal: np.ndarray) -> None:
        from scipy.ndimage import distance_transform_edt

        origin, res, _ = self._grid_shape()
        dist = distance_transform_edt(~self.known).astype(np.float32) * res
        clear = self.cfg.drone_radius + self.margin
        grid = OccupancyGrid(origin, res, dist, dist <= clear)
        grid.occ |= edge_mask(grid, clear)
        self._grid = grid
        path = np.zeros((0, 2))
        if self._grid.free(pos) and self._grid.free(goal):
            path, length = shortest_path(self._grid, pos, goal)
            path = path if math.isfinite(length) else np.zeros((0, 2))
        # Nothing known to get there (or the drone stands in an inflated cell): head straight for the goal
        # and let the potential field do the rest, as the classical method would; retry every step.
        self._fallback = not len(path)
        self.path = path if len(path) else np.stack([pos, goal])
        self.idx = 1

    def act(self, obs: dict, info: dict) -> np.ndarray:
        if ("path" in info and info is not self._reset_info) or self.known is None:
            self.reset(info)
        pose = np.asarray(info["pose"], np.float64)
        pos, goal = pose[:2], np.asarray(info["goal"], np.float64)
        pts = self.sense(np.asarray(obs["depth"])[-1], pose)
        if len(pts):
            c, s = math.cos(pose[2]), math.sin(pose[2])
            world = pos + np.stack([c * pts[:, 0] - s * pts[:, 1], s * pts[:, 0] + c * pts[:, 1]], 1)
            origin, res, g = self._grid_shape()
            ij = np.clip(np.rint((world - origin) / res).astype(np.int64), 0, g - 1)
            new = ~self.known[ij[:, 0], ij[:, 1]]
            self.known[ij[new, 0], ij[new, 1]] = True
            # Replan only when a new obstacle (or one that made the last plan fail) blocks the rest of the path.
            if new.any() or self._fallback:
                rest = [pos, *self.path[self.idx :]]
                if any(not self._blocked_free(a, b) for a, b in itertools.pairwise(rest)):
                    self._replan(pos, goal)
        return self._control(info, self._nearest_known(pose, pts))

    def _nearest_known(self, pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Nearest obstacle point (3,) body frame, m: sensed now or remembered on the map within ``influence``.

        The map matters when turning: a forward camera loses the corner it is passing.
        """
        best = pts[np.argmin(np.einsum("ij,ij->i", pts, pts))] if len(pts) else np.array([self.cfg.far, 0.0, 0.0])
        origin, res, g = self._grid_shape()
        r = math.ceil(self.influence / res)
        ci = np.clip(np.rint((pose[:2] - origin) / res).astype(np.int64), 0, g - 1)
        lo, hi = np.maximum(ci - r, 0), np.minimum(ci + r + 1, g)
        cells = np.argwhere(self.known[lo[0] : hi[0], lo[1] : hi[1]]) + lo
        if len(cells):
            d = cells * res + origin - pose[:2]
            k = np.argmin(np.einsum("ij,ij->i", d, d))
            if np.hypot(*d[k]) < np.linalg.norm(best):
                c, s = math.cos(pose[2]), math.sin(pose[2])
                best = np.array([c * d[k, 0] + s * d[k, 1], -s * d[k, 0] + c * d[k, 1], 0.0])
        return best

    def _blocked_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """True when segment a->b stays clear of the known obstacles inflated by the drone radius."""
        origin, res, g = self._grid_shape()
        n = max(2, math.ceil(np.linalg.norm(b - a) / (res / 2)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        ij = np.clip(np.rint((a + t * (b - a) - origin) / res).astype(np.int64), 0, g - 1)
        r = math.ceil(self.cfg.drone_radius / res)
        for dx in range(-r, r + 1):
            for dy in range(-r, r + 1):
                if self.known[np.clip(ij[:, 0] + dx, 0, g - 1), np.clip(ij[:, 1] + dy, 0, g - 1)].any():
                    return False
        return True


class LocalAPF(PerceptiveHybridAPF):
    """A local potential field on what the drone senses now: NPE's non-expert guide (no map, no path search).

    Each step it pulls straight towards the goal and pushes away from the nearest obstacle point seen in the
    newest depth frame (the forward camera's FOV, within ``sense_range`` m and ``height_band`` m of the flight
    altitude), with the same force law, speed and heading control as :class:`HybridAPF`. It remembers nothing:
    an obstacle that leaves the field of view stops pushing, and nothing plans around a wall. So it has the
    classical weaknesses the paper lists for potential fields — local minima in pockets and in front of walls
    across the goal line, oscillation in narrow gaps — and those of a perception-constrained controller: the
    "suboptimal planner" that guides NPE-DRL [zhang2024npe]. Pose and goal come from ``info``, as for the
    learned policies' state vector.

    Parameters are :class:`PerceptiveHybridAPF`'s.
    """

    name = "LocalAPF"

    def reset(self, info: dict | None = None) -> None:
        self._reset_info = info
        self.path = np.zeros((0, 2))
        if info is not None:
            pose = np.asarray(info["pose"], np.float64)
            self.path = np.stack([pose[:2], np.asarray(info["goal"], np.float64)])  # the straight line
            self.idx = 1

    def act(self, obs: dict, info: dict) -> np.ndarray:
        if ("path" in info and info is not self._reset_info) or len(self.path) == 0:
            self.reset(info)
        pts = self.sense(np.asarray(obs["depth"])[-1], np.asarray(info["pose"], np.float64))
        near = pts[np.argmin(np.einsum("ij,ij->i", pts, pts))] if len(pts) else np.array([self.cfg.far, 0.0, 0.0])
        return self._control(info, near)
