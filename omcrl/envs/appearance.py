"""How a scene looks in ``NavEnv``: its bodies in PyBullet, their materials, and the disturbances of appearance.

:class:`Disturbance` describes changes of lighting, colour and look (paper V-D, the real-world tests of VI-B, the
kit's zero-shot diagnosis); :class:`SceneLook` is the part of :class:`omcrl.envs.nav_env.NavEnv` that builds a
layout's bodies from a pool, gives each its material (its own, another scene's, or a random generic one) and
sets the light of each render.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields
from typing import Any

import cv2
import numpy as np

from omcrl.config import ConfigError, show
from omcrl.envs.textures import TEXTURE_KINDS, texture_file
from omcrl.scenes import SCENE_SPECS, decor, generate_scene, scene_id, scene_spec
from omcrl.scenes.geometry import Primitive
from omcrl.utils.quiet import import_quietly

pb = import_quietly("pybullet")  # without the build-time line PyBullet prints on stderr

APPEARANCE_PARTS = ("all", "surroundings", "obstacles")


# Textures for randomized looks: only kinds no evaluation scene (furniture, barrier, tree) uses (not paint:
# furniture's room and barrier's walls are painted), so randomized box data never shows an unseen scene's material.
GENERIC_TEXTURES = tuple(
    f"{kind}:{k}" for kind in ("tiles", "carpet", "checker", "stripes", "crate") for k in range(10)
)


POOL_SLACK = 24  # pooled bodies allowed beyond the current layout's count before a full rebuild


@dataclass
class Disturbance:
    """Visual disturbances (paper VI-B, real-world tests; VI-C t-SNE), applied at render time.

    Attributes
    ----------
    obstacle_colors : ``"random"`` gives each obstacle a random colour (textures kept, tinted).
    obstacle_texture : a texture kind (e.g. ``"checker"``) put on every obstacle instead of its own.
    ambient, diffuse, specular : light coefficients in [0, 1] (TinyRenderer); None keeps the default.
    light_direction : (3,) direction the light comes from; None keeps the default.
    switch_step : at this step of an episode the light switches to ``switch_ambient``/``switch_diffuse``
        (the paper's lights-off test); None for no switch.
    switch_range : (lo, hi): the switch happens at a step drawn uniformly from [lo, hi] for every episode
        (reproducibly from ``seed`` and the episode's layout seed); overrides ``switch_step``.
    brightness : multiplier on the image (1 = unchanged).
    hue : hue rotation of the image, degrees.
    seed : seed for the random colours.
    appearance : render this env's layout with another scene's look: that scene's surroundings (floor, walls
        and ceiling, or grass and sky) and obstacle materials (colours and textures drawn from the materials
        its own generator uses). Geometry, collisions, start/goal and rewards are untouched, so geometry and
        appearance can be varied separately (e.g. the furniture layout with the box look). None: own look.
    appearance_parts : what ``appearance`` swaps: ``"all"``, ``"surroundings"`` (floor, walls, ceiling or sky
        only) or ``"obstacles"`` (obstacle materials only).
    randomize_look : a new random look for every layout: floor, room walls and each obstacle get a texture drawn
        from :data:`GENERIC_TEXTURES` (kinds and variants no evaluation scene uses) and a random tint. For
        pretraining data that varies what box cannot (``data.look=randomized``, a deviation behind a flag).
    """

    obstacle_colors: str | None = None
    obstacle_texture: str | None = None
    ambient: float | None = None
    diffuse: float | None = None
    specular: float | None = None
    light_direction: tuple[float, float, float] | None = None
    switch_step: int | None = None
    switch_range: tuple[int, int] | None = None
    switch_ambient: float = 0.25
    switch_diffuse: float = 0.15
    brightness: float = 1.0
    hue: float = 0.0
    seed: int = 0
    appearance: str | None = None
    appearance_parts: str = "all"
    randomize_look: bool = False

    @classmethod
    def from_any(cls, d: Disturbance | dict | None) -> Disturbance | None:
        if d is None or isinstance(d, Disturbance):
            return d
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ConfigError(f"disturbance: unknown fields {sorted(unknown)}; known: {sorted(known)}")
        out = cls(**d)
        if out.obstacle_colors not in (None, "random"):
            raise ConfigError(f"disturbance.obstacle_colors: got {out.obstacle_colors!r}, expected None or 'random'")
        if out.obstacle_texture is not None:
            if out.obstacle_texture not in TEXTURE_KINDS:
                raise ConfigError(
                    f"disturbance.obstacle_texture: got {show(out.obstacle_texture)}, expected None or one of "
                    f"{list(TEXTURE_KINDS)}"
                )

        def number(name: str, lo: float | None = None, hi: float | None = None, integer: bool = False) -> None:
            v = getattr(out, name)
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            ok = ok and (not integer or float(v).is_integer())
            ok = ok and (lo is None or v >= lo) and (hi is None or v <= hi)
            if not ok:
                rng = f" in [{lo}, {hi}]" if hi is not None else (f" >= {lo}" if lo is not None else "")
                raise ConfigError(
                    f"disturbance.{name}: got {show(v)}, expected a{'n integer' if integer else ' number'}{rng}"
                )

        for name in ("ambient", "diffuse", "specular"):
            if getattr(out, name) is not None:
                number(name, 0.0, 1.0)
        number("switch_ambient", 0.0, 1.0)
        number("switch_diffuse", 0.0, 1.0)
        number("brightness", 0.0)
        number("hue", -360.0, 360.0)
        number("seed", 0, integer=True)
        if out.appearance is not None:
            try:
                out.appearance = scene_id(out.appearance)
            except ValueError:
                raise ConfigError(
                    f"disturbance.appearance: got {show(out.appearance)}, expected None or one of {list(SCENE_SPECS)}"
                ) from None
        if out.appearance_parts not in APPEARANCE_PARTS:
            raise ConfigError(
                f"disturbance.appearance_parts: got {show(out.appearance_parts)}, expected one of {APPEARANCE_PARTS}"
            )
        if out.switch_step is not None:
            number("switch_step", 0, integer=True)
        if out.switch_range is not None:
            sr = out.switch_range
            if not (
                isinstance(sr, (list, tuple))
                and len(sr) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in sr)
                and sr[0] <= sr[1]
            ):
                raise ConfigError(f"disturbance.switch_range: got {show(sr)}, expected two integers 0 <= lo <= hi")
            out.switch_range = (int(sr[0]), int(sr[1]))
        if out.light_direction is not None:
            ld = out.light_direction
            if not (isinstance(ld, (list, tuple)) and len(ld) == 3 and all(isinstance(v, (int, float)) for v in ld)):
                raise ConfigError(f"disturbance.light_direction: got {show(ld)}, expected three numbers (x, y, z)")
        return out


@functools.lru_cache(maxsize=8)
def appearance_materials(scene: str, arena_half: float) -> tuple[tuple[tuple, str | None], ...]:
    """The obstacle materials (rgba, texture) of ``scene``'s generator, from four fixed layouts, in a fixed
    order: the palette an appearance swap draws from (box: its one crate look; tree: barks and leaves; ...)."""
    looks: dict[tuple, None] = {}
    for seed in range(4):
        for p in generate_scene(scene, seed, arena_half):
            if not p.visual_only:
                looks[(tuple(p.rgba), p.texture)] = None
    return tuple(looks)


def box_edges_xy(prims: list[Primitive]) -> np.ndarray:
    """Where the vertical edges of the boxes among ``prims`` stand: distinct (x, y) m, shape (N, 2).

    A horizontal camera's plane holds a box corner exactly when it holds that corner's vertical edge, so these
    points are what :meth:`omcrl.envs.nav_env.NavEnv._camera_image` keeps it clear of.
    """
    boxes = [p for p in prims if p.kind == "box"]
    if not boxes:
        return np.zeros((0, 2))
    c = np.array([p.center[:2] for p in boxes])
    h = np.array([p.size[:2] for p in boxes])
    yaw = np.array([p.yaw for p in boxes])
    rot = np.stack([np.stack([np.cos(yaw), -np.sin(yaw)], -1), np.stack([np.sin(yaw), np.cos(yaw)], -1)], -2)
    signs = np.array([(1, 1), (1, -1), (-1, 1), (-1, -1)], np.float64)
    corners = c[:, None, :] + np.einsum("bij,bkj->bki", rot, signs[None] * h[:, None, :])
    return np.unique(corners.reshape(-1, 2), axis=0)


# A body's bounding sphere is its primitive's (half-diagonal of a box, a cylinder's corner circle, a sphere's radius),
# grown by this factor and margin (m) to cover PyBullet's tessellation and float rounding: the test must never drop a
# body that puts a pixel in the frame. Measured with 1.05 and 0.02: 0 of 1,800 random poses differed in any scene.
CULL_RADIUS_FACTOR = 1.05
CULL_RADIUS_MARGIN_M = 0.02
# Pixels of slack beyond the image's edge in the side tests (TinyRenderer samples pixel corners 0 … W-1).
CULL_EDGE_PX = 2.0


def bounding_radius(p: Primitive) -> float:
    """The radius (m) of a sphere about ``p.center`` that holds all of ``p``'s visual mesh, with the margins above."""
    if p.kind == "box":
        r = float(np.linalg.norm(p.size))
    elif p.kind == "cylinder":
        r = math.hypot(p.size[0], p.size[2])
    else:
        r = float(p.size[0])
    return r * CULL_RADIUS_FACTOR + CULL_RADIUS_MARGIN_M


class CullSet:
    """The bodies of a layout that a camera may or may not see, as bounding spheres, and which of them are drawn.

    TinyRenderer transforms every vertex of every body with a non-zero alpha, whether it can reach the image or not
    (tree-v2's trees: most of its 8,000 triangles for a view that shows a few). :meth:`drawn` says which bodies can
    put a pixel in a frame, by what TinyRenderer itself does (``examples/TinyRenderer``): a triangle whose three
    vertices lie behind the camera plane (w < 0) is discarded; one in front of it is rasterised only inside the
    image. So a body is left out when its sphere lies wholly behind the camera plane, or wholly in front of it and
    wholly beyond one side plane of the view. A body that straddles the camera plane is always drawn: a vertex *in*
    that plane is the fault :data:`omcrl.envs.nav_env.RENDER_NUDGES_M` re-renders for, and leaving such a body out
    could hide the fault and change which frame is kept. The far plane is not used (it changes no frame here to
    keep bodies beyond it). The frames are bit-identical with and without (``tests/test_render_cull.py``).

    Attributes
    ----------
    ids : (N,) int, PyBullet body ids.
    centers : (N, 3) m, world frame.
    radii : (N,) m.
    state : (N,) bool, whether each body is drawn now.
    """

    def __init__(self, ids: np.ndarray, centers: np.ndarray, radii: np.ndarray, state: np.ndarray) -> None:
        self.ids, self.centers, self.radii, self.state = ids, centers, radii, state

    @classmethod
    def of(cls, bodies: list[int], prims: list[Primitive], hidden: set[int]) -> CullSet:
        """The set for ``bodies[i]`` placed as ``prims[i]``; those in ``hidden`` are not drawn now."""
        return cls(
            np.asarray(bodies, np.int64),
            np.array([p.center for p in prims], np.float64).reshape(-1, 3),
            np.array([bounding_radius(p) for p in prims], np.float64),
            np.array([b not in hidden for b in bodies], bool),
        )

    def drawn(self, eye: np.ndarray, yaw: float, tan_h: float, tan_v: float, width: int, height: int) -> np.ndarray:
        """(N,) bool: the bodies that may put a pixel in a ``width`` × ``height`` frame from a level camera at ``eye``
        (m) looking along ``yaw`` (rad), whose half-angles have tangents ``tan_h`` (horizontal) and ``tan_v``."""
        c, s = math.cos(yaw), math.sin(yaw)
        d = self.centers - eye
        z = d[:, 0] * c + d[:, 1] * s  # depth along the optical axis
        x = d[:, 0] * s - d[:, 1] * c  # across it, horizontal
        y = d[:, 2]  # across it, vertical (the camera is level)
        r = self.radii
        th = tan_h * (1.0 + 2.0 * CULL_EDGE_PX / width)
        tv = tan_v * (1.0 + 2.0 * CULL_EDGE_PX / height)
        # Distance of the centre beyond each side plane (planes through the eye): > r means wholly outside.
        beyond_h = (np.abs(x) - th * z) / math.sqrt(1.0 + th * th)
        beyond_v = (np.abs(y) - tv * z) / math.sqrt(1.0 + tv * tv)
        behind = z + r < 0.0
        outside = (z - r > 0.0) & ((beyond_h > r) | (beyond_v > r))
        return ~(behind | outside)


class SceneLook:
    """The bodies and looks of a :class:`omcrl.envs.nav_env.NavEnv` (a mixin: it uses the env's PyBullet client,
    config, disturbance and look generator)."""

    def _build_bodies(self, prims: list[Primitive]) -> None:
        """Put ``prims`` in this env's PyBullet client (visual shapes only: we do our own collisions).

        Bodies are pooled by look (kind, size, colour, texture): a new layout moves pooled bodies that look
        right and hides the rest far below the floor, beyond the far plane, so the box scene's identical
        crates never need recreating. PyBullet frees visual shapes only on ``resetSimulation`` (``removeBody``
        leaks them: +9 MB per 300 layouts, measured), so when the pool outgrows the layout by ``POOL_SLACK``
        the world is rebuilt from scratch, which keeps memory bounded.
        """
        cid = self._client
        dist = self.disturbance
        randomize = dist is not None and dist.randomize_look
        # With randomized looks one generator lives as long as the env, so every layout draws a new look
        # (reproducibly from dist.seed); otherwise every layout gets the same draws.
        rng = self._look_rng if randomize else np.random.default_rng(dist.seed if dist else 0)
        looks = [self._look(p, rng) for p in prims]
        pooled = sum(len(v) for v in self._pool.values())
        if not self._decor_built or pooled > len(prims) + POOL_SLACK:
            pb.resetSimulation(physicsClientId=cid)
            self._tex_ids = {}
            self._pool = {}
            self._paint = {}
            self._hidden = set()
            self._decor_bodies = [
                (self._create(p, p.rgba, p.texture), p)
                for p in decor(self._look_scene("surroundings"), self.cfg.arena_half)
            ]
            self._decor_built = True
        if randomize:
            self._randomize_surroundings(rng)
        free = {k: list(v) for k, v in self._pool.items()}
        placed = [body for body, _ in self._decor_bodies]
        for p, (rgba, tex) in zip(prims, looks):
            key = (p.kind, p.size, rgba, tex)
            orn = pb.getQuaternionFromEuler((0, 0, p.yaw))
            if free.get(key):
                placed.append(free[key].pop())
                pb.resetBasePositionAndOrientation(placed[-1], p.center, orn, physicsClientId=cid)
            else:
                placed.append(self._create(p, rgba, tex))
                self._pool.setdefault(key, []).append(placed[-1])
        hidden = []
        for key, bodies in free.items():
            for body in bodies:
                pb.resetBasePositionAndOrientation(body, (0.0, 0.0, -1000.0), (0, 0, 0, 1), physicsClientId=cid)
                hidden.append(Primitive(key[0], (0.0, 0.0, -1000.0), key[1]))
                if self.cull:  # parked: never drawn until a layout places it again
                    self._set_drawn(body, False)
        shown = [p for _, p in self._decor_bodies] + list(prims)  # what `placed` holds, body for body
        self._cull_set = CullSet.of(placed, shown, self._hidden)
        # Every box the renderer draws, hidden ones too (they stand below the origin, still in the camera's plane
        # when it passes through it): NavEnv._camera_image keeps that plane off their vertical edges.
        self._box_edges_xy = box_edges_xy(shown + hidden)

    def _look_scene(self, part: str) -> str:
        """The scene whose ``part`` (``surroundings`` or ``obstacles``) this env renders: its own unless swapped."""
        d = self.disturbance
        if d is not None and d.appearance and d.appearance_parts in ("all", part):
            return d.appearance
        return self.scene

    def _randomize_surroundings(self, rng: np.random.Generator) -> None:
        """Give the floor one random generic texture and the room walls another, each with a random tint."""
        cid = self._client
        floor, walls = (str(rng.choice(GENERIC_TEXTURES)) for _ in range(2))
        tints = [(*rng.uniform(0.5, 1.0, 3).tolist(), 1.0) for _ in range(2)]
        for body, p in self._decor_bodies:
            if p.center[2] < 0:  # floor tiles
                tex, rgba = floor, tints[0]
            elif p.size[2] > 0.5:  # walls (the ceiling is a thin slab; the sky stays sky)
                if p.texture and p.texture.startswith("sky"):
                    continue
                tex, rgba = walls, tints[1]
            else:
                continue
            if tex not in self._tex_ids:
                self._tex_ids[tex] = pb.loadTexture(texture_file(tex), physicsClientId=cid)
            pb.changeVisualShape(body, -1, textureUniqueId=self._tex_ids[tex], rgbaColor=rgba, physicsClientId=cid)
            self._paint[body] = rgba
            self._hidden.discard(body)  # painted with its alpha: drawn again until the next cull says otherwise

    def _look(self, p: Primitive, rng: np.random.Generator) -> tuple[tuple, str | None]:
        """Colour and texture of an obstacle after the disturbance (appearance swap, random colours, replaced
        textures)."""
        rgba, tex = tuple(p.rgba), p.texture
        dist = self.disturbance
        look = self._look_scene("obstacles")
        # Versions of a family share the generator and so its materials: only another family's are a swap.
        if scene_spec(look).family != scene_spec(self.scene).family and not p.visual_only:
            pool = appearance_materials(look, self.cfg.arena_half)
            rgba, tex = pool[int(rng.integers(len(pool)))]
        if dist is not None and dist.randomize_look and not p.visual_only:
            tex = str(rng.choice(GENERIC_TEXTURES))
            rgba = (*np.round(rng.uniform(0.4, 1.0, 3), 2).tolist(), 1.0)
        if dist is not None and not p.visual_only:
            if dist.obstacle_texture:
                tex = f"{dist.obstacle_texture}:{rng.integers(8)}"
            if dist.obstacle_colors == "random":
                rgba = (*rng.uniform(0.15, 1.0, 3).tolist(), 1.0)
        return rgba, tex

    def _create(self, p: Primitive, rgba: tuple, tex: str | None) -> int:
        """One static visual body for primitive ``p`` with the given look; returns its body id."""
        cid = self._client
        if p.kind == "box":
            vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=p.size, rgbaColor=rgba, physicsClientId=cid)
        elif p.kind == "cylinder":
            vis = pb.createVisualShape(
                pb.GEOM_CYLINDER, radius=p.size[0], length=2 * p.size[2], rgbaColor=rgba, physicsClientId=cid
            )
        else:
            vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=p.size[0], rgbaColor=rgba, physicsClientId=cid)
        body = pb.createMultiBody(
            0,
            -1,
            vis,
            basePosition=p.center,
            baseOrientation=pb.getQuaternionFromEuler((0, 0, p.yaw)),
            physicsClientId=cid,
        )
        if tex:
            if tex not in self._tex_ids:
                self._tex_ids[tex] = pb.loadTexture(texture_file(tex), physicsClientId=cid)
            pb.changeVisualShape(body, -1, textureUniqueId=self._tex_ids[tex], rgbaColor=rgba, physicsClientId=cid)
        self._paint[body] = tuple(rgba)
        return body

    def _set_drawn(self, body: int, drawn: bool) -> None:
        """Draw ``body`` with its own colour, or give it alpha 0, which TinyRenderer skips without a vertex
        transformed (its texture stays bound, so drawing it again restores the very same pixels)."""
        if drawn == (body not in self._hidden):
            return
        rgba = self._paint[body]
        pb.changeVisualShape(body, -1, rgbaColor=rgba if drawn else (*rgba[:3], 0.0), physicsClientId=self._client)
        if drawn:
            self._hidden.discard(body)
        else:
            self._hidden.add(body)

    def _cull_to(self, eye: np.ndarray, yaw: float, tan_h: float, tan_v: float, width: int, height: int) -> None:
        """Before a TinyRenderer frame: draw only the bodies that can put a pixel in it (:class:`CullSet`)."""
        cs = self._cull_set
        if cs is None:
            return
        drawn = cs.drawn(eye, yaw, tan_h, tan_v, width, height)
        for i in np.flatnonzero(drawn != cs.state):
            self._set_drawn(int(cs.ids[i]), bool(drawn[i]))
        cs.state = drawn

    def _light(self) -> dict:
        d = self.disturbance
        if d is None:
            return {}
        kw: dict[str, Any] = {}
        if d.ambient is not None:
            kw["lightAmbientCoeff"] = d.ambient
        if d.diffuse is not None:
            kw["lightDiffuseCoeff"] = d.diffuse
        if d.specular is not None:
            kw["lightSpecularCoeff"] = d.specular
        if d.light_direction is not None:
            kw["lightDirection"] = list(d.light_direction)
        if self.light_switch_step is not None and self._steps >= self.light_switch_step:
            kw["lightAmbientCoeff"] = d.switch_ambient
            kw["lightDiffuseCoeff"] = d.switch_diffuse
        return kw

    def _draw_switch(self, layout_seed: int) -> int | None:
        """The step at which this episode's light switches (None: no switch); see ``Disturbance.switch_range``."""
        d = self.disturbance
        if d is None:
            return None
        if d.switch_range is not None:
            lo, hi = d.switch_range
            return int(np.random.default_rng([d.seed, max(layout_seed, 0), 11]).integers(lo, hi + 1))
        return d.switch_step


def _adjust(rgb: np.ndarray, brightness: float, hue_deg: float) -> np.ndarray:
    """Brightness multiplier and hue rotation of an (H, W, 3) uint8 image."""
    if hue_deg:
        hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
        # OpenCV stores hue in [0, 180) for uint8 images.
        hsv[..., 0] = ((hsv[..., 0].astype(np.int32) + round(hue_deg / 2)) % 180).astype(np.uint8)
        rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    if brightness != 1.0:
        rgb = np.clip(rgb.astype(np.float32) * brightness, 0, 255).astype(np.uint8)
    return rgb
