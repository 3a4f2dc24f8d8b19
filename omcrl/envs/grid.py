"""Occupancy grid at flight altitude and any-angle shortest paths on it.

The grid samples the exact obstacle distance (``Geometry``) at cell centres over the arena at the flight
altitude; a cell is blocked when an obstacle surface is within the drone radius (the map inflated by the
drone). Shortest paths: an optimal 8-connected graph search (scipy's compiled Dijkstra, which returns the
same optimal path an A* search with an admissible heuristic would, and also tells which cells are reachable),
then line-of-sight string pulling to an any-angle path. In an empty arena this equals the straight line.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from omcrl.scenes.geometry import Geometry

_SQ2 = math.sqrt(2.0)


@dataclass
class OccupancyGrid:
    """A square grid over the arena at flight altitude.

    Attributes
    ----------
    origin : float, world x (= y) of the centre of cell (0, 0), m.
    res : float, cell size, m.
    dist : (G, G) float32, distance from each cell centre to the nearest obstacle surface, m; indexed [ix, iy].
    occ : (G, G) bool, True where ``dist <= inflate`` (blocked for the drone centre).
    """

    origin: float
    res: float
    dist: np.ndarray
    occ: np.ndarray

    @property
    def size(self) -> int:
        return self.occ.shape[0]

    def to_cell(self, xy: np.ndarray) -> np.ndarray:
        """World (..., 2) m -> integer cell indices (..., 2), clipped to the grid."""
        ij = np.rint((np.asarray(xy, np.float64) - self.origin) / self.res).astype(np.int64)
        return np.clip(ij, 0, self.size - 1)

    def to_world(self, ij: np.ndarray) -> np.ndarray:
        """Cell indices (..., 2) -> world cell centres (..., 2), m."""
        return np.asarray(ij, np.float64) * self.res + self.origin

    def free(self, xy: np.ndarray) -> np.ndarray:
        ij = self.to_cell(xy)
        return ~self.occ[ij[..., 0], ij[..., 1]]

    def line_of_sight(self, a: np.ndarray, b: np.ndarray) -> bool:
        """True when every point of segment a->b (world, m) lies in a free cell (sampled every res/3)."""
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        n = max(2, math.ceil(np.linalg.norm(b - a) / (self.res / 3)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        return bool(self.free(a + t * (b - a)).all())


def build_grid(
    geometry: Geometry, arena_half: float, altitude: float, res: float, inflate: float, cap: float = 0.75
) -> OccupancyGrid:
    """Sample ``geometry`` at flight altitude on a grid of cell ``res`` m covering [-arena_half, arena_half]^2.

    Distances are exact up to ``cap`` m and saturate at ``cap`` beyond it: each solid is only evaluated in a
    window of its footprint plus ``cap`` (all windows of a kind in one vectorised pass), which makes building
    the map ~20x cheaper than a dense evaluation while every consumer (blocked cells, start/goal clearance)
    only asks about short distances.
    """
    g = math.floor(2 * arena_half / res) + 1
    origin = -arena_half
    dist = np.full(g * g, cap, np.float64)
    for kind, centre, reach, _ in geometry.kinds():
        if len(centre) == 0:
            continue
        span = (reach + cap)[:, None]
        lo = np.clip(np.floor((centre - span - origin) / res).astype(np.int64), 0, g)
        hi = np.clip(np.ceil((centre + span - origin) / res).astype(np.int64) + 1, 0, g)
        n = np.maximum(hi - lo, 0)  # (N, 2) window size in cells
        count = n[:, 0] * n[:, 1]
        if count.sum() == 0:
            continue
        # Enumerate every window's cells at once: solid index and row-major offset inside its window.
        solid = np.repeat(np.arange(len(centre)), count)
        off = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        ix = lo[solid, 0] + off // n[solid, 1]
        iy = lo[solid, 1] + off % n[solid, 1]
        pts = np.stack([origin + res * ix, origin + res * iy, np.full(ix.size, altitude)], 1)
        np.minimum.at(dist, ix * g + iy, geometry.distance_each(pts, kind, solid))
    dist = dist.reshape(g, g).astype(np.float32)
    return OccupancyGrid(origin=origin, res=res, dist=dist, occ=dist <= inflate)


def components(grid: OccupancyGrid) -> np.ndarray:
    """(G, G) int labels of 4-connected free regions (0 = blocked); a subset of 8-connected reachability."""
    from scipy.ndimage import label

    lab, _ = label(~grid.occ)
    return lab


# The 8 lattice directions (dx, dy); every node lists its neighbours in this order in the CSR graph.
_DIRS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


@functools.lru_cache(maxsize=4)
def _lattice(g: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR structure of the full 8-neighbour lattice on a g x g grid: indptr (g*g+1,), indices (8*g*g,) and
    unit step costs (8*g*g,). Neighbours beyond the border wrap around; :func:`_graph` never enables them."""
    idx = np.arange(g * g, dtype=np.int32).reshape(g, g)
    nbr = np.stack([np.roll(idx, (-dx, -dy), (0, 1)) for dx, dy in _DIRS], axis=-1)
    cost = np.tile([_SQ2 if dx and dy else 1.0 for dx, dy in _DIRS], g * g)
    return np.arange(0, 8 * g * g + 1, 8, dtype=np.int32), nbr.ravel(), cost


