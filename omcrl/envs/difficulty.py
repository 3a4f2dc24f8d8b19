"""Navigation difficulty of a layout, network-free: how much a flight to the goal needs sight.

Three measures in the spirit of FlightBench's task-difficulty suite (Yu et al., 2024), taken on the any-angle
shortest path that the env plans for SPL (``env.path``), in the flight plane at flight altitude:

* :func:`narrowest_corridor` (traversability obstruction), m: the narrowest free passage the path crosses —
  at points along the path, the free distance to the left plus to the right of it, across its direction;
* :func:`view_occlusion`, a fraction in [0, 1]: how much of the path still to fly is hidden from the drone's
  forward camera along the way (behind an obstacle, or outside the camera's horizontal field of view);
* :func:`turning_per_metre` (angle over length), rad/m: how much the path turns per metre flown.

A straight flight across an empty arena scores (2 · ``cap``, 0, 0). :func:`difficulty_stats` gives them per
layout beside the detour (shortest path / straight line).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from omcrl.config import EnvConfig
from omcrl.envs.grid import OccupancyGrid
from omcrl.envs.nav_env import make_env
from omcrl.scenes.geometry import Geometry

COLUMNS = ("scene", "seed", "straight_line_m", "shortest_path_m", "detour", "corridor_m", "occlusion", "turning_rad_m")


def resample(path: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` m along a polyline ``path`` (K, 2) m, its end included, and the unit direction of
    the segment each point lies on: ((M, 2) m, (M, 2))."""
    path = np.asarray(path, np.float64)
    seg = np.diff(path, axis=0)
    length = np.linalg.norm(seg, axis=1)
    keep = length > 1e-9
    seg, length, starts = seg[keep], length[keep], path[:-1][keep]
    if len(seg) == 0:
        return path[:1].copy(), np.array([[1.0, 0.0]])
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s = np.append(np.arange(0.0, cum[-1], step), cum[-1])
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    u = seg[k] / length[k, None]
    return starts[k] + u * (s - cum[k])[:, None], u


def turning_per_metre(path: np.ndarray) -> float:
    """Angle over length: the sum of the absolute heading changes at the inner vertices of ``path`` (K, 2) m,
    rad, divided by its length, m. 0 for a straight line; an L of two legs of ``a`` m turns π/2 over 2a m."""
    path = np.asarray(path, np.float64)
    seg = np.diff(path, axis=0)
    seg = seg[np.linalg.norm(seg, axis=1) > 1e-9]
    length = float(np.linalg.norm(seg, axis=1).sum())
    if len(seg) < 2 or length == 0.0:
        return 0.0
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    turn = (np.diff(heading) + math.pi) % (2 * math.pi) - math.pi
    return float(np.abs(turn).sum() / length)


def narrowest_corridor(
    path: np.ndarray, geometry: Geometry, altitude: float, step: float = 0.1, cap: float = 4.0
) -> float:
    """Traversability obstruction: the narrowest free width (m) across ``path`` (K, 2) m at flight ``altitude``.

    At points every ``step`` m along the path, rays go left and right, perpendicular to the path, until they meet
    an obstacle surface (sphere tracing on the exact distances of ``geometry``) or ``cap`` m; the width there is
    the sum of the two. Returns the minimum over the path, m: the gap between two walls the path passes between
    (surface to surface), and ``2 · cap`` when nothing lies within ``cap`` on either side anywhere.
    """
    pts, u = resample(path, step)
    normal = np.stack([-u[:, 1], u[:, 0]], 1)
    origin = np.concatenate([pts, pts])
    direction = np.concatenate([normal, -normal])
    t = np.zeros(len(origin))
    active = np.ones(len(origin), bool)
    for _ in range(64):
        if not active.any():
            break
        q = origin[active] + direction[active] * t[active, None]
        d = geometry.distance(np.column_stack([q, np.full(len(q), altitude)]))
        idx = np.flatnonzero(active)
        t[idx] = np.minimum(t[idx] + d, cap)
        active[idx] = (d > 1e-3) & (t[idx] < cap)
    width = t[: len(pts)] + t[len(pts) :]
    return float(width.min())


