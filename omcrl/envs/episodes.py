"""Episode planning for ``NavEnv``: the layout, its collision and occupancy maps, a reachable start and goal.

An :class:`EpisodePlanner` is an object the env holds (``env.episodes``). It owns what a reset decides before
touching PyBullet: the current layout's plan, the episode count and a plan made ahead of time. It is pure
computation drawn from the random generator the env hands it (PyBullet is untouched), so the vector env can plan
an env's next reset ahead while it waits for another (:meth:`EpisodePlanner.prefetch`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from omcrl.config import EnvConfig
from omcrl.envs.dynamics import _wrap
from omcrl.envs.grid import OccupancyGrid, build_grid, components, shortest_path
from omcrl.scenes import generate_scene, scene_spec
from omcrl.scenes.geometry import Geometry, Primitive


@dataclass
class Plan:
    """Everything a reset decides before touching PyBullet (:meth:`EpisodePlanner.plan`).

    Attributes
    ----------
    episodes : the planner's episode count the plan was made at.
    rng_before, rng_after : the generator's state before and after planning (set by :meth:`EpisodePlanner.prefetch`).
    layout_seed : the seed the layout was generated from.
    key : identifies the layout (scene, seed) or the user's layout.
    prims : the layout's obstacles.
    geometry : their collision geometry.
    grid : the occupancy grid at flight altitude.
    placed : start (3,) (x, y m, yaw rad), goal (2,) m, shortest path (K, 2) m, its length m.
    """

    episodes: int
    rng_before: dict | None
    rng_after: dict | None
    layout_seed: int
    key: Any
    prims: list[Primitive]
    geometry: Geometry
    grid: OccupancyGrid
    placed: tuple

    def valid(self, episodes: int, rng: np.random.Generator) -> bool:
        return episodes == self.episodes and rng.bit_generator.state == self.rng_before


class EpisodePlanner:
    """Layout, maps, start/goal and path of each episode of a :class:`omcrl.envs.nav_env.NavEnv`.

    Parameters
    ----------
    cfg : the env's configuration (arena, altitude, grid resolution, goal distance, ``layout_every``, ...).
    scene : the scene id whose layouts are generated.
    layout : a user's fixed layout (obstacle primitives) instead of generated ones, or None.

    Attributes
    ----------
    current : the plan of the running episode (its layout is the one built in PyBullet); None before the first.
    episodes : how many episodes have begun.
    """

    def __init__(self, cfg: EnvConfig, scene: str, layout: list[Primitive] | None = None) -> None:
        self.cfg, self.scene, self.layout = cfg, scene, layout
        self.current: Plan | None = None
        self.episodes = 0
        self._ahead: Plan | None = None

    def begin(self, rng: np.random.Generator, reseed: bool, options: dict) -> tuple[Plan, bool]:
        """The next episode's plan, now the current one; and whether its layout differs from the last one's (the
        env then builds its bodies). A plan made ahead (:meth:`prefetch`) is adopted when this is the automatic
        reset it was made for, with ``rng`` moved on as if it had been planned just now."""
        plan, self._ahead = self._ahead, None
        if plan is not None and not reseed and not options and plan.valid(self.episodes, rng):
            rng.bit_generator.state = plan.rng_after
        else:
            plan = self.plan(rng, reseed=reseed, options=options)
        new_layout = self.current is None or plan.key != self.current.key
        self.current = plan
        self.episodes += 1
        return plan, new_layout

    def maps(self, prims: list[Primitive]) -> tuple[Geometry, OccupancyGrid]:
        """Collision geometry and occupancy grid of a layout (pure computation: no PyBullet)."""
        c = self.cfg
        geo = Geometry.from_primitives(prims)
        return geo, build_grid(geo, c.arena_half, c.altitude, c.grid_resolution, c.drone_radius)

    def plan(self, rng: np.random.Generator, reseed: bool, options: dict) -> Plan:
        """Layout, maps, start/goal and path of the next episode, drawn from ``rng``.

        Pure computation (PyBullet is untouched), so it can run ahead of the reset (:meth:`prefetch`).
        ``reseed``: reset() got a seed, so the layout always follows from it.
        """
        c = self.cfg
        cur = self.current
        layout_seed, key = (-1, None) if cur is None else (cur.layout_seed, cur.key)
        prims, geometry, grid = (None, None, None) if cur is None else (cur.prims, cur.geometry, cur.grid)
        for attempt in range(50):
            # A new layout every `layout_every` episodes (and after a layout with no valid start/goal pair);
            # with a seed given to reset() the layout always follows from that seed.
            if reseed or attempt > 0 or self.episodes % c.layout_every == 0 or layout_seed < 0:
                layout_seed = int(rng.integers(2**31 - 1))
            new_key = ("layout", id(self.layout)) if self.layout is not None else (self.scene, layout_seed)
            if new_key != key:
                prims = (
                    self.layout
                    if self.layout is not None
                    else generate_scene(self.scene, layout_seed, c.arena_half, c.n_obstacles)
                )
                geometry, grid = self.maps(prims)
                key = new_key
            placed = self._place(rng, options, grid, geometry)
            if placed is not None:
                return Plan(self.episodes, None, None, layout_seed, key, prims, geometry, grid, placed)
            if self.layout is not None:
                raise ValueError(
                    "could not find a reachable start/goal pair in the given layout within the "
                    f"configured goal_distance {c.goal_distance} m"
                )
        raise RuntimeError(f"scene {self.scene!r}: no reachable start/goal found in 50 layouts")  # pragma: no cover

    @property
    def prefetched(self) -> bool:
        """True when the next automatic reset has been planned ahead by :meth:`prefetch`."""
        return self._ahead is not None

    def prefetch(self, rng: np.random.Generator) -> bool:
        """Plan the next automatic reset (``reset()`` without seed or options) now, while there is time.

        The plan is exactly what that reset would compute: it is drawn from a snapshot of ``rng`` (the env's
        generator), which is then put back, and :meth:`begin` only adopts it when the generator and the episode
        count are still where the plan started (anything else, e.g. a reset with a seed, discards it).

        Returns
        -------
        bool : True when a plan was made (False before the first episode or when one is pending).
        """
        if self.current is None or self._ahead is not None:
            return False
        before = rng.bit_generator.state
        plan = self.plan(rng, reseed=False, options={})
        plan.rng_before, plan.rng_after = before, rng.bit_generator.state
        rng.bit_generator.state = before
        self._ahead = plan
        return True

    def _place(self, rng: np.random.Generator, options: dict, grid: OccupancyGrid, geometry: Geometry) -> tuple | None:
        """Start (x, y, yaw) and goal (x, y) from ``options`` or sampled free, reachable, at a distance in
        ``goal_distance`` on the layout of ``grid``/``geometry``; also the any-angle shortest path. None when
        this layout has no valid pair."""
        c = self.cfg
        clearance = c.drone_radius + 0.25
        if "start" in options:
            start = self._check_point("start", options["start"], True, geometry)
        else:
            start = None
        if "goal" in options:
            goal = self._check_point("goal", options["goal"], False, geometry)
        else:
            goal = None
        if start is not None and goal is not None:
            path, length = shortest_path(grid, start[:2], goal)
            if not math.isfinite(length):
                raise ValueError(f"reset options: goal {tuple(goal)} is not reachable from start {tuple(start[:2])}")
            return start, goal, path, length
        # Scenes that ask for it (SceneSpec.line_blocked) take only pairs whose straight line is blocked in that
        # share of episodes, and only pairs with a clear line in the others; at 0 (v0, v1) nothing is asked and
        # nothing drawn, so those scenes keep their random streams.
        share = scene_spec(self.scene).line_blocked if self.layout is None else 0.0
        want_blocked = None if share <= 0.0 else share >= 1.0 or bool(rng.random() < share)
        labels = components(grid)
        axis = grid.to_world(np.arange(grid.size))
        # Cells too near the arena edge would make "leaving the arena" an instant failure.
        inner = np.abs(axis) <= c.arena_half - 0.5
        ok = (grid.dist > clearance) & (labels > 0) & inner[:, None] & inner[None, :]
        lo, hi = c.goal_distance
        for _ in range(20):
            if start is not None or goal is not None:
                anchor = start[:2] if start is not None else goal
                aij = grid.to_cell(anchor)
            else:
                aij = _draw_cell(rng, ok, lambda: rng.integers(0, grid.size, (_DRAWS, 2)))
                if aij is None:
                    return None
                anchor = grid.to_world(aij)
            alab = labels[aij[0], aij[1]]

            def around(anchor: np.ndarray = anchor) -> np.ndarray:
                # Uniform in the annulus lo <= r <= hi (area-uniform radius), snapped to cells.
                r = np.sqrt(rng.uniform(lo * lo, hi * hi, _DRAWS))
                t = rng.uniform(0.0, 2.0 * math.pi, _DRAWS)
                # Cells clipped onto the border are never allowed (arena margin), so clipping drops them.
                return grid.to_cell(anchor + np.stack([r * np.cos(t), r * np.sin(t)], 1))

            def fits(ij: np.ndarray, anchor: np.ndarray = anchor, alab: int = alab) -> np.ndarray:
                d = np.linalg.norm(grid.to_world(ij) - anchor, axis=1)
                return (labels[ij[:, 0], ij[:, 1]] == alab) & (d >= lo) & (d <= hi)

            oij = _draw_cell(rng, ok, around, fits)
            if oij is None:
                if start is not None or goal is not None:
                    return None
                continue
            other = grid.to_world(oij)
            s_xy, g_xy = (other, goal) if goal is not None and start is None else (anchor, other)
            if want_blocked is not None and grid.line_of_sight(s_xy, g_xy) == want_blocked:
                continue  # the scene asks for the other kind of pair (a blocked or a clear straight line)
            path, length = shortest_path(grid, s_xy, g_xy)
            if not math.isfinite(length):
                continue
            if start is not None:
                yaw = start[2]
            else:
                toward = math.atan2(g_xy[1] - s_xy[1], g_xy[0] - s_xy[0])
                yaw = toward + float(rng.uniform(-c.start_yaw_noise, c.start_yaw_noise))
            return np.array([s_xy[0], s_xy[1], _wrap(yaw)]), np.asarray(g_xy, np.float64), path, length
        return None

    def _check_point(self, name: str, value: Any, with_yaw: bool, geometry: Geometry) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise ValueError(f"reset options['{name}']: got {value!r}, expected numbers") from None
        want = (2, 3) if with_yaw else (2,)
        if arr.size not in want or not np.all(np.isfinite(arr)):
            raise ValueError(
                f"reset options['{name}']: got {value!r}, expected {'(x, y[, yaw])' if with_yaw else '(x, y)'}"
                " with finite values in metres/radians"
            )
        a = self.cfg.arena_half
        if np.any(np.abs(arr[:2]) > a):
            raise ValueError(f"reset options['{name}']: {tuple(arr[:2])} lies outside the arena [-{a}, {a}]^2 m")
        d = geometry.nearest(np.array([arr[0], arr[1], self.cfg.altitude]))[1]
        if d <= self.cfg.drone_radius:
            raise ValueError(
                f"reset options['{name}']: {tuple(arr[:2])} is inside or within the drone radius "
                f"({self.cfg.drone_radius} m) of an obstacle (clearance {d:.3f} m)"
            )
        if with_yaw and arr.size == 2:
            arr = np.append(arr, 0.0)
        return arr


# Candidate cells per rejection-sampling draw in ``_place``.
_DRAWS = 64


def _draw_cell(
    rng: np.random.Generator, ok: np.ndarray, propose: Any, fits: Any = None, rounds: int = 8
) -> np.ndarray | None:
    """First proposed cell that is ``ok`` (and ``fits``), by rejection sampling; else a uniform draw over all
    such cells; None when there is none.

    Rejection sampling from a uniform proposal is uniform over the accepted cells, like drawing from the full
    candidate list, but costs tens of microseconds instead of milliseconds of whole-grid work per reset.

    Parameters
    ----------
    ok : (G, G) bool, allowed cells.
    propose : ``propose() -> (K, 2)`` int candidate cell indices (out-of-grid ones are dropped).
    fits : optional ``fits(ij (K, 2) int) -> (K,) bool`` extra condition.
    """
    g = ok.shape[0]
    for _ in range(rounds):
        ij = np.asarray(propose())
        ij = ij[np.all((ij >= 0) & (ij < g), axis=1)].astype(np.int64)
        good = ok[ij[:, 0], ij[:, 1]]
        if fits is not None and good.any():
            good[good] = fits(ij[good])
        if good.any():
            return ij[int(np.argmax(good))]
    ij = np.argwhere(ok)  # few allowed cells: fall back to the exhaustive list
    if fits is not None and len(ij):
        ij = ij[fits(ij)]
    return ij[rng.integers(len(ij))] if len(ij) else None