def _graph(grid: OccupancyGrid) -> csr_matrix:
    """Directed (both ways) 8-connected graph over free cells; diagonal moves need both adjacent orthogonal
    cells free. Disabled lattice edges get infinite weight, so the cached CSR structure is reused as is."""
    g = grid.size
    indptr, indices, cost = _lattice(g)
    free = ~grid.occ
    pad = np.zeros((g + 2, g + 2), bool)  # blocked border: no edges leave the grid
    pad[1:-1, 1:-1] = free
    ok = np.empty((g, g, 8), bool)
    for k, (dx, dy) in enumerate(_DIRS):
        m = np.logical_and(free, pad[1 + dx : g + 1 + dx, 1 + dy : g + 1 + dy], out=ok[..., k])
        if dx and dy:  # no corner cutting
            m &= pad[1 + dx : g + 1 + dx, 1 : g + 1]
            m &= pad[1 : g + 1, 1 + dy : g + 1 + dy]
    w = np.where(ok.ravel(), cost * grid.res, np.inf)
    return csr_matrix((w, indices, indptr), shape=(g * g, g * g))


def geodesic(grid: OccupancyGrid, source_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid-path distance (m) from ``source_xy`` to every cell, and Dijkstra predecessors.

    Returns
    -------
    dist : (G, G) float64, ``inf`` where unreachable (or blocked).
    pred : (G*G,) int32 predecessor of each node towards the source (-9999 where none).
    """
    ij = grid.to_cell(source_xy)
    src = int(ij[0] * grid.size + ij[1])
    d, pred = dijkstra(_graph(grid), directed=True, indices=src, return_predecessors=True)
    return d.reshape(grid.size, grid.size), pred


def shortest_path(
    grid: OccupancyGrid, start: np.ndarray, goal: np.ndarray, geo: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, float]:
    """Any-angle shortest path from ``start`` to ``goal`` (world xy, m) on the inflated map.

    Parameters
    ----------
    geo : optional precomputed ``geodesic(grid, start)`` to reuse.

    Returns
    -------
    path : (K, 2) waypoints from start to goal (exact endpoints), m; empty (0, 2) when unreachable.
    length : float path length, m (``inf`` when unreachable).
    """
    start, goal = np.asarray(start, np.float64)[:2], np.asarray(goal, np.float64)[:2]
    if grid.line_of_sight(start, goal):
        return np.stack([start, goal]), float(np.linalg.norm(goal - start))
    dist, pred = geo if geo is not None else geodesic(grid, start)
    gi = grid.to_cell(goal)
    if not np.isfinite(dist[gi[0], gi[1]]):
        return np.zeros((0, 2)), math.inf
    node = int(gi[0] * grid.size + gi[1])
    cells = [node]
    while pred[node] >= 0:
        node = int(pred[node])
        cells.append(node)
    cells.reverse()
    ij = np.stack([np.asarray(cells) // grid.size, np.asarray(cells) % grid.size], 1)
    pts = grid.to_world(ij)
    pts[0], pts[-1] = start, goal
    path = _string_pull(grid, pts)
    return path, float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())


def _string_pull(grid: OccupancyGrid, pts: np.ndarray) -> np.ndarray:
    """Greedy line-of-sight shortcutting: from each anchor jump to the farthest visible later point."""
    out = [pts[0]]
    i, n = 0, len(pts)
    while i < n - 1:
        lo, hi = i + 1, n - 1
        # Farthest visible point, found by a binary search that is correct when visibility is monotone and
        # falls back to the next point otherwise; shortcuts are only ever taken when the segment is clear.
        best = lo
        while lo <= hi:
            mid = (lo + hi) // 2
            if grid.line_of_sight(pts[i], pts[mid]):
                best, lo = mid, mid + 1
            else:
                hi = mid - 1
        out.append(pts[best])
        i = best
    return np.asarray(out)
