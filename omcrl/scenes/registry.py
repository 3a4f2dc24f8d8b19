"""Scenes as versioned specs (paper V-A), generated from a seed, and user layouts.

The paper builds four scenes as "a gradient of perceptual and navigational difficulty": identical boxes
(training), furniture in an indoor room (easy), irregular barriers (medium) and a forest (hard). Each scene
here is a :class:`SceneSpec` in one registry, named as Gymnasium names environments: a family and a version,
``furniture-v1``. A version never changes once published; a changed scene is a new version.

* ``box-v0`` — identical crates with one texture in a tiled, painted room: the training scene.
* ``furniture-v1`` — tables, chairs, shelves, sofas, lamps, cabinets and plants of different shapes, sizes,
  colours and materials, in **box's room** (its floor, walls and ceiling): the paper's easy indoor scene.
* ``furniture-v0`` — the same furniture and layouts in a room of its own (wood floor, other paint): the
  first suite's furniture scene, kept as a stress test for an unseen room (docs/generalization.md).
* ``barrier-v0`` — irregular walls: straight runs, L- and U-shapes, walls with gaps, in a concrete and brick
  hall. U-shapes open towards the arena centre are local minima for potential fields.
* ``tree-v0`` — an outdoor forest: trunks of varied radius and bark, canopies (spheres or stacked cones), low
  bushes, grass and sky.

The v2 suite (the default, :data:`SUITES`) keeps the v1 suite's looks and makes layouts that need sight
(docs/scenes.md, "The v2 suite"): a blind pilot fails, the map planner succeeds, box holds detours.

* ``box-v2`` — box-v0's crates, loose and in walls of 4-8, tees and pockets; 80 % of its episodes have the
  straight start-goal line blocked (:attr:`SceneSpec.line_blocked`), 20 % a clear one.
* ``furniture-v2`` — furniture-v1's pieces, more of them and more often tall ones, plus shelf rows, in box's room.
* ``barrier-v2`` — barrier-v0's walls, spaced wider with wider doors, in its hall.
* ``tree-v2`` — tree-v0's trees and bushes, 55 instead of 34.

In the unseen v2 scenes every episode has its straight line blocked.

A bare family name (``"furniture"``) means its latest version, as in Gymnasium. furniture-v0 and -v1 share their
generator and random stream, so a seed gives the same geometry in both; v2 scenes draw from streams of their own.
Run and cache identities name a scene by its id.

A scene is a list of :class:`~omcrl.scenes.geometry.Primitive`; decor (floor, walls beyond the arena, ceiling,
sky) is ``visual_only``. Generators place structures by rejection sampling with a spacing margin so that the
drone can pass between most of them; reachability of start and goal is checked later on the occupancy grid.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from omcrl.scenes.geometry import Primitive

Generator = Callable[[np.random.Generator, float, int], list[Primitive]]


@dataclass(frozen=True)
class SceneSpec:
    """One scene at one version: what generates its obstacles and what surrounds them.

    Attributes
    ----------
    family : ``box`` | ``furniture`` | ``barrier`` | ``tree`` (or a user's own).
    version : integer; ``id`` is ``f"{family}-v{version}"``.
    generator : ``(rng, arena_half m, n) -> [Primitive]``, obstacles with their materials.
    stream : index of the random stream (``default_rng([seed, stream])``); versions that share it (furniture-v0
        and -v1) give the same layout for a seed.
    default_count : structures placed when ``env.n_obstacles`` is 0.
    indoor : a room (walls and ceiling) or the outdoors (sky).
    floor_texture, wall_texture : surroundings (``kind:variant`` of :mod:`omcrl.envs.textures`); no walls
        outdoors.
    materials : texture kinds the generator puts on obstacles (besides plain colours).
    difficulty : the paper's label (Table I): ``training``, ``easy``, ``medium``, ``hard``, or ``stress``.
    paper_scene : the column of the paper's Table I this scene stands for, or None (a stress test).
    description : one line for tables and ``--help``.
    line_blocked : the share (0-1) of episodes drawn so that the straight start–goal segment crosses the blocked
        map (obstacles inflated by the drone radius): in those a pilot that flies straight at the goal collides, so
        they need sight. 0 draws start and goal as v0 did; 1 blocks every episode. Only sampled starts and goals
        are redrawn; ``reset(options=...)`` keeps the caller's.
    """

    family: str
    version: int
    generator: Generator
    stream: int
    default_count: int
    indoor: bool
    floor_texture: str
    wall_texture: str | None
    materials: tuple[str, ...]
    difficulty: str
    paper_scene: str | None
    description: str
    line_blocked: float = 0.0

    @property
    def id(self) -> str:
        return f"{self.family}-v{self.version}"

    @property
    def gym_id(self) -> str:
        """The Gymnasium id, e.g. ``omcrl/Furniture-v1``."""
        return f"omcrl/{self.family.capitalize()}-v{self.version}"


SCENE_SPECS: dict[str, SceneSpec] = {}


def register_scene(spec: SceneSpec) -> SceneSpec:
    """Add ``spec`` to the registry; a published id cannot be redefined."""
    if not re.fullmatch(r"[a-z][a-z0-9_]*", spec.family) or spec.version < 0:
        raise ValueError(f"scene family must be lower-case letters/digits and version >= 0, got {spec.id!r}")
    if spec.id in SCENE_SPECS and SCENE_SPECS[spec.id] != spec:
        raise ValueError(f"scene {spec.id!r} is already registered; a changed scene needs a new version")
    SCENE_SPECS[spec.id] = spec
    return spec


def scene_spec(name: str) -> SceneSpec:
    """The spec of ``name``: an id (``furniture-v0``) or a bare family (its latest version).

    Raises ValueError naming the known scenes for anything else.
    """
    if isinstance(name, str):
        if name in SCENE_SPECS:
            return SCENE_SPECS[name]
        versions = [s for s in SCENE_SPECS.values() if s.family == name]
        if versions:
            return max(versions, key=lambda s: s.version)
    raise ValueError(f"scene: got {name!r}, expected one of {list(SCENE_SPECS)} (or a family {list(families())})")


def scene_id(name: str) -> str:
    """The canonical id of ``name`` (``"furniture"`` -> ``"furniture-v1"``, ``"box"`` -> ``"box-v0"``)."""
    return scene_spec(name).id


def families() -> tuple[str, ...]:
    """Scene families in registration order."""
    return tuple(dict.fromkeys(s.family for s in SCENE_SPECS.values()))


def is_unseen(name: str) -> bool:
    """True for a scene no trained part of the kit sees by default (every scene but the training scene)."""
    return scene_spec(name).difficulty != "training"


def is_stress(name: str) -> bool:
    """True for a stress test beside the paper's suite (furniture-v0's unseen room), not one of the paper's scenes."""
    return scene_spec(name).difficulty == "stress"


