"""Obstacle primitives and exact distance queries, in numpy.

The simulator never asks PyBullet for contacts: the drone is a sphere at a fixed altitude and every obstacle is
a union of boxes (any yaw), vertical cylinders and spheres, so collision, the nearest obstacle surface point
(the privileged observation) and the occupancy grid all come from the same closed-form distances here. That
keeps an env step at one render plus a few microseconds of numpy.

All positions are world-frame metres; ``z`` is up.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

KINDS = ("box", "cylinder", "sphere")


@dataclass
class Primitive:
    """One solid: ``box`` (half extents ``size``), ``cylinder`` (radius ``size[0]``, half height ``size[2]``,
    vertical axis) or ``sphere`` (radius ``size[0]``). ``center`` (3,) m, ``yaw`` rad (boxes only).
    ``rgba`` and ``texture`` only affect rendering; ``visual_only`` parts (floor, walls beyond the arena,
    sky) are drawn but never collide."""

    kind: str
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float = 0.0
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    texture: str | None = None
    visual_only: bool = False

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"primitive kind: got {self.kind!r}, expected one of {KINDS}")
        if len(self.center) != 3 or len(self.size) != 3:
            raise ValueError(f"primitive {self.kind}: center and size need 3 values, got {self.center}, {self.size}")
        if (min(self.size) <= 0 and self.kind == "box") or self.size[0] <= 0:
            raise ValueError(f"primitive {self.kind}: sizes must be positive, got {self.size}")


@dataclass
class Geometry:
    """Vectorised collision geometry built from the non-visual primitives of a scene."""

    box_c: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    box_h: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    box_cos: np.ndarray = field(default_factory=lambda: np.zeros(0))
    box_sin: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cyl_c: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    cyl_r: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cyl_hh: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sph_c: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sph_r: np.ndarray = field(default_factory=lambda: np.zeros(0))

    solids: list[Primitive] = field(default_factory=list)

    @classmethod
    def from_primitives(cls, prims: list[Primitive]) -> Geometry:
        solid = [p for p in prims if not p.visual_only]
        boxes = [p for p in solid if p.kind == "box"]
        cyls = [p for p in solid if p.kind == "cylinder"]
        sphs = [p for p in solid if p.kind == "sphere"]

        def arr(xs: list, n: int) -> np.ndarray:
            return np.asarray(xs, dtype=np.float64).reshape(-1, n) if n > 1 else np.asarray(xs, np.float64)

        return cls(
            box_c=arr([p.center for p in boxes], 3),
            box_h=arr([p.size for p in boxes], 3),
            box_cos=np.cos(arr([p.yaw for p in boxes], 1)),
            box_sin=np.sin(arr([p.yaw for p in boxes], 1)),
            cyl_c=arr([p.center for p in cyls], 3),
            cyl_r=arr([p.size[0] for p in cyls], 1),
            cyl_hh=arr([p.size[2] for p in cyls], 1),
            sph_c=arr([p.center for p in sphs], 3),
            sph_r=arr([p.size[0] for p in sphs], 1),
            solids=solid,
        )

    def distance_each(self, pts: np.ndarray, kind: str, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Distance (m, 0 inside) from points to solids of one ``kind``, elementwise with numpy broadcasting.

        The one place the closed-form distances live; :meth:`closest`, :meth:`nearest` and the occupancy grid
        call it. ``pts`` (..., 3) m is broadcast against the solids ``idx`` (an index into this kind's solids),
        e.g. (P, 1, 3) against all N solids gives (P, N); (M, 3) against (M,) indices gives (M,).
        """
        if kind == "box":
            rel = pts - self.box_c[idx]
            c, s, h = self.box_cos[idx], self.box_sin[idx], self.box_h[idx]
            ex = np.maximum(np.abs(c * rel[..., 0] + s * rel[..., 1]) - h[..., 0], 0)
            ey = np.maximum(np.abs(c * rel[..., 1] - s * rel[..., 0]) - h[..., 1], 0)
            ez = np.maximum(np.abs(rel[..., 2]) - h[..., 2], 0)
            return np.sqrt(ex * ex + ey * ey + ez * ez)
        if kind == "cylinder":
            rel = pts - self.cyl_c[idx]
            dr = np.maximum(np.hypot(rel[..., 0], rel[..., 1]) - self.cyl_r[idx], 0)
            return np.hypot(dr, np.maximum(np.abs(rel[..., 2]) - self.cyl_hh[idx], 0))
        if kind == "sphere":
            return np.maximum(np.linalg.norm(pts - self.sph_c[idx], axis=-1) - self.sph_r[idx], 0)
        raise ValueError(f"kind: got {kind!r}, expected one of {KINDS}")

    def kinds(self) -> list[tuple[str, np.ndarray, np.ndarray, Callable[[np.ndarray, np.ndarray], np.ndarray]]]:
        """Per kind, in the order :meth:`closest` ranks them: (kind, xy centres (N, 2) m, horizontal reach (N,) m,
        surface-point function ``(pts (K, 3), idx (K,)) -> (K, 3)``)."""
        return [
            ("box", self.box_c[:, :2], np.hypot(self.box_h[:, 0], self.box_h[:, 1]), self._box_point),
            ("cylinder", self.cyl_c[:, :2], self.cyl_r, self._cyl_point),
            ("sphere", self.sph_c[:, :2], self.sph_r, self._sph_point),
        ]

    @property
    def n(self) -> int:
        return len(self.box_c) + len(self.cyl_c) + len(self.sph_c)

    def closest(self, pts: np.ndarray, points: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        """Nearest obstacle surface point and distance for each query point.

        Distances to every primitive use cheap closed forms; the surface point is only constructed for the
        winning primitive of each query, which keeps the per-step call (one point) at a few array operations.

        Parameters
        ----------
        pts : (P, 3) query points, m.
        points : False skips constructing the surface points (returns None for them): distances only.

        Returns
        -------
        closest : (P, 3) nearest surface point over all primitives (the query point itself when inside one,
            and the query point when the scene is empty); None when ``points`` is False.
        dist : (P,) distance to it, m (0 inside an obstacle, ``inf`` for an empty scene).
        """
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        if self.n == 0:
            return pts.copy(), np.full(len(pts), np.inf)
        parts = [self.distance_each(pts[:, None, :], kind) for kind, xy, _, _ in self.kinds() if len(xy)]
        alld = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)
        idx = np.argmin(alld, axis=1)
        dist = alld[np.arange(len(pts)), idx]
        if not points:
            return None, dist
        out = np.empty_like(pts)
        lo = 0
        for _, xy, _, fn in self.kinds():
            sel = (idx >= lo) & (idx < lo + len(xy))
            if sel.any():
                out[sel] = fn(pts[sel], idx[sel] - lo)
            lo += len(xy)
        return out, dist

    def nearest(self, p: np.ndarray) -> tuple[np.ndarray, float]:
        """:meth:`closest` for one point ``p`` (3,) m: (nearest surface point (3,) m, distance m).

        The env asks this once per control substep; for one point, distances over (N,) arrays per kind and the
        surface point of the winner only are ~3x cheaper than the batched :meth:`closest`, which it equals
        (``tests/test_envs.py``).
        """
        p = np.asarray(p, dtype=np.float64).reshape(3)
        best, win = math.inf, None
        for kind, xy, _, fn in self.kinds():
            if len(xy):
                d = self.distance_each(p, kind)
                k = int(np.argmin(d))
                if d[k] < best:  # strict: ties go to the earlier kind, as in closest()
                    best, win = float(d[k]), (fn, k)
        if win is None:
            return p.copy(), math.inf
        fn, k = win
        return fn(p[None], np.array([k]))[0], best

    def _box_point(self, p: np.ndarray, i: np.ndarray) -> np.ndarray:
        c, s, h = self.box_cos[i], self.box_sin[i], self.box_h[i]
        rel = p - self.box_c[i]
        lx = np.clip(c * rel[:, 0] + s * rel[:, 1], -h[:, 0], h[:, 0])
        ly = np.clip(-s * rel[:, 0] + c * rel[:, 1], -h[:, 1], h[:, 1])
        lz = np.clip(rel[:, 2], -h[:, 2], h[:, 2])
        return self.box_c[i] + np.stack([c * lx - s * ly, s * lx + c * ly, lz], 1)

    def _cyl_point(self, p: np.ndarray, i: np.ndarray) -> np.ndarray:
        rel = p - self.cyl_c[i]
        rad = np.hypot(rel[:, 0], rel[:, 1])
        scale = np.minimum(1.0, self.cyl_r[i] / np.maximum(rad, 1e-12))
        qz = np.clip(rel[:, 2], -self.cyl_hh[i], self.cyl_hh[i])
        return self.cyl_c[i] + np.stack([rel[:, 0] * scale, rel[:, 1] * scale, qz], 1)

    def _sph_point(self, p: np.ndarray, i: np.ndarray) -> np.ndarray:
        rel = p - self.sph_c[i]
        norm = np.linalg.norm(rel, axis=1)
        scale = np.minimum(1.0, self.sph_r[i] / np.maximum(norm, 1e-12))
        return self.sph_c[i] + rel * scale[:, None]

    def distance(self, pts: np.ndarray, chunk: int = 4096) -> np.ndarray:
        """(P,) distance to the nearest obstacle for (P, 3) points, computed in chunks to bound memory."""
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        out = np.empty(len(pts))
        for i in range(0, len(pts), chunk):
            out[i : i + chunk] = self.closest(pts[i : i + chunk], points=False)[1]
        return out
