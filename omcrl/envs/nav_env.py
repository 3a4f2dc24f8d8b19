"""``NavEnv``: first-person drone navigation to a goal, in PyBullet (paper III-A, IV-C, V-A, V-D).

The drone flies at a fixed altitude and is commanded in its body frame with (vx, vy, ωz). Each command goes
through a first-order velocity response with an acceleration limit (a Tello-like model). A forward camera
(FOV 82.6°) renders RGB and linear depth with PyBullet's TinyRenderer in DIRECT mode, one physics client per
env. Collisions, the nearest obstacle and the occupancy map come from the analytic geometry of the scene (see
:mod:`omcrl.scenes.geometry`), never from PyBullet contacts, so one step costs one render.

Observation (dict)
------------------
``rgb``        uint8   (L, 3, H, W)  last L camera frames, oldest first
``depth``      float32 (L, H, W)     linear depth along the optical axis, m, clipped to ``far``
``state``      float32 (12,)         v (3, body, m/s), ω (3, rad/s), θ (roll, pitch, yaw, rad), Δp_goal (3, body, m)
``privileged`` float32 (6,)          Δp to the nearest obstacle surface point (3, body, m), Δp_goal (3, body, m)

Action: float32 (3,) in [-1, 1], scaled to (vx, vy, ωz) by ``max_speed`` and ``max_yaw_rate``; values outside
are clipped, NaN is an error.

Reward (see docs/ARCHITECTURE.md and docs/DEVIATIONS.md): ``-1/H_max`` per step, plus the progress term
``progress_scale·(d_{t-1} - d_t)`` (default, potential-based) or the paper's literal ``progress_scale·(d_init -
d_t)``, plus ``goal_reward`` on success or ``collision_penalty`` on a collision or leaving the arena.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
from gymnasium import spaces

from omcrl.config import ConfigError, EnvConfig, _check_value, show, validate_env
from omcrl.envs.grid import OccupancyGrid, build_grid, components, shortest_path
from omcrl.envs.render import load_egl, pybullet_renderer, resolve_renderer
from omcrl.envs.textures import TEXTURE_KINDS, texture_file
from omcrl.scenes import SCENE_SPECS, decor, generate_scene, layout_to_primitives, scene_id, scene_spec
from omcrl.scenes.geometry import Geometry, Primitive
from omcrl.utils.quiet import import_quietly

pb = import_quietly("pybullet")  # without the build-time line PyBullet prints on stderr

GRAVITY = 9.81
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


class NavEnv(gym.Env):
    """Goal-reaching drone navigation from a monocular camera; see the module docstring for the contract."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        scene: str | None = None,
        seed: int | None = None,
        image_size: int | None = None,
        frame_stack: int | None = None,
        disturbance: Disturbance | dict | None = None,
        layout: list[dict] | None = None,
        config: EnvConfig | None = None,
        render_mode: str | None = "rgb_array",
        **overrides: Any,
    ) -> None:
        cfg = EnvConfig(**asdict(config)) if config is not None else EnvConfig()
        # Explicit arguments win over the config; every value is validated like a config field.
        given = {"scene": scene, "image_size": image_size, "frame_stack": frame_stack}
        values = {**{k: v for k, v in given.items() if v is not None}, **overrides}
        by_name = {f.name: f for f in fields(EnvConfig)}
        for k, v in values.items():
            if k not in by_name:
                raise ConfigError(f"env option '{k}' does not exist; known: {sorted(by_name)}")
            setattr(cfg, k, _check_value(f"env.{k}", by_name[k], v))
        validate_env(cfg)
        self.cfg = cfg
        self.scene = cfg.scene
        self.disturbance = Disturbance.from_any(disturbance)
        self._look_rng = np.random.default_rng([self.disturbance.seed if self.disturbance else 0, 7])
        try:
            self.layout = layout_to_primitives(layout) if layout is not None else None
        except ValueError as e:
            raise ConfigError(f"env option 'layout': {e}") from None
        self._init_seed = seed
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ConfigError(
                f"render_mode: got {render_mode!r}, allowed values are {[None, *self.metadata['render_modes']]}"
            )
        self.render_mode = render_mode
        L, S = cfg.frame_stack, cfg.image_size
        self.dt = 1.0 / cfg.control_hz
        self.h_max = cfg.step_penalty_horizon or cfg.max_steps
        self.observation_space = spaces.Dict(
            {
                "rgb": spaces.Box(0, 255, (L, 3, S, S), np.uint8),
                "depth": spaces.Box(0.0, cfg.far, (L, S, S), np.float32),
                # Finite bounds that no reachable value exceeds (arena and far plane are tens of metres).
                "state": spaces.Box(-1e3, 1e3, (12,), np.float32),
                "privileged": spaces.Box(-1e3, 1e3, (6,), np.float32),
            }
        )
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self._scale = np.array([cfg.max_speed, cfg.max_speed, cfg.max_yaw_rate])
        # Substeps keep each move shorter than the drone radius, so thin walls cannot be tunnelled through.
        self._substeps = max(1, math.ceil(cfg.max_speed * self.dt / cfg.drone_radius - 1e-9))
        sub_dt = self.dt / self._substeps
        self._k_resp = 1.0 - math.exp(-sub_dt / cfg.velocity_tau) if cfg.velocity_tau > 0 else 1.0
        self._client = pb.connect(pb.DIRECT)
        self.renderer = resolve_renderer(cfg.renderer)  # "tiny" or "egl"
        if self.renderer == "egl":
            load_egl(self._client)
        self._pb_renderer = pybullet_renderer(self.renderer)
        self._proj = pb.computeProjectionMatrixFOV(cfg.fov_deg, 1.0, cfg.near, cfg.far)
        self._built_key: Any = None
        self._decor_built = False
        self._tex_ids: dict[str, int] = {}
        self._pool: dict[tuple, list[int]] = {}
        self._geometry = Geometry()
        self._prims: list[Primitive] = []
        self.grid: OccupancyGrid | None = None
        self.path = np.zeros((0, 2))
        self.light_switch_step: int | None = None
        self._rgb = np.zeros((L, 3, S, S), np.uint8)
        self._depth = np.zeros((L, S, S), np.float32)
        self._episode_seed = -1
        self._layout_seed = -1
        self._episodes = 0
        self._has_episode = False
        self._prefetched: _Plan | None = None

    # ------------------------------------------------------------------ world
    def _maps(self, prims: list[Primitive]) -> tuple[Geometry, OccupancyGrid]:
        """Collision geometry and occupancy grid of a layout (pure computation: no PyBullet)."""
        c = self.cfg
        geo = Geometry.from_primitives(prims)
        return geo, build_grid(geo, c.arena_half, c.altitude, c.grid_resolution, c.drone_radius)

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
            self._decor_bodies = [
                (self._create(p, p.rgba, p.texture), p)
                for p in decor(self._look_scene("surroundings"), self.cfg.arena_half)
            ]
            self._decor_built = True
        if randomize:
            self._randomize_surroundings(rng)
        free = {k: list(v) for k, v in self._pool.items()}
        for p, (rgba, tex) in zip(prims, looks):
            key = (p.kind, p.size, rgba, tex)
            orn = pb.getQuaternionFromEuler((0, 0, p.yaw))
            if free.get(key):
                pb.resetBasePositionAndOrientation(free[key].pop(), p.center, orn, physicsClientId=cid)
            else:
                self._pool.setdefault(key, []).append(self._create(p, rgba, tex))
        for bodies in free.values():
            for body in bodies:
                pb.resetBasePositionAndOrientation(body, (0.0, 0.0, -1000.0), (0, 0, 0, 1), physicsClientId=cid)

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
        return body

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if self._client < 0:
            raise RuntimeError("NavEnv.reset called on a closed env")
        if seed is None and not self._has_episode and self._init_seed is not None:
            seed = self._init_seed
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"start", "goal"}
        if unknown:
            raise ValueError(f"reset options: unknown keys {sorted(unknown)}; expected 'start' and/or 'goal'")
        rng = self.np_random
        plan = self._prefetched
        self._prefetched = None
        if plan is not None and seed is None and not options and plan.valid(self._episodes, rng):
            rng.bit_generator.state = plan.rng_after  # as if planned just now
        else:
            plan = self._plan(reseed=seed is not None, options=options)
        if plan.key != self._built_key:
            self._build_bodies(plan.prims)
            self._geometry, self.grid, self._prims = plan.geometry, plan.grid, plan.prims
            self._built_key = plan.key
        self._layout_seed = layout_seed = plan.layout_seed
        placed = plan.placed
        c = self.cfg
        start, goal, self.path, self._opt_len = placed
        self._episode_seed = layout_seed if self.layout is None else -1
        self._pos = np.array([start[0], start[1], c.altitude])
        self._yaw = float(start[2])
        self._vel = (0.0, 0.0)  # body frame, m/s
        self._wz = 0.0
        self._acc = (0.0, 0.0)  # body frame, m/s^2
        self._goal = np.array([goal[0], goal[1], c.altitude])
        self._steps = 0
        self.light_switch_step = self._draw_switch(layout_seed)
        self._d_init = self._d_prev = float(np.linalg.norm(self._goal[:2] - self._pos[:2]))
        self._min_d = self._d_init
        self._path_len = 0.0
        self._has_episode = True
        self._episodes += 1
        frame_rgb, frame_depth = self._render_frame()
        self._rgb[:] = frame_rgb
        self._depth[:] = frame_depth
        obs = self._obs(self._geometry.nearest(self._pos)[0])
        # The path is a list, not an array: its length varies, and vector envs can only stack fixed shapes.
        info = {
            "pose": self.pose,
            "goal": self._goal[:2].copy(),
            "path": self.path.tolist(),
            "optimal_path_length": self._opt_len,
            "layout_seed": self._episode_seed,
        }
        return obs, info

    def _plan(self, reseed: bool, options: dict) -> _Plan:
        """Layout, maps, start/goal and path of the next episode, drawn from ``self.np_random``.

        Pure computation (PyBullet is untouched), so it can run ahead of the reset (:meth:`prefetch`).
        ``reseed``: reset() got a seed, so the layout always follows from it.
        """
        c = self.cfg
        rng = self.np_random
        layout_seed, key = self._layout_seed, self._built_key
        prims, geometry, grid = self._prims, self._geometry, self.grid
        for attempt in range(50):
            # A new layout every `layout_every` episodes (and after a layout with no valid start/goal pair);
            # with a seed given to reset() the layout always follows from that seed.
            if reseed or attempt > 0 or self._episodes % c.layout_every == 0 or layout_seed < 0:
                layout_seed = int(rng.integers(2**31 - 1))
            new_key = ("layout", id(self.layout)) if self.layout is not None else (self.scene, layout_seed)
            if new_key != key:
                prims = (
                    self.layout
                    if self.layout is not None
                    else generate_scene(self.scene, layout_seed, c.arena_half, c.n_obstacles)
                )
                geometry, grid = self._maps(prims)
                key = new_key
            placed = self._place(options, grid, geometry)
            if placed is not None:
                return _Plan(self._episodes, None, None, layout_seed, key, prims, geometry, grid, placed)
            if self.layout is not None:
                raise ValueError(
                    "could not find a reachable start/goal pair in the given layout within the "
                    f"configured goal_distance {c.goal_distance} m"
                )
        raise RuntimeError(f"scene {self.scene!r}: no reachable start/goal found in 50 layouts")  # pragma: no cover

    @property
    def prefetched(self) -> bool:
        """True when the next automatic reset has been planned ahead by :meth:`prefetch`."""
        return self._prefetched is not None

    def prefetch(self) -> bool:
        """Plan the next automatic reset (``reset()`` without seed or options) now, while there is time.

        The plan is exactly what that reset would compute: it is drawn from a snapshot of the env's random
        generator, which is then put back, and the reset only adopts it when the generator and the episode
        count are still where the plan started (anything else, e.g. a reset with a seed, discards it). The
        vector env calls this while a process waits for another env's reset, which hides the planning
        (~70% of a box-scene reset) behind that wait.

        Returns
        -------
        bool : True when a plan was made (False before the first reset or when one is pending).
        """
        if not self._has_episode or self._prefetched is not None:
            return False
        rng = self.np_random
        before = rng.bit_generator.state
        plan = self._plan(reseed=False, options={})
        plan.rng_before, plan.rng_after = before, rng.bit_generator.state
        rng.bit_generator.state = before
        self._prefetched = plan
        return True

    def _place(self, options: dict, grid: OccupancyGrid, geometry: Geometry) -> tuple | None:
        """Start (x, y, yaw) and goal (x, y) from ``options`` or sampled free, reachable, at a distance in
        ``goal_distance`` on the layout of ``grid``/``geometry``; also the any-angle shortest path. None when
        this layout has no valid pair."""
        c = self.cfg
        clearance = c.drone_radius + 0.25
        rng = self.np_random
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

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        if self._client < 0:
            raise RuntimeError("NavEnv.step called on a closed env")
        if not self._has_episode:
            raise RuntimeError("NavEnv.step called before reset()")
        if np.shape(action) != (3,):  # (1, 3) or (3, 1) would hide a batching mistake
            raise ValueError(f"action: expected shape (3,), got {np.shape(action)}")
        if np.iscomplexobj(action):  # float64 conversion would drop the imaginary part with only a warning
            raise ValueError(f"action: expected real numbers, got complex values {np.asarray(action).tolist()}")
        a = np.asarray(action, dtype=np.float64)
        ax, ay, az = a.tolist()
        if not (math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az)):
            raise ValueError(f"action contains NaN or inf: {[ax, ay, az]}")
        c = self.cfg
        # Scalar math on purpose: on 2-vectors plain floats are several times cheaper than numpy calls, and
        # this loop is the only per-step work besides the render.
        cx = min(1.0, max(-1.0, ax)) * c.max_speed
        cy_cmd = min(1.0, max(-1.0, ay)) * c.max_speed
        cw = min(1.0, max(-1.0, az)) * c.max_yaw_rate
        dt = self.dt / self._substeps
        # First-order response toward the command, then the acceleration limit (Tello-like).
        k = self._k_resp
        lim = c.max_accel * dt
        collided = out = False
        geo = self._geometry
        vx, vy = self._vel
        px, py = float(self._pos[0]), float(self._pos[1])
        for _ in range(self._substeps):
            dvx, dvy = (cx - vx) * k, (cy_cmd - vy) * k
            n = math.hypot(dvx, dvy)
            if n > lim:
                dvx, dvy = dvx * lim / n, dvy * lim / n
            vx, vy = vx + dvx, vy + dvy
            self._acc = (dvx / dt, dvy / dt)
            self._wz += (cw - self._wz) * k
            self._yaw = _wrap(self._yaw + self._wz * dt)
            cyaw, syaw = math.cos(self._yaw), math.sin(self._yaw)
            mx, my = (cyaw * vx - syaw * vy) * dt, (syaw * vx + cyaw * vy) * dt
            px, py = px + mx, py + my
            self._path_len += math.hypot(mx, my)
            self._pos[0], self._pos[1] = px, py
            closest, dist = geo.nearest(self._pos)
            if dist <= c.drone_radius:
                collided = True
                break
            if abs(px) > c.arena_half or abs(py) > c.arena_half:
                out = True
                break
        self._vel = (vx, vy)
        self._steps += 1
        d = math.hypot(self._goal[0] - px, self._goal[1] - py)
        self._min_d = min(self._min_d, d)
        success = not (collided or out) and d <= c.goal_radius
        if c.progress == "difference":
            progress = c.progress_scale * (self._d_prev - d)
        else:
            progress = c.progress_scale * (self._d_init - d)
        self._d_prev = d
        reward = -1.0 / self.h_max + progress
        if success:
            reward += c.goal_reward
        elif collided or out:
            reward += c.collision_penalty
        terminated = bool(success or collided or out)
        truncated = bool(not terminated and self._steps >= c.max_steps)
        rgb, depth = self._render_frame()
        self._rgb[:-1] = self._rgb[1:]
        self._rgb[-1] = rgb
        self._depth[:-1] = self._depth[1:]
        self._depth[-1] = depth
        obs = self._obs(closest)
        info: dict[str, Any] = {"pose": self.pose, "goal": self._goal[:2].copy()}
        if terminated or truncated:
            info["metrics"] = {
                "final_distance": d,
                "min_distance": self._min_d,
                "success": bool(success),
                "collision": bool(collided),
                "out_of_arena": bool(out),
                "path_length": self._path_len,
                "optimal_path_length": self._opt_len,
                "steps": self._steps,
                "scene": self.scene,
                "seed": self._episode_seed,
            }
        return obs, float(reward), terminated, truncated, info

    # ------------------------------------------------------------------ sensors
    @property
    def pose(self) -> np.ndarray:
        """(x, y, yaw) in the world frame, m and rad."""
        return np.array([self._pos[0], self._pos[1], self._yaw])

    def _obs(self, closest: np.ndarray) -> dict:
        c, s = math.cos(self._yaw), math.sin(self._yaw)
        gx, gy = self._goal[0] - self._pos[0], self._goal[1] - self._pos[1]
        goal_b = (c * gx + s * gy, -s * gx + c * gy, 0.0)  # goal and drone share the flight altitude
        if self._geometry.n:
            ox, oy, oz = (closest - self._pos).tolist()
            obst_b = (c * ox + s * oy, -s * ox + c * oy, oz)
        else:  # nothing in range: report an obstacle at the far plane straight ahead
            obst_b = (self.cfg.far, 0.0, 0.0)
        pitch = math.atan2(self._acc[0], GRAVITY)
        roll = -math.atan2(self._acc[1], GRAVITY)
        vx, vy = self._vel
        state = np.array([vx, vy, 0.0, 0.0, 0.0, self._wz, roll, pitch, self._yaw, *goal_b], np.float32)
        priv = np.array([*obst_b, *goal_b], np.float32)
        return {"rgb": self._rgb.copy(), "depth": self._depth.copy(), "state": state, "privileged": priv}

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

    def obstacle_mask(self) -> np.ndarray:
        """(H, W) bool: pixels of the current camera view that show an obstacle (not floor, walls or sky).

        Renders the view once more with PyBullet's segmentation buffer (the observation renders skip it); for
        analysis such as the Grad-CAM mass on obstacles, not for training.
        """
        c = self.cfg
        S = c.image_size
        *_, seg = pb.getCameraImage(
            S,
            S,
            self.view_matrix(),
            self._proj,
            renderer=self._pb_renderer,
            shadow=0,
            physicsClientId=self._client,
            **self._light(),
        )
        bodies = [b for v in self._pool.values() for b in v]
        return np.isin(np.asarray(seg, np.int64).reshape(S, S), bodies)

    def view_matrix(self) -> list[float]:
        """PyBullet view matrix (16 floats) of the forward camera at the current pose (what renders use)."""
        eye = self._pos
        cy, sy = math.cos(self._yaw), math.sin(self._yaw)
        return pb.computeViewMatrix(eye.tolist(), [eye[0] + cy, eye[1] + sy, eye[2]], [0.0, 0.0, 1.0])

    def _render_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """One camera render (``self.renderer``): RGB (3, H, W) uint8 and linear depth (H, W) float32 in metres."""
        c = self.cfg
        view = self.view_matrix()
        S = c.image_size
        _, _, rgba, zbuf, _ = pb.getCameraImage(
            S,
            S,
            view,
            self._proj,
            renderer=self._pb_renderer,
            shadow=0,
            flags=pb.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self._client,
            **self._light(),
        )
        rgba = np.asarray(rgba, np.uint8).reshape(S, S, 4)
        zbuf = np.asarray(zbuf, np.float32).reshape(S, S)
        depth = c.far * c.near / (c.far - (c.far - c.near) * zbuf)
        rgb = rgba[..., :3]
        d = self.disturbance
        if d is not None and (d.brightness != 1.0 or d.hue != 0.0):
            rgb = _adjust(rgb, d.brightness, d.hue)
        return rgb.transpose(2, 0, 1), np.minimum(depth, c.far)

    def render_camera(self, width: int, height: int, vfov_deg: float) -> np.ndarray:
        """An RGB frame (height, width, 3) uint8 from the drone's camera pose through another pinhole camera
        (``vfov_deg`` vertical field of view, square pixels): what a real camera of that geometry would see here
        (the deploy tests stream such frames from a simulated Tello)."""
        c = self.cfg
        proj = pb.computeProjectionMatrixFOV(vfov_deg, width / height, c.near, c.far)
        _, _, rgba, _, _ = pb.getCameraImage(
            int(width),
            int(height),
            self.view_matrix(),
            proj,
            renderer=self._pb_renderer,
            shadow=0,
            flags=pb.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self._client,
            **self._light(),
        )
        return np.asarray(rgba, np.uint8).reshape(int(height), int(width), 4)[..., :3].copy()

    def render(self) -> np.ndarray | None:
        """The newest camera frame as (H, W, 3) uint8 with ``render_mode="rgb_array"``; None (and gymnasium's
        warning) without a render mode."""
        if self.render_mode is None:
            gym.logger.warn("NavEnv.render() called without a render_mode; make the env with render_mode='rgb_array'")
            return None
        return self._rgb[-1].transpose(1, 2, 0).copy()

    @property
    def primitives(self) -> list[Primitive]:
        """Obstacles of the current layout (collision geometry), for maps and plots."""
        return list(self._prims)

    def close(self) -> None:
        if getattr(self, "_client", None) is not None and self._client >= 0:
            try:
                pb.disconnect(physicsClientId=self._client)
            except pb.error:  # already disconnected
                pass
            self._client = -1

    def __del__(self) -> None:  # pragma: no cover - best effort at interpreter shutdown
        try:
            self.close()
        except Exception:
            pass


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