def paper_unseen(scenes: Sequence[str]) -> tuple[str, ...]:
    """The ids of ``scenes`` that stand for the paper's unseen scenes (no training scene, no stress test), in
    order: the columns of the paper's zero-shot claims."""
    return tuple(scene_id(s) for s in scenes if is_unseen(s) and not is_stress(s))


def scene_label(name: str) -> str:
    """A scene's id with its role, for tables and figures: ``furniture-v1 (easy)``."""
    spec = scene_spec(name)
    return f"{spec.id} ({spec.difficulty})"


def _rgba(rng: np.random.Generator, lo: float = 0.25, hi: float = 0.95) -> tuple[float, float, float, float]:
    r, g, b = rng.uniform(lo, hi, 3)
    return (float(r), float(g), float(b), 1.0)


class _Placer:
    """Rejection sampler for structure footprints (discs) inside the arena with a spacing margin.

    A placement draws up to ``tries`` candidates from ``rng`` one after the other and takes the first that fits.
    After the first few, the remaining candidates are tested all at once in numpy, and the generator is then left
    exactly where drawing them one by one up to the accepted one would leave it; a test within :data:`_EXACT` of
    its bound is decided again by the scalar arithmetic (``math``) the layouts were first generated with, so every
    layout is the same to the bit (numpy's cos, sin and hypot may differ from math's in the last ulp)."""

    # False: every candidate one by one (the reference the batched search must match; ``bench scenes``).
    batched = True

    def __init__(self, rng: np.random.Generator, arena_half: float, gap: float) -> None:
        self.rng, self.a, self.gap = rng, arena_half, gap
        self.discs: list[tuple[float, float, float]] = []
        self.one_by_one = _ONE_BY_ONE if self.batched else 10**9

    def _scalar_ok(self, pts: Sequence[tuple[float, float]], radius: float, bounded: bool) -> bool:
        if bounded and not all(abs(px) <= self.a and abs(py) <= self.a for px, py in pts):
            return False
        return all(math.hypot(px - u, py - v) > radius + r + self.gap for px, py in pts for u, v, r in self.discs)

    def _first_fit(self, pts: np.ndarray, radius: float, bounded: bool, exact: Any) -> int | None:
        """Index of the first candidate (``pts``: (n, k, 2) m) whose k discs are inside the arena (when ``bounded``)
        and clear of every placed disc; ``exact(i)`` gives candidate i's points in scalar arithmetic."""
        possible = np.ones(len(pts), bool)  # not surely refused
        unsure = np.zeros(len(pts), bool)  # within _EXACT of a bound: decided by _scalar_ok
        if bounded:
            inside = (self.a - np.abs(pts).max(axis=2)).min(axis=1)  # m
            possible &= inside > -_EXACT
            unsure |= np.abs(inside) <= _EXACT
        if self.discs:
            placed = np.asarray(self.discs)  # (m, 3): centre x, y and radius, m
            dx, dy = pts[..., 0, None] - placed[:, 0], pts[..., 1, None] - placed[:, 1]
            clear = (dx * dx + dy * dy - (radius + placed[:, 2] + self.gap) ** 2).min(axis=(1, 2))  # m²
            possible &= clear > -_EXACT
            unsure |= np.abs(clear) <= _EXACT
        for i in np.flatnonzero(possible):
            if not unsure[i] or self._scalar_ok(exact(int(i)), radius, bounded):
                return int(i)
        return None

    def _add(self, pts: Sequence[tuple[float, float]], radius: float) -> None:
        self.discs += [(px, py, radius) for px, py in pts]

    def _search(self, per_try: int, tries: int, radius: float, bounded: bool, exact: Any, batch: Any) -> Any:
        """The ``per_try`` uniforms of the first of ``tries`` candidates that fits, its discs added; None if none.

        ``exact(u)`` gives a candidate's disc centres (m) from its uniforms in scalar arithmetic, ``batch(U)`` those
        of (n, per_try) uniforms as an (n, k, 2) array. The first candidates are drawn and tested one by one; the
        rest are drawn at once, and the generator is then set back to where the one-by-one search would leave it."""
        first = min(self.one_by_one, tries)
        for _ in range(first):  # most placements fit within a few candidates
            u = self.rng.random(per_try)
            pts = exact(u)
            if self._scalar_ok(pts, radius, bounded):
                self._add(pts, radius)
                return u
        if tries <= first:
            return None
        state = self.rng.bit_generator.state
        U = self.rng.random(per_try * (tries - first)).reshape(-1, per_try)
        i = self._first_fit(batch(U), radius, bounded, lambda j: exact(U[j]))
        self.rng.bit_generator.state = state  # the candidates after the accepted one were never drawn
        self.rng.random(per_try * (tries - first if i is None else i + 1))
        if i is None:
            return None
        self._add(exact(U[i]), radius)
        return U[i]

    def place_group(self, offsets: Sequence[tuple[float, float]], radius: float, tries: int = 60) -> tuple | None:
        """Place a rigid group of discs (``offsets`` m from its centre, each of ``radius`` m) at a random centre
        and yaw, every disc ``gap`` m clear of all placed ones; returns (x, y, yaw) or None."""
        lo, hi = -self.a + 0.5, self.a - 0.5
        off = np.asarray(offsets, dtype=float)  # (k, 2)

        def batch(U: np.ndarray) -> np.ndarray:
            x, y, yaw = lo + (hi - lo) * U[:, :1], lo + (hi - lo) * U[:, 1:2], math.pi * U[:, 2:]
            c, s = np.cos(yaw), np.sin(yaw)
            return np.stack([x + c * off[:, 0] - s * off[:, 1], y + s * off[:, 0] + c * off[:, 1]], -1)

        def exact(u: np.ndarray) -> list[tuple[float, float]]:
            return _group_points(lo + (hi - lo) * u[0], lo + (hi - lo) * u[1], math.pi * u[2], offsets)

        bounded = max(math.hypot(x, y) for x, y in offsets) > 0
        u = self._search(3, tries, radius, bounded, exact, batch)
        if u is None:
            return None
        return float(lo + (hi - lo) * u[0]), float(lo + (hi - lo) * u[1]), float(math.pi * u[2])

    def place(self, radius: float, tries: int = 60) -> tuple[float, float] | None:
        lo, hi = -self.a + radius * 0.5, self.a - radius * 0.5

        def exact(u: np.ndarray) -> list[tuple[float, float]]:
            return [(lo + (hi - lo) * u[0], lo + (hi - lo) * u[1])]

        u = self._search(2, tries, radius, False, exact, lambda U: (lo + (hi - lo) * U)[:, None, :])
        return None if u is None else (float(lo + (hi - lo) * u[0]), float(lo + (hi - lo) * u[1]))


