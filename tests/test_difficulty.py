"""Navigation difficulty measures (scenes v2): each on a layout whose value is known by construction."""

from __future__ import annotations

import math

import numpy as np
import pytest

from omcrl.envs.difficulty import (
    difficulty_stats,
    narrowest_corridor,
    resample,
    turning_per_metre,
    view_occlusion,
)
from omcrl.envs.grid import build_grid
from omcrl.scenes.geometry import Geometry, Primitive

ALT = 1.0


def _wall(x0, x1, y0, y1):
    return Primitive("box", ((x0 + x1) / 2, (y0 + y1) / 2, 1.25), ((x1 - x0) / 2, (y1 - y0) / 2, 1.25))


def test_resample_keeps_the_ends_and_the_step():
    pts, u = resample(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0]]), 0.25)
    assert np.allclose(pts[0], [0, 0]) and np.allclose(pts[-1], [2, 1]) and len(pts) == 13
    assert np.allclose(u[0], [1, 0]) and np.allclose(u[-2], [0, 1])


def test_turning_per_metre_of_a_line_an_l_and_a_zigzag():
    assert turning_per_metre(np.array([[0, 0], [5, 0], [9, 0]])) == 0.0
    assert turning_per_metre(np.array([[0, 0], [3, 0], [3, 3]])) == pytest.approx((math.pi / 2) / 6)
    zig = np.array([[0, 0], [1, 1], [2, 0]])  # +45° then -45°: a 90° turn over 2√2 m
    assert turning_per_metre(zig) == pytest.approx((math.pi / 2) / (2 * math.sqrt(2)))


def test_narrowest_corridor_is_the_gap_between_two_walls():
    walls = Geometry.from_primitives([_wall(2.0, 3.0, 0.6, 3.0), _wall(2.0, 3.0, -3.0, -0.6)])
    path = np.array([[0.0, 0.0], [6.0, 0.0]])
    assert narrowest_corridor(path, walls, ALT) == pytest.approx(1.2, abs=2e-3)
    # A gap off centre: still the width, surface to surface.
    walls = Geometry.from_primitives([_wall(2.0, 3.0, 0.3, 3.0), _wall(2.0, 3.0, -3.0, -0.6)])
    assert narrowest_corridor(path, walls, ALT) == pytest.approx(0.9, abs=2e-3)
    assert narrowest_corridor(path, Geometry.from_primitives([]), ALT, cap=4.0) == pytest.approx(8.0)


def test_view_occlusion_zero_in_the_open_and_ln2_over_2_around_a_walled_corner():
    empty = Geometry.from_primitives([])
    grid = build_grid(empty, 8.0, ALT, 0.1, 0.15)
    straight = np.array([[-6.0, 0.0], [6.0, 0.0]])
    assert view_occlusion(straight, grid, 82.6) == 0.0
    a = 6.0
    corner = np.array([[-3.0, -3.0], [-3.0 + a, -3.0], [-3.0 + a, -3.0 + a]])
    # In the open, the second leg is hidden only where it leaves the field of view.
    open_share = view_occlusion(corner, grid, 82.6)
    assert 0.0 < open_share < math.log(2) / 2
    # Walled off inside the corner (0.3 m from both legs): nothing of the second leg is seen from the first.
    wall = Geometry.from_primitives([_wall(-8.0, -3.0 + a - 0.3, -3.0 + 0.3, 8.0)])
    walled = view_occlusion(corner, build_grid(wall, 8.0, ALT, 0.1, 0.15), 82.6)
    assert walled == pytest.approx(math.log(2) / 2, abs=0.02)
    # A camera that sees all around is blind only behind the wall: it sees round the wall's end near the corner.
    around = view_occlusion(corner, build_grid(wall, 8.0, ALT, 0.1, 0.15), 360.0)
    assert 0.8 * walled < around < walled


def test_difficulty_stats_on_scene_layouts_are_consistent():
    df = difficulty_stats("box-v2", [5, 6, 7], None)
    assert list(df.seed) == [5, 6, 7]
    assert (df.shortest_path_m >= df.straight_line_m - 1e-9).all()
    assert np.allclose(df.detour, df.shortest_path_m / df.straight_line_m)
    assert ((df.occlusion >= 0) & (df.occlusion <= 1)).all() and (df.corridor_m > 0).all()
    assert ((df.detour > 1.0 + 1e-9) == (df.turning_rad_m > 0)).all()  # a path bends exactly when it turns