def view_occlusion(
    path: np.ndarray, grid: OccupancyGrid, fov_deg: float, step: float = 0.25, horizon: float = math.inf
) -> float:
    """View occlusion: the mean, over points every ``step`` m along ``path`` (K, 2) m, of the share of the path
    still ahead (within ``horizon`` m of arc) that a camera there, looking along the path, cannot see.

    A path point ahead is hidden when it lies outside the horizontal field of view ``fov_deg`` (deg) around the
    path's direction, or when the straight sight line to it crosses an obstacle at flight altitude (a cell of
    ``grid`` whose centre lies within half a cell of a surface: the map *not* inflated by the drone). 0 for a
    straight path in the open; for an L of two equal legs whose inner corner is walled off, every point of the
    second leg is hidden from the first, and the mean tends to ln(2)/2 ≈ 0.347.
    """
    pts, u = resample(path, step)
    n = len(pts)
    if n < 2:
        return 0.0
    arc = np.arange(n) * step
    arc[-1] = arc[-2] + float(np.linalg.norm(pts[-1] - pts[-2]))
    half = math.radians(fov_deg) / 2
    solid = grid.dist <= grid.res / 2
    shares = []
    for i in range(n - 1):
        ahead = np.flatnonzero((arc > arc[i]) & (arc - arc[i] <= horizon))
        if len(ahead) == 0:
            continue
        rel = pts[ahead] - pts[i]
        bearing = np.arctan2(rel[:, 1], rel[:, 0]) - math.atan2(u[i, 1], u[i, 0])
        hidden = np.abs((bearing + math.pi) % (2 * math.pi) - math.pi) > half
        # Sight lines sampled every third of a cell; a sample in a solid cell hides the point.
        dist = np.linalg.norm(rel, axis=1)
        m = max(2, math.ceil(float(dist.max()) / (grid.res / 3)) + 1)
        frac = np.linspace(0.0, 1.0, m)[None, :, None]
        line = pts[i] + rel[:, None, :] * frac
        ij = grid.to_cell(line)
        hidden |= solid[ij[..., 0], ij[..., 1]].any(axis=1)
        shares.append(float(hidden.mean()))
    return float(np.mean(shares)) if shares else 0.0


def difficulty_stats(scene: str, seeds: Sequence[int], config: EnvConfig | None = None) -> pd.DataFrame:
    """Per episode seed, the layout's navigation difficulty (:data:`COLUMNS`).

    Parameters
    ----------
    scene : a scene id or family; rows name its id.
    seeds : episode seeds; ``env.reset(seed=s)`` draws layout, start and goal exactly as an evaluation episode
        with that seed does.
    config : env settings (arena, altitude, drone radius, camera FOV, grid resolution); default ``EnvConfig()``.

    Returns
    -------
    DataFrame, one row per seed: ``straight_line_m`` and ``shortest_path_m`` (m), ``detour`` (their ratio),
    ``corridor_m`` (:func:`narrowest_corridor`, m), ``occlusion`` (:func:`view_occlusion`, 0-1) and
    ``turning_rad_m`` (:func:`turning_per_metre`, rad/m), all on the env's shortest path.
    """
    env = make_env(scene, seed=None, config=config)
    c = env.unwrapped.cfg
    rows = []
    try:
        for s in seeds:
            _, info = env.reset(seed=int(s))
            path = np.asarray(info["path"], np.float64)
            geo = Geometry.from_primitives(env.unwrapped.primitives)
            grid = env.unwrapped.grid
            straight = float(np.linalg.norm(info["goal"] - info["pose"][:2]))
            shortest = float(info["optimal_path_length"])
            rows.append(
                {
                    "scene": env.unwrapped.scene,
                    "seed": int(s),
                    "straight_line_m": straight,
                    "shortest_path_m": shortest,
                    "detour": shortest / straight,
                    "corridor_m": narrowest_corridor(path, geo, c.altitude),
                    "occlusion": view_occlusion(path, grid, c.fov_deg),
                    "turning_rad_m": turning_per_metre(path),
                }
            )
    finally:
        env.close()
    return pd.DataFrame(rows, columns=list(COLUMNS))