def _group_points(x: float, y: float, yaw: float, offsets: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """The centres (m) of a group's discs at (x, y) and ``yaw``, in the scalar arithmetic of the first layouts."""
    return [(x + u, y + v) for u, v in (_rot(ox, oy, float(yaw)) for ox, oy in offsets)]


# Candidates a placement tests one by one, as drawn, before it tests the rest in one batch (_Placer).
_ONE_BY_ONE = 4
# A clearance or bound within this distance (m) of its limit is decided by scalar arithmetic (see _Placer).
_EXACT = 1e-9


def _rot(x: float, y: float, yaw: float) -> tuple[float, float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return c * x - s * y, s * x + c * y


def _part(
    cx: float,
    cy: float,
    yaw: float,
    lx: float,
    ly: float,
    half: tuple[float, float],
    z: tuple[float, float],
    **kw: Any,
) -> Primitive:
    """Box part of a structure: local offset (lx, ly) m, half extents ``half`` (x, y), spanning heights ``z``."""
    ox, oy = _rot(lx, ly, yaw)
    return Primitive("box", (cx + ox, cy + oy, (z[0] + z[1]) / 2), (half[0], half[1], (z[1] - z[0]) / 2), yaw=yaw, **kw)


# ------------------------------------------------------------------ generators
def gen_box(rng: np.random.Generator, arena_half: float, n: int) -> list[Primitive]:
    placer = _Placer(rng, arena_half, gap=0.9)
    out = []
    for _ in range(n):
        pos = placer.place(0.71)
        if pos is None:
            break
        # Identical crates: same size, colour and texture; only position and yaw vary.
        out.append(
            Primitive(
                "box",
                (pos[0], pos[1], 1.25),
                (0.5, 0.5, 1.25),
                yaw=float(rng.uniform(0, math.pi)),
                rgba=(1, 1, 1, 1),
                texture="crate:0",
            )
        )
    return out


def _furniture_piece(kind: str, rng: np.random.Generator, x: float, y: float, yaw: float) -> list[Primitive]:
    wood = f"wood:{rng.integers(6)}"
    col = _rgba(rng)
    if kind == "table":  # low: the drone (altitude 1 m) flies over it
        w, d = rng.uniform(0.5, 0.8), rng.uniform(0.35, 0.45)
        top = _part(x, y, yaw, 0, 0, (w, d), (0.72, 0.76), rgba=(1, 1, 1, 1), texture=wood)
        legs = [
            _part(
                x,
                y,
                yaw,
                sx * (w - 0.05),
                sy * (d - 0.05),
                (0.03, 0.03),
                (0.0, 0.72),
                rgba=(1, 1, 1, 1),
                texture=wood,
            )
            for sx in (-1, 1)
            for sy in (-1, 1)
        ]
        return [top, *legs]
    if kind == "round_table":
        r = float(rng.uniform(0.35, 0.55))
        return [
            Primitive("cylinder", (x, y, 0.72), (r, r, 0.02), rgba=(1, 1, 1, 1), texture=f"marble:{rng.integers(4)}"),
            Primitive("cylinder", (x, y, 0.35), (0.05, 0.05, 0.35), rgba=(0.2, 0.2, 0.2, 1), texture=None),
        ]
    if kind == "chair":
        s = 0.23
        fab = f"fabric:{rng.integers(8)}"
        return [
            _part(x, y, yaw, 0, 0, (s, s), (0.42, 0.48), rgba=(1, 1, 1, 1), texture=fab),
            _part(x, y, yaw, -s + 0.03, 0, (0.03, s), (0.48, 1.1), rgba=(1, 1, 1, 1), texture=fab),
            *[
                _part(x, y, yaw, sx * (s - 0.03), sy * (s - 0.03), (0.02, 0.02), (0.0, 0.42), rgba=col)
                for sx in (-1, 1)
                for sy in (-1, 1)
            ],
        ]
    if kind == "shelf":
        w, d, h = rng.uniform(0.4, 0.8), rng.uniform(0.18, 0.25), rng.uniform(1.7, 2.2)
        parts = [_part(x, y, yaw, 0, sy * w, (d, 0.02), (0, h), rgba=(1, 1, 1, 1), texture=wood) for sy in (-1, 1)]
        parts.append(_part(x, y, yaw, -d + 0.01, 0, (0.01, w), (0, h), rgba=(1, 1, 1, 1), texture=wood))
        parts += [
            _part(x, y, yaw, 0, 0, (d, w), (z, z + 0.03), rgba=(1, 1, 1, 1), texture=wood)
            for z in np.linspace(0.0, h - 0.03, 5)
        ]
        return parts
    if kind == "sofa":  # low back: flyable over
        w, d = rng.uniform(0.8, 1.1), 0.45
        fab = f"fabric:{rng.integers(8)}"
        return [
            _part(x, y, yaw, 0, 0, (d, w), (0, 0.45), rgba=(1, 1, 1, 1), texture=fab),
            _part(x, y, yaw, -d + 0.1, 0, (0.1, w), (0.45, 0.82), rgba=(1, 1, 1, 1), texture=fab),
            *[
                _part(x, y, yaw, 0, sy * (w - 0.08), (d, 0.08), (0.45, 0.62), rgba=(1, 1, 1, 1), texture=fab)
                for sy in (-1, 1)
            ],
        ]
    if kind == "lamp":
        h = float(rng.uniform(1.4, 1.8))
        return [
            Primitive("cylinder", (x, y, 0.02), (0.18, 0.18, 0.02), rgba=(0.15, 0.15, 0.15, 1)),
            Primitive(
                "cylinder",
                (x, y, h / 2),
                (0.025, 0.025, h / 2),
                rgba=(0.7, 0.7, 0.72, 1),
                texture=f"metal:{rng.integers(4)}",
            ),
            Primitive("cylinder", (x, y, h), (0.22, 0.22, 0.15), rgba=(*_rgba(rng, 0.7, 1.0)[:3], 1.0)),
        ]
    if kind == "cabinet":
        w, d, h = rng.uniform(0.4, 0.7), rng.uniform(0.25, 0.35), rng.uniform(1.2, 2.0)
        return [
            _part(
                x,
                y,
                yaw,
                0,
                0,
                (d, w),
                (0, h),
                rgba=col,
                texture=f"metal:{rng.integers(4)}" if rng.random() < 0.4 else wood,
            )
        ]
    if kind == "plant":
        r = float(rng.uniform(0.3, 0.5))
        return [
            Primitive("cylinder", (x, y, 0.25), (0.2, 0.2, 0.25), rgba=(0.55, 0.3, 0.2, 1), texture="concrete:pot"),
            Primitive(
                "sphere",
                (x, y, 0.5 + r * 0.9),
                (r, r, r),
                rgba=(1, 1, 1, 1),
                texture=f"leaves:{rng.integers(6)}",
            ),
        ]
    if kind == "coffee_table":
        w, d = rng.uniform(0.4, 0.6), rng.uniform(0.3, 0.4)
        return [_part(x, y, yaw, 0, 0, (w, d), (0.0, 0.42), rgba=col, texture=f"marble:{rng.integers(4)}")]
    raise ValueError(kind)


FURNITURE = ("table", "round_table", "chair", "shelf", "sofa", "lamp", "cabinet", "plant", "coffee_table")
_FURN_RADIUS = {
    "table": 0.95,
    "round_table": 0.55,
    "chair": 0.35,
    "shelf": 0.8,
    "sofa": 1.1,
    "lamp": 0.25,
    "cabinet": 0.75,
    "plant": 0.5,
    "coffee_table": 0.7,
}


def gen_furniture(rng: np.random.Generator, arena_half: float, n: int) -> list[Primitive]:
    placer = _Placer(rng, arena_half, gap=0.7)
    out: list[Primitive] = []
    # Every kind appears at least once, then random kinds, so each layout shows the variety.
    kinds = list(FURNITURE) + list(rng.choice(FURNITURE, size=max(0, n - len(FURNITURE))))
    for kind in kinds[:n]:
        pos = placer.place(_FURN_RADIUS[kind])
        if pos is not None:
            out += _furniture_piece(kind, rng, pos[0], pos[1], float(rng.uniform(0, 2 * math.pi)))
    return out


def gen_barrier(
    rng: np.random.Generator, arena_half: float, n: int, spacing: float = 1.0, door: tuple[float, float] = (0.45, 0.6)
) -> list[Primitive]:
    """Irregular walls (straight, L, U, walls with a door, zigzags), ``spacing`` m apart at least (footprint discs),
    doors of half width ``door`` m (v0's defaults)."""
    placer = _Placer(rng, arena_half, gap=spacing)
    out: list[Primitive] = []
    h = 2.4
    shapes = ["U", "L", "gap", "straight", "U", "zigzag"]
    for i in range(n):
        shape = shapes[i % len(shapes)] if i < len(shapes) else str(rng.choice(shapes))
        size = float(rng.uniform(1.4, 2.4))
        pos = placer.place(size * 1.1)
        if pos is None:
            continue
        x, y = pos
        yaw = float(rng.uniform(0, 2 * math.pi))
        t = float(rng.uniform(0.1, 0.18))  # half thickness
        tex = f"{rng.choice(['brick', 'concrete', 'paint'])}:{rng.integers(6)}"
        kw = {"rgba": (1.0, 1.0, 1.0, 1.0), "texture": tex}
        hh = h * float(rng.uniform(0.85, 1.1))
        if shape == "straight":
            out.append(_part(x, y, yaw, 0, 0, (size, t), (0, hh), **kw))
        elif shape == "L":
            out += [
                _part(x, y, yaw, 0, -size + t, (size, t), (0, hh), **kw),
                _part(x, y, yaw, -size + t, 0, (t, size), (0, hh), **kw),
            ]
        elif shape == "U":  # a pocket: potential-field local minimum when the goal lies behind it
            depth = size * float(rng.uniform(0.7, 1.0))
            out += [
                _part(x, y, yaw, 0, 0, (t, size), (0, hh), **kw),
                _part(x, y, yaw, depth, size - t, (depth, t), (0, hh), **kw),
                _part(x, y, yaw, depth, -size + t, (depth, t), (0, hh), **kw),
            ]
        elif shape == "gap":
            g = float(rng.uniform(*door))  # half gap: passable for a 0.15 m drone
            seg = size
            out += [
                _part(x, y, yaw, 0, g + seg / 2, (t, seg / 2), (0, hh), **kw),
                _part(x, y, yaw, 0, -g - seg / 2, (t, seg / 2), (0, hh), **kw),
            ]
        else:  # zigzag: irregular run of short segments at alternating angles
            px, py = -size, 0.0
            ang = yaw
            for _ in range(3):
                seg = size * 0.5
                ang += float(rng.uniform(-1.0, 1.0))
                cx, cy = px + math.cos(ang) * seg, py + math.sin(ang) * seg
                ox, oy = _rot(cx, cy, 0.0)
                out.append(_part(x + ox, y + oy, ang, 0, 0, (seg, t), (0, hh), **kw))
                px, py = cx + math.cos(ang) * seg, cy + math.sin(ang) * seg
    return out


def gen_barrier_v2(rng: np.random.Generator, arena_half: float, n: int) -> list[Primitive]:
    """barrier-v2: barrier-v0's walls with wider spacing and doors (:data:`BARRIER_V2_SPACING`, ``_DOOR``)."""
    return gen_barrier(rng, arena_half, n, spacing=BARRIER_V2_SPACING, door=BARRIER_V2_DOOR)


def gen_tree(rng: np.random.Generator, arena_half: float, n: int) -> list[Primitive]:
    placer = _Placer(rng, arena_half, gap=1.0)
    out: list[Primitive] = []
    for i in range(n):
        bush = i % 5 == 4
        r_trunk = float(rng.uniform(0.1, 0.3))
        pos = placer.place(0.55 if bush else r_trunk + 0.35)
        if pos is None:
            continue
        x, y = pos
        if bush:  # low bushes, some reaching flight altitude
            r = float(rng.uniform(0.35, 0.6))
            out.append(
                Primitive(
                    "sphere",
                    (x, y, r * 0.8),
                    (r, r, r),
                    rgba=(1, 1, 1, 1),
                    texture=f"leaves:{rng.integers(8)}",
                )
            )
            continue
        h = float(rng.uniform(3.0, 6.5))
        out.append(
            Primitive(
                "cylinder",
                (x, y, h / 2),
                (r_trunk, r_trunk, h / 2),
                rgba=(1, 1, 1, 1),
                texture=f"bark:{rng.integers(6)}",
            )
        )
        leaves = f"leaves:{rng.integers(8)}"
        if rng.random() < 0.5:  # broadleaf: one to three canopy spheres above the flight level
            for _ in range(int(rng.integers(1, 4))):
                r = float(rng.uniform(0.8, 1.6))
                cz = max(h - r * 0.3, 1.5 + r) + float(rng.uniform(-0.2, 0.4))
                dx, dy = rng.uniform(-0.4, 0.4, 2)
                out.append(Primitive("sphere", (x + dx, y + dy, cz), (r, r, r), rgba=(1, 1, 1, 1), texture=leaves))
        else:  # conifer: stacked discs shrinking upwards
            base = float(rng.uniform(1.6, 2.2))
            levels = 3
            for k in range(levels):
                r = float(rng.uniform(0.9, 1.3)) * (1 - k / (levels + 1))
                z0 = base + k * (h - base) / levels
                out.append(
                    Primitive("cylinder", (x, y, z0 + 0.3), (r, r, 0.3), rgba=(0.8, 0.9, 0.8, 1), texture=leaves)
                )
    return out


# ------------------------------------------------------------------ v2 generators: layouts that need sight
# Crate groups of box-v2, in crate units (1 m, the crates touch): a local offset per crate. Rows and corners make
# walls a straight flight cannot pass; the U is a pocket (a local minimum for a potential field).
_CRATE_GROUPS: dict[str, tuple[tuple[float, float], ...]] = {
    "single": ((0.0, 0.0),),
    "row4": tuple((i - 1.5, 0.0) for i in range(4)),
    "row6": tuple((i - 2.5, 0.0) for i in range(6)),
    "row8": tuple((i - 3.5, 0.0) for i in range(8)),
    "tee": ((-1, 0), (0, 0), (1, 0), (0, 1), (0, 2)),
    "pocket": ((-1, -0.5), (0, -0.5), (1, -0.5), (-1, 0.5), (1, 0.5)),
    "big_pocket": ((-1.5, -1), (-0.5, -1), (0.5, -1), (1.5, -1), (-1.5, 0), (1.5, 0), (-1.5, 1), (1.5, 1)),
}
# Chance of each group per draw: loose crates (small detours a reactive controller can fly round) and walls
# (detours it cannot), in the proportion that meets the v2 criteria (docs/scenes.md, "The v2 suite").
_CRATE_GROUP_P = {
    "single": 0.3,
    "row4": 0.14,
    "row6": 0.175,
    "row8": 0.105,
    "tee": 0.105,
    "pocket": 0.105,
    "big_pocket": 0.07,
}


def gen_box_v2(rng: np.random.Generator, arena_half: float, n: int) -> list[Primitive]:
    """box-v2: ``n`` identical crates (box-v0's size, colour and texture), loose or in touching groups with a
    random yaw each — walls of 4, 6 or 8 crates, tees and pockets (:data:`_CRATE_GROUPS`) — every crate
    ``BOX_V2_GAP`` m clear of the crates of other groups (box-v0's spacing)."""
    placer = _Placer(rng, arena_half, gap=BOX_V2_GAP)
    names = list(_CRATE_GROUP_P)
    p = np.array([_CRATE_GROUP_P[k] for k in names])
    out: list[Primitive] = []
    misses = 0
    while len(out) < n and misses < 40:
        offsets = _CRATE_GROUPS[names[int(rng.choice(len(names), p=p))]][: n - len(out)]
        pos = placer.place_group(offsets, 0.71)
        if pos is None:
            misses += 1
            continue
        yaw = pos[2]
        for lx, ly in offsets:
            out.append(_part(pos[0], pos[1], yaw, lx, ly, (0.5, 0.5), (0.0, 2.5), rgba=(1, 1, 1, 1), texture="crate:0"))
    return out


# furniture-v2 draws the tall pieces (at or above flight altitude) more often than v1, and adds shelf rows.
_FURN_V2_P = {
    "table": 0.05,
    "round_table": 0.04,
    "chair": 0.1,
    "shelf": 0.17,
    "sofa": 0.05,
    "lamp": 0.1,
    "cabinet": 0.17,
    "plant": 0.17,
    "coffee_table": 0.03,
    "shelf_row": 0.12,
}


def gen_furniture_v2(rng: np.random.Generator, arena_half: float, n: int) -> list[Primitive]:
    """furniture-v2: ``n`` pieces of furniture-v1's kinds (every kind once, then drawn with :data:`_FURN_V2_P`,
    which favours pieces that reach flight altitude), and rows of 2-3 shelves back to back as room dividers."""
    placer = _Placer(rng, arena_half, gap=0.7)
    names = list(_FURN_V2_P)
    p = np.array([_FURN_V2_P[k] for k in names])
    kinds = list(FURNITURE) + [names[int(i)] for i in rng.choice(len(names), size=max(0, n - len(FURNITURE)), p=p)]
    out: list[Primitive] = []
    for kind in kinds[:n]:
        yaw = float(rng.uniform(0, 2 * math.pi))
        if kind == "shelf_row":
            k = int(rng.integers(2, 4))
            pos = placer.place(0.8 * k)
            if pos is None:
                continue
            for i in range(k):  # shelves side by side along their width (local y), 1.6 m apart
                ox, oy = _rot(0.0, (i - (k - 1) / 2) * 1.6, yaw)
                out += _furniture_piece("shelf", rng, pos[0] + ox, pos[1] + oy, yaw)
            continue
        pos = placer.place(_FURN_RADIUS[kind])
        if pos is not None:
            out += _furniture_piece(kind, rng, pos[0], pos[1], yaw)
    return out


# Default structure counts of the v2 scenes (crates, furniture pieces, walls, trees and bushes).
BOX_V2_GAP = 0.9  # m between crate groups' footprints
BOX_V2_COUNT, FURNITURE_V2_COUNT, BARRIER_V2_COUNT, TREE_V2_COUNT = 54, 26, 12, 55
BARRIER_V2_SPACING, BARRIER_V2_DOOR = 1.5, (0.6, 0.8)
# box-v2 is the training scene: 80 % of its episodes need a detour, 20 % keep a clear line (docs/scenes.md).
BOX_V2_BLOCKED = 0.8

_BOX_ROOM = {"indoor": True, "floor_texture": "tiles:0", "wall_texture": "paint:0"}
_FURNITURE = {
    "family": "furniture",
    "generator": gen_furniture,
    "stream": 1,
    "default_count": 18,
    "materials": ("wood", "marble", "fabric", "metal", "leaves", "concrete"),
}
# Streams are the scenes' indices before versions existed, so v0 layouts are unchanged (pinned by a test).
for _spec in (
    SceneSpec(
        "box",
        0,
        gen_box,
        0,
        20,
        **_BOX_ROOM,
        materials=("crate",),
        difficulty="training",
        paper_scene=None,
        description="identical crates in a tiled, painted room (training)",
    ),
    SceneSpec(
        **_FURNITURE,
        version=1,
        **_BOX_ROOM,
        difficulty="easy",
        paper_scene="furniture",
        description="furniture of many shapes, sizes and materials in box's room",
    ),
    SceneSpec(
        "barrier",
        0,
        gen_barrier,
        2,
        9,
        True,
        "concrete:floor",
        "brick:room",
        ("brick", "concrete", "paint"),
        difficulty="medium",
        paper_scene="barrier",
        description="irregular walls (straight, L, U, gaps, zigzags) in a concrete and brick hall",
    ),
    SceneSpec(
        "tree",
        0,
        gen_tree,
        3,
        34,
        False,
        "grass:0",
        None,
        ("bark", "leaves"),
        difficulty="hard",
        paper_scene="tree",
        description="a forest of varied trunks, canopies and bushes on grass under sky",
    ),
    SceneSpec(
        **_FURNITURE,
        version=0,
        indoor=True,
        floor_texture="wood:floor",
        wall_texture="paint:1",
        difficulty="stress",
        paper_scene=None,
        description="furniture-v1's layouts in a room of its own (wood floor, other paint): an unseen room",
    ),
    # v2: the same looks as the v1 suite, layouts that need sight (docs/scenes.md, "The v2 suite").
    SceneSpec(
        "box",
        2,
        gen_box_v2,
        10,
        BOX_V2_COUNT,
        **_BOX_ROOM,
        materials=("crate",),
        difficulty="training",
        paper_scene=None,
        description="identical crates, loose and in walls, tees and pockets; most goals behind one (training)",
        line_blocked=BOX_V2_BLOCKED,
    ),
    SceneSpec(
        "furniture",
        2,
        gen_furniture_v2,
        11,
        FURNITURE_V2_COUNT,
        **_BOX_ROOM,
        materials=_FURNITURE["materials"],
        difficulty="easy",
        paper_scene="furniture",
        description="denser, taller furniture and shelf rows in box's room; every goal behind an obstacle",
        line_blocked=1.0,
    ),
    SceneSpec(
        "barrier",
        2,
        gen_barrier_v2,
        12,
        BARRIER_V2_COUNT,
        True,
        "concrete:floor",
        "brick:room",
        ("brick", "concrete", "paint"),
        difficulty="medium",
        paper_scene="barrier",
        description="barrier-v0's walls, more of them, in its hall; every goal behind a wall",
        line_blocked=1.0,
    ),
    SceneSpec(
        "tree",
        2,
        gen_tree,
        13,
        TREE_V2_COUNT,
        False,
        "grass:0",
        None,
        ("bark", "leaves"),
        difficulty="hard",
        paper_scene="tree",
        description="a denser forest of tree-v0's trunks, canopies and bushes; every goal behind a tree",
        line_blocked=1.0,
    ),
):
    register_scene(_spec)

# Scene families, as in the public API; each name means its latest version.
SCENES = families()
# The paper's four scenes (training scene first) in each published suite; v2 is the default (Table I's columns).
SUITES: dict[str, tuple[str, ...]] = {
    "v1": ("box-v0", "furniture-v1", "barrier-v0", "tree-v0"),
    "v2": ("box-v2", "furniture-v2", "barrier-v2", "tree-v2"),
}
DEFAULT_SUITE = "v2"
PAPER_SUITE = SUITES[DEFAULT_SUITE]


def suite_of(train_scene: str) -> str | None:
    """The suite (a key of :data:`SUITES`) whose training box is ``train_scene``, or None for a box of no suite."""
    return next((suite for suite, scenes in SUITES.items() if scenes[0] == train_scene), None)


def suite_overrides(suite: str) -> list[str]:
    """Config overrides (``--set`` strings) that train in ``suite``'s box and evaluate in its four scenes plus
    the stress scenes: ``suite_overrides("v1")`` reproduces the v1 suite's runs and Table I."""
    if suite not in SUITES:
        raise ValueError(f"suite: got {suite!r}, expected one of {list(SUITES)}")
    scenes = ", ".join([*SUITES[suite], *STRESS_SCENES])
    return [f"env.scene={SUITES[suite][0]}", f"data.scene={SUITES[suite][0]}", f"eval.scenes=[{scenes}]"]


# Stress tests beside the paper's suite (docs/generalization.md): furniture-v0's unseen room.
STRESS_SCENES = tuple(s.id for s in SCENE_SPECS.values() if s.difficulty == "stress")


def generate_scene(scene: str, seed: int, arena_half: float, n_obstacles: int = 0) -> list[Primitive]:
    """Obstacles of ``scene`` (an id or a family) for ``seed`` (deterministic), ``arena_half`` m.

    ``n_obstacles`` 0 means the scene's default count. Versions of one family give the same obstacles.
    """
    spec = scene_spec(scene)
    rng = np.random.default_rng([seed, spec.stream])
    return spec.generator(rng, arena_half, n_obstacles or spec.default_count)


def floor_tile_m(scene: str) -> float:
    """Edge of the square floor tiles of ``scene``'s surroundings, m: few, large tiles (each body costs ~0.2-0.3 ms
    per reset), 6 m indoors and 7 m outdoors; tile corners lie on the multiples of it."""
    return 6.0 if scene_spec(scene).indoor else 7.0


def decor(scene: str, arena_half: float) -> list[Primitive]:
    """Visual-only surroundings of ``scene``: floor tiles, and room walls + ceiling (indoor) or sky (outdoor).

    Room walls stand 1 m beyond the arena edge (``arena_half`` m), so leaving the arena ends an episode before
    the drone could touch them; they are scenery, not obstacles.
    """
    spec = scene_spec(scene)
    out = []
    ext = arena_half + (1.0 if spec.indoor else 6.0)
    tile = floor_tile_m(scene)
    k = math.ceil(ext / tile)
    ftex = spec.floor_texture
    for i in range(-k, k):
        for j in range(-k, k):
            out.append(
                Primitive(
                    "box",
                    ((i + 0.5) * tile, (j + 0.5) * tile, -0.05),
                    (tile / 2, tile / 2, 0.05),
                    rgba=(1, 1, 1, 1),
                    texture=ftex,
                    visual_only=True,
                )
            )
    if spec.indoor:
        wt = spec.wall_texture
        hgt = 3.0
        e = arena_half + 1.0
        for sx, sy, hx, hy in ((e, 0, 0.1, e), (-e, 0, 0.1, e), (0, e, e, 0.1), (0, -e, e, 0.1)):
            out.append(
                Primitive(
                    "box",
                    (sx, sy, hgt / 2),
                    (hx, hy, hgt / 2),
                    rgba=(1, 1, 1, 1),
                    texture=wt,
                    visual_only=True,
                )
            )
        out.append(
            Primitive(
                "box",
                (0, 0, hgt + 0.05),
                (e, e, 0.05),
                rgba=(0.92, 0.92, 0.9, 1),
                texture="paint:ceiling",
                visual_only=True,
            )
        )
    else:
        e = arena_half + 6.0
        hgt = 14.0
        for sx, sy, hx, hy in ((e, 0, 0.1, e), (-e, 0, 0.1, e), (0, e, e, 0.1), (0, -e, e, 0.1)):
            out.append(
                Primitive(
                    "box",
                    (sx, sy, hgt / 2 - 1),
                    (hx, hy, hgt / 2),
                    rgba=(1, 1, 1, 1),
                    texture="sky:0",
                    visual_only=True,
                )
            )
    return out


def layout_to_primitives(layout: Sequence[dict]) -> list[Primitive]:
    """Convert a user layout into primitives.

    Each entry is a dict with ``kind`` (``box``/``cylinder``/``sphere``), ``position`` (x, y) — standing on
    the floor — or (x, y, z) — centre —, ``size`` (box: full extents (sx, sy, sz); cylinder: (radius,
    height); sphere: (radius,)), optional ``yaw`` (rad), ``color`` (rgb or rgba in [0, 1]), ``texture``.
    """
    out = []
    for i, item in enumerate(layout):
        try:
            kind = item["kind"]
            pos = [float(v) for v in item["position"]]
            size = [float(v) for v in item["size"]]
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"layout[{i}]: needs 'kind', 'position' and 'size' ({e})") from None
        if kind == "box":
            if len(size) != 3:
                raise ValueError(f"layout[{i}] box: size needs (sx, sy, sz), got {size}")
            half = (size[0] / 2, size[1] / 2, size[2] / 2)
            height = size[2]
        elif kind == "cylinder":
            if len(size) != 2:
                raise ValueError(f"layout[{i}] cylinder: size needs (radius, height), got {size}")
            half = (size[0], size[0], size[1] / 2)
            height = size[1]
        elif kind == "sphere":
            if len(size) != 1:
                raise ValueError(f"layout[{i}] sphere: size needs (radius,), got {size}")
            half = (size[0],) * 3
            height = 2 * size[0]
        else:
            raise ValueError(f"layout[{i}]: kind must be box, cylinder or sphere, got {kind!r}")
        if len(pos) == 2:
            pos.append(height / 2)
        if len(pos) != 3:
            raise ValueError(f"layout[{i}]: position needs (x, y) or (x, y, z), got {pos}")
        if min(half) <= 0 or not all(math.isfinite(v) for v in (*size, *pos)):
            raise ValueError(
                f"layout[{i}]: sizes must be positive and positions finite, got size {size}, position {pos}"
            )
        unknown = set(item) - {"kind", "position", "size", "yaw", "color", "texture"}
        if unknown:
            raise ValueError(f"layout[{i}]: unknown fields {sorted(unknown)}")
        color = tuple(float(c) for c in item.get("color", (0.7, 0.7, 0.7)))
        if len(color) not in (3, 4) or not all(0.0 <= c <= 1.0 for c in color):
            raise ValueError(f"layout[{i}]: color needs 3 or 4 values in [0, 1], got {color}")
        rgba = (*color[:3], color[3] if len(color) > 3 else 1.0)
        out.append(
            Primitive(
                kind,
                tuple(pos),
                half,
                yaw=float(item.get("yaw", 0.0)),
                rgba=rgba,
                texture=item.get("texture"),
            )
        )
    return out


@dataclass(frozen=True)
class FixedLayout:
    """A scene generator that always returns the same course (a user ``layout``, see :func:`layout_to_primitives`):
    the start and goal still change with the episode's seed. Compared by value, so registering the same course
    twice is not a conflict."""

    layout: tuple

    def __call__(self, rng: np.random.Generator, arena_half: float, n: int) -> list[Primitive]:
        return layout_to_primitives([dict(item) for item in self.layout])


def course_scene(
    family: str,
    layout: Sequence[dict],
    *,
    look: str = "box-v0",
    version: int = 0,
    difficulty: str = "medium",
    description: str = "",
) -> SceneSpec:
    """Register a fixed course as a scene ``<family>-v<version>`` in the surroundings (floor, walls) of ``look``.

    A registered scene is what training (``env.scene``), evaluation and Table I (``eval.scenes``) take by name,
    and its id enters every run key and cache key, so runs on two courses never mix. ``layout``: dicts as in
    :func:`layout_to_primitives`. Raises ValueError for a malformed layout (before anything is registered) or an id
    already registered with another course.
    """
    layout_to_primitives(layout)  # a malformed course fails here, naming the entry
    frozen = tuple(tuple(sorted((k, _frozen(v)) for k, v in item.items())) for item in layout)
    base = scene_spec(look)
    spec = SceneSpec(
        family,
        version,
        FixedLayout(frozen),
        stream=base.stream,
        default_count=len(layout),
        indoor=base.indoor,
        floor_texture=base.floor_texture,
        wall_texture=base.wall_texture,
        materials=(),  # a course's obstacles carry their own colour or texture (layout_to_primitives)
        difficulty=difficulty,
        paper_scene=None,
        description=description or f"a fixed course of {len(layout)} obstacles in {base.id}'s surroundings",
    )
    return register_scene(spec)


def _frozen(v: Any) -> Any:
    return tuple(_frozen(x) for x in v) if isinstance(v, (list, tuple)) else v