@dataclass
class _Plan:
    """Everything a reset decides before touching PyBullet (see ``NavEnv._plan``)."""

    episodes: int  # the env's episode count the plan was made at
    rng_before: dict | None  # generator state before/after planning (set by prefetch)
    rng_after: dict | None
    layout_seed: int
    key: Any  # identifies the layout (scene, seed) or the user layout
    prims: list[Primitive]
    geometry: Geometry
    grid: OccupancyGrid
    placed: tuple  # start (3,), goal (2,), path (K, 2), optimal length

    def valid(self, episodes: int, rng: np.random.Generator) -> bool:
        return episodes == self.episodes and rng.bit_generator.state == self.rng_before


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


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def make_env(
    scene: str | None = "box",
    seed: int | None = 0,
    image_size: int | None = None,
    frame_stack: int | None = None,
    disturbance: Disturbance | dict | None = None,
    layout: list[dict] | None = None,
    config: EnvConfig | None = None,
    **overrides: Any,
) -> NavEnv:
    """Build a :class:`NavEnv`.

    ``scene`` is a scene id (``furniture-v0``) or family (``furniture``: its latest version), see
    :mod:`omcrl.scenes`; ``image_size``/``frame_stack`` and other keywords are ``EnvConfig`` fields that
    override ``config`` (default 64 px, L = 3). ``scene=None`` takes the scene from ``config``.
    """
    if scene is None and config is not None:
        scene = config.scene
    try:
        scene = scene_id(scene)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    return NavEnv(
        scene=scene,
        seed=seed,
        image_size=image_size,
        frame_stack=frame_stack,
        disturbance=disturbance,
        layout=layout,
        config=config,
        **overrides,
    )
