"""Geometry statistics of the scenes: what a layout leaves free to fly, independent of how it looks.

Used to check that look changes (``Disturbance.appearance``, ``data.look``) and scene edits leave the geometry
alone (docs/history/generalization-investigation.md, "Scene geometry"), and to compare how cluttered the
scenes are at flight altitude.
Pure geometry from the env's own occupancy grid and planner path, so the numbers are exactly what collisions,
the planners and SPL use.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from omcrl.config import EnvConfig
from omcrl.envs.nav_env import Disturbance, make_env

COLUMNS = ("scene", "seed", "obstacles", "occupied_pct", "blocked_pct", "shortest_path_m", "straight_line_m")


def geometry_stats(
    scene: str,
    seeds: Sequence[int],
    config: EnvConfig | None = None,
    disturbance: Disturbance | dict | None = None,
) -> pd.DataFrame:
    """Per episode seed, the layout's geometry at flight altitude.

    Parameters
    ----------
    scene : a scene id or family (``omcrl.scenes``); rows name its id.
    seeds : episode seeds; ``env.reset(seed=s)`` draws the layout, start and goal exactly as an evaluation
        episode with that seed does (Table I uses ``omcrl.eval.runner.eval_seeds``).
    config : env settings (arena, altitude, drone radius, grid resolution); default ``EnvConfig()``.
    disturbance : e.g. ``{"appearance": "box"}``; it must not change any column (tested).

    Returns
    -------
    DataFrame with one row per seed and the columns :data:`COLUMNS`: ``obstacles``, the count of solid
    (collidable) primitives; ``occupied_pct``, % of the arena's grid cells (``grid_resolution`` m) inside a
    solid at flight altitude; ``blocked_pct``, % of cells within the drone radius of a solid (where its centre
    cannot go); ``shortest_path_m``, the planner's any-angle shortest path start → goal on the blocked map (the
    ℓ of SPL), m; ``straight_line_m``, the start-goal distance, m.
    """
    env = make_env(scene, seed=None, config=config, disturbance=disturbance)
    rows = []
    try:
        for s in seeds:
            _, info = env.reset(seed=int(s))
            grid = env.grid
            assert grid is not None  # reset builds it
            rows.append(
                {
                    "scene": env.scene,
                    "seed": int(s),
                    "obstacles": sum(not p.visual_only for p in env.primitives),
                    "occupied_pct": 100.0 * float(np.mean(grid.dist <= 0.0)),
                    "blocked_pct": 100.0 * float(np.mean(grid.occ)),
                    "shortest_path_m": float(info["optimal_path_length"]),
                    "straight_line_m": float(np.linalg.norm(info["goal"] - info["pose"][:2])),
                }
            )
    finally:
        env.close()
    return pd.DataFrame(rows, columns=list(COLUMNS))


def geometry_summary(stats: pd.DataFrame) -> pd.DataFrame:
    """Mean and standard deviation per scene of :func:`geometry_stats`' numeric columns (one row per scene,
    columns ``<column>`` and ``<column>_sd``, plus ``layouts``, the number of seeds)."""
    num = [c for c in COLUMNS if c not in ("scene", "seed")]
    g = stats.groupby("scene", sort=False)[num]
    out = g.mean().join(g.std(ddof=1).add_suffix("_sd"))
    out.insert(0, "layouts", stats.groupby("scene", sort=False).size())
    return out.reset_index()
