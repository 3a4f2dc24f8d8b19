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

Structure: :class:`NavEnv` is the Gymnasium API over three parts, each in its own module — episode planning
(:mod:`omcrl.envs.episodes`: layout, maps, start/goal; an :class:`~omcrl.envs.episodes.EpisodePlanner` the env
holds as ``env.episodes``, whose current plan is the layout the env has built), the scene's bodies and looks
(:mod:`omcrl.envs.appearance`, with :class:`Disturbance`) and the flight dynamics (:mod:`omcrl.envs.dynamics`: the
drone's state is one record, ``env.drone``, a :class:`~omcrl.envs.dynamics.DroneState`, and a control step the pure
function :func:`~omcrl.envs.dynamics.fly` of it under ``env.flight``, the :class:`~omcrl.envs.dynamics.FlightModel`).
The task is in four methods a subclass may override, as gym-pybullet-drones' envs do: ``_reward``, ``_terminated``,
``_truncated``, ``_metrics``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, fields
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from omcrl.config import ConfigError, EnvConfig, _check_value, validate_env
from omcrl.envs.appearance import (
    APPEARANCE_PARTS,
    GENERIC_TEXTURES,
    POOL_SLACK,
    CullSet,
    Disturbance,
    SceneLook,
    _adjust,
    appearance_materials,
)
from omcrl.envs.dynamics import GRAVITY, DroneState, FlightModel, fly
from omcrl.envs.episodes import EpisodePlanner
from omcrl.envs.grid import OccupancyGrid
from omcrl.envs.observation import PRIVILEGED_DIM, STATE_DIM, pack_privileged, pack_state
from omcrl.envs.render import load_egl, pybullet_renderer, resolve_renderer
from omcrl.scenes import layout_to_primitives, scene_id
from omcrl.scenes.geometry import Geometry, Primitive
from omcrl.utils.quiet import import_quietly

pb = import_quietly("pybullet")  # without the build-time line PyBullet prints on stderr

_NO_GEOMETRY = Geometry()  # before the first reset: no obstacles
# Where the camera renders from, in order, m along the optical axis. TinyRenderer divides by a vertex's depth along
# that axis and does not clip what lies in the camera's plane (depth 0):
# - one box corner there (the drone started right above a floor-tile corner: (-6, -6) at yaw 2.4212, in any layout)
#   gives NaN depth and black pixels over that tile in ~15 % of yaws, and a policy given that depth a NaN action
#   (seed 2's oracle died of it at 364,544 steps). The frame is rendered again with the eye a millimetre forward,
#   which takes the corner out of the plane; a frame without the fault stays the one render from the pose.
# - the plane along a row of corners (a tile edge: the eye on the line x = 6 m looking along it, yaw 0 or pi, the
#   kind of pose a user types) makes it NaN or never return: of 120 such poses within 1e-7 m of the line, 29 hung
#   and 24 gave NaN; none at 1e-6 m. No second try helps a render that never ends, so such a pose is not rendered
#   from itself at all (RENDER_PLANE_CLEARANCE_M). In flight that needs the yaw within ~2e-6 rad of the edge's
#   direction and the eye within 1e-5 m of its line at once (roughly 1e-10 a frame, an estimate).
RENDER_NUDGES_M = (0.0, 1e-3, -1e-3)
# A camera plane within this of two or more vertical box edges (m) is not rendered from (see above): 100x the
# largest offset from a tile edge measured to hang (1e-7 m), 10x the smallest measured clean (1e-6 m).
RENDER_PLANE_CLEARANCE_M = 1e-5

# Re-exported: the env's public names live here as before the split into appearance, episodes and dynamics.
__all__ = [
    "APPEARANCE_PARTS",
    "GENERIC_TEXTURES",
    "GRAVITY",
    "POOL_SLACK",
    "Disturbance",
    "NavEnv",
    "appearance_materials",
    "make_env",
]


class NavEnv(SceneLook, gym.Env):
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
        camera: bool = True,
        cull: bool = True,
        **overrides: Any,
    ) -> None:
        """``camera=False``: no frame is rendered on reset or step, and ``rgb`` and ``depth`` stay zero (as does
        :meth:`render`), for a pilot that does not look (:class:`omcrl.planners.HybridAPF`, the blind pilot):
        its episodes are the same, in a fifth to a third of the time. ``cull=False``: TinyRenderer draws every
        body of the layout for every frame, as before culling (:class:`~omcrl.envs.appearance.CullSet`; the
        frames are bit-identical either way, so benchmarks compare the two). Neither is a config field: they
        change no episode, so no run identity. The other keywords are described in :func:`make_env`."""
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
        self.camera = bool(camera)
        L, S = cfg.frame_stack, cfg.image_size
        self.dt = 1.0 / cfg.control_hz
        self.h_max = cfg.step_penalty_horizon or cfg.max_steps
        self.observation_space = spaces.Dict(
            {
                "rgb": spaces.Box(0, 255, (L, 3, S, S), np.uint8),
                "depth": spaces.Box(0.0, cfg.far, (L, S, S), np.float32),
                # Finite bounds that no reachable value exceeds (arena and far plane are tens of metres).
                "state": spaces.Box(-1e3, 1e3, (STATE_DIM,), np.float32),
                "privileged": spaces.Box(-1e3, 1e3, (PRIVILEGED_DIM,), np.float32),
            }
        )
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self._scale = np.array([cfg.max_speed, cfg.max_speed, cfg.max_yaw_rate])
        self.flight = FlightModel.from_config(cfg)
        self.drone = DroneState(np.array([0.0, 0.0, cfg.altitude]), 0.0)
        self._client = pb.connect(pb.DIRECT)
        self.renderer = resolve_renderer(cfg.renderer)  # "tiny" or "egl"
        if self.renderer == "egl":
            load_egl(self._client)
        self._pb_renderer = pybullet_renderer(self.renderer)
        # EGL clips on the GPU and would blend an alpha-0 body: culling is TinyRenderer's alone.
        self.cull = bool(cull) and self.renderer == "tiny"
        self._cull_set: CullSet | None = None
        self._paint: dict[int, tuple] = {}  # body -> its rgba as painted (alpha included)
        self._hidden: set[int] = set()  # bodies drawn with alpha 0 now (culled or parked)
        self._proj = pb.computeProjectionMatrixFOV(cfg.fov_deg, 1.0, cfg.near, cfg.far)
        # What each reset decides before touching PyBullet (layout, maps, start/goal): an object the env holds.
        self.episodes = EpisodePlanner(cfg, self.scene, self.layout)
        self._decor_built = False
        self._box_edges_xy = np.zeros((0, 2))  # where the boxes' vertical edges stand, m (set per layout)
        self._tex_ids: dict[str, int] = {}
        self._pool: dict[tuple, list[int]] = {}
        self.light_switch_step: int | None = None
        self._rgb = np.zeros((L, 3, S, S), np.uint8)
        self._depth = np.zeros((L, S, S), np.float32)
        self._episode_seed = -1

    # ------------------------------------------------------------------ world

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if self._client < 0:
            raise RuntimeError("NavEnv.reset called on a closed env")
        if seed is None and self.episodes.current is None and self._init_seed is not None:
            seed = self._init_seed
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"start", "goal"}
        if unknown:
            raise ValueError(f"reset options: unknown keys {sorted(unknown)}; expected 'start' and/or 'goal'")
        plan, new_layout = self.episodes.begin(self.np_random, reseed=seed is not None, options=options)
        if new_layout:
            self._build_bodies(plan.prims)
        layout_seed = plan.layout_seed
        c = self.cfg
        start, goal, _, _ = plan.placed
        self._episode_seed = layout_seed if self.layout is None else -1
        self.drone = DroneState(np.array([start[0], start[1], c.altitude]), float(start[2]))
        self._goal = np.array([goal[0], goal[1], c.altitude])
        self._steps = 0
        self.light_switch_step = self._draw_switch(layout_seed)
        self._d_init = self._d_prev = float(np.linalg.norm(self._goal[:2] - self.drone.pos[:2]))
        self._min_d = self._d_init
        if self.camera:
            frame_rgb, frame_depth = self._render_frame()
            self._rgb[:] = frame_rgb
            self._depth[:] = frame_depth
        obs = self._obs(plan.geometry.nearest(self.drone.pos)[0])
        # The path is a list, not an array: its length varies, and vector envs can only stack fixed shapes.
        info = {
            "pose": self.pose,
            "goal": self._goal[:2].copy(),
            "path": plan.placed[2].tolist(),
            "optimal_path_length": plan.placed[3],
            "layout_seed": self._episode_seed,
        }
        return obs, info

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        if self._client < 0:
            raise RuntimeError("NavEnv.step called on a closed env")
        plan = self.episodes.current
        if plan is None:
            raise RuntimeError("NavEnv.step called before reset()")
        if np.shape(action) != (3,):  # (1, 3) or (3, 1) would hide a batching mistake
            raise ValueError(f"action: expected shape (3,), got {np.shape(action)}")
        if np.iscomplexobj(action):  # float64 conversion would drop the imaginary part with only a warning
            raise ValueError(f"action: expected real numbers, got complex values {np.asarray(action).tolist()}")
        a = np.asarray(action, dtype=np.float64)
        ax, ay, az = a.tolist()
        if not (math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az)):
            raise ValueError(f"action contains NaN or inf: {[ax, ay, az]}")
        self.drone, closest, collided, out = fly(self.drone, (ax, ay, az), self.flight, plan.geometry)
        self._steps += 1
        pos = self.drone.pos
        d = math.hypot(self._goal[0] - pos[0], self._goal[1] - pos[1])
        self._min_d = min(self._min_d, d)
        success = not (collided or out) and d <= self.cfg.goal_radius
        reward = self._reward(d, success, collided or out)
        self._d_prev = d
        terminated = self._terminated(success, collided, out)
        truncated = self._truncated(terminated)
        if self.camera:
            rgb, depth = self._render_frame()
            self._rgb[:-1] = self._rgb[1:]
            self._rgb[-1] = rgb
            self._depth[:-1] = self._depth[1:]
            self._depth[-1] = depth
        obs = self._obs(closest)
        info: dict[str, Any] = {"pose": self.pose, "goal": self._goal[:2].copy()}
        if terminated or truncated:
            info["metrics"] = self._metrics(d, success, collided, out)
        return obs, float(reward), terminated, truncated, info

    # ------------------------------------------------------------------ task: override these for another task
    def _reward(self, d: float, success: bool, crashed: bool) -> float:
        """The step's reward: ``-1/H_max``, the progress term toward the goal (``d`` m, after the move; the
        previous distance is ``self._d_prev``), and ``goal_reward`` on success or ``collision_penalty`` on a crash
        (a collision or leaving the arena)."""
        c = self.cfg
        if c.progress == "difference":
            progress = c.progress_scale * (self._d_prev - d)
        else:
            progress = c.progress_scale * (self._d_init - d)
        reward = -1.0 / self.h_max + progress
        if success:
            reward += c.goal_reward
        elif crashed:
            reward += c.collision_penalty
        return reward

    def _terminated(self, success: bool, collided: bool, out: bool) -> bool:
        """Whether the episode ends here: the goal reached, a collision, or leaving the arena."""
        return bool(success or collided or out)

    def _truncated(self, terminated: bool) -> bool:
        """Whether the episode is cut at the step limit ``max_steps``."""
        return bool(not terminated and self._steps >= self.cfg.max_steps)

    def _metrics(self, d: float, success: bool, collided: bool, out: bool) -> dict[str, Any]:
        """``info["metrics"]`` of the episode's last step (distances m, lengths m, steps)."""
        return {
            "final_distance": d,
            "min_distance": self._min_d,
            "success": bool(success),
            "collision": bool(collided),
            "out_of_arena": bool(out),
            "path_length": self.drone.path_len,
            "optimal_path_length": self.episodes.current.placed[3],
            "steps": self._steps,
            "scene": self.scene,
            "seed": self._episode_seed,
        }

    # ------------------------------------------------------------------ sensors
    @property
    def pose(self) -> np.ndarray:
        """(x, y, yaw) in the world frame, m and rad."""
        return np.array([self.drone.pos[0], self.drone.pos[1], self.drone.yaw])

    def _obs(self, closest: np.ndarray) -> dict:
        drone = self.drone
        c, s = math.cos(drone.yaw), math.sin(drone.yaw)
        gx, gy = self._goal[0] - drone.pos[0], self._goal[1] - drone.pos[1]
        goal_b = (c * gx + s * gy, -s * gx + c * gy, 0.0)  # goal and drone share the flight altitude
        if self.geometry.n:
            ox, oy, oz = (closest - drone.pos).tolist()
            obst_b = (c * ox + s * oy, -s * ox + c * oy, oz)
        else:  # nothing in range: report an obstacle at the far plane straight ahead
            obst_b = (self.cfg.far, 0.0, 0.0)
        pitch = math.atan2(drone.acc[0], GRAVITY)
        roll = -math.atan2(drone.acc[1], GRAVITY)
        vx, vy = drone.vel
        state = pack_state((vx, vy, 0.0), (0.0, 0.0, drone.wz), (roll, pitch, drone.yaw), goal_b)
        priv = pack_privileged(obst_b, goal_b)
        return {"rgb": self._rgb.copy(), "depth": self._depth.copy(), "state": state, "privileged": priv}

    def obstacle_mask(self) -> np.ndarray:
        """(H, W) bool: pixels of the current camera view that show an obstacle (not floor, walls or sky).

        Renders the view once more with PyBullet's segmentation buffer (the observation renders skip it); for
        analysis such as the Grad-CAM mass on obstacles, not for training.
        """
        S = self.cfg.image_size
        _, _, seg = self._camera_image(S, S, self._proj, segmentation=True)
        bodies = [b for v in self._pool.values() for b in v]
        return np.isin(seg, bodies)

    def view_matrix(self, forward: float = 0.0) -> list[float]:
        """PyBullet view matrix (16 floats) of the forward camera at the current pose (what renders use), its eye
        moved ``forward`` m along the optical axis."""
        eye, yaw = self.drone.pos, self.drone.yaw
        cy, sy = math.cos(yaw), math.sin(yaw)
        eye = [eye[0] + forward * cy, eye[1] + forward * sy, eye[2]]
        return pb.computeViewMatrix(eye, [eye[0] + cy, eye[1] + sy, eye[2]], [0.0, 0.0, 1.0])

    def _camera_image(
        self, width: int, height: int, proj: list[float], segmentation: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """One PyBullet render from the camera pose through ``proj``: RGBA (height, width, 4) uint8, the OpenGL
        z-buffer (height, width) float32 and, with ``segmentation``, body ids (height, width) int64 (else None).
        Every render of the env goes through here, so a pose TinyRenderer cannot draw is re-rendered
        (:data:`RENDER_NUDGES_M`) for all of them."""
        flags = 0 if segmentation else pb.ER_NO_SEGMENTATION_MASK
        for forward in RENDER_NUDGES_M:
            if not self._plane_is_clear(forward):
                continue
            if self.cull:
                yaw = self.drone.yaw
                eye = self.drone.pos + forward * np.array([math.cos(yaw), math.sin(yaw), 0.0])
                # A pinhole projection's first and sixth entries are 1/tan of the half-angles (x, y).
                self._cull_to(eye, yaw, 1.0 / proj[0], 1.0 / proj[5], width, height)
            _, _, rgba, zbuf, seg = pb.getCameraImage(
                width,
                height,
                self.view_matrix(forward),
                proj,
                renderer=self._pb_renderer,
                shadow=0,
                flags=flags,
                physicsClientId=self._client,
                **self._light(),
            )
            zbuf = np.asarray(zbuf, np.float32).reshape(height, width)
            if np.isfinite(zbuf).all():
                break
        else:
            raise RuntimeError(
                f"{self.scene}: the camera at pose {self.pose.round(4).tolist()} (x m, y m, yaw rad) renders a "
                f"non-finite depth buffer (or its camera plane lies on box edges), also with its eye moved "
                f"{list(RENDER_NUDGES_M[1:])} m forward"
            )
        rgba = np.asarray(rgba, np.uint8).reshape(height, width, 4)
        return rgba, zbuf, np.asarray(seg, np.int64).reshape(height, width) if segmentation else None

    def _plane_is_clear(self, forward: float) -> bool:
        """False when the camera's plane, its eye moved ``forward`` m along the optical axis, passes within
        :data:`RENDER_PLANE_CLEARANCE_M` of two or more vertical box edges (a pose TinyRenderer may never finish)."""
        edges = self._box_edges_xy
        if len(edges) < 2:
            return True
        axis = np.array([math.cos(self.drone.yaw), math.sin(self.drone.yaw)])
        depth = (edges - (self.drone.pos[:2] + forward * axis)) @ axis
        return int(np.count_nonzero(np.abs(depth) < RENDER_PLANE_CLEARANCE_M)) < 2

    def _render_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """One camera render (``self.renderer``): RGB (3, H, W) uint8 and linear depth (H, W) float32 in metres."""
        c = self.cfg
        S = c.image_size
        rgba, zbuf, _ = self._camera_image(S, S, self._proj)
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
        rgba, _, _ = self._camera_image(int(width), int(height), proj)
        return rgba[..., :3].copy()

    def render(self) -> np.ndarray | None:
        """The newest camera frame as (H, W, 3) uint8 with ``render_mode="rgb_array"``; None (and gymnasium's
        warning) without a render mode."""
        if self.render_mode is None:
            gym.logger.warn("NavEnv.render() called without a render_mode; make the env with render_mode='rgb_array'")
            return None
        return self._rgb[-1].transpose(1, 2, 0).copy()

    # The current layout, as the episode planner decided it (empty before the first reset).
    @property
    def primitives(self) -> list[Primitive]:
        """Obstacles of the current layout (collision geometry), for maps and plots."""
        plan = self.episodes.current
        return [] if plan is None else list(plan.prims)

    @property
    def geometry(self) -> Geometry:
        """Collision geometry of the current layout (collisions and the nearest obstacle come from it)."""
        plan = self.episodes.current
        return _NO_GEOMETRY if plan is None else plan.geometry

    @property
    def grid(self) -> OccupancyGrid | None:
        """Occupancy grid of the current layout at flight altitude; None before the first reset."""
        plan = self.episodes.current
        return None if plan is None else plan.grid

    @property
    def path(self) -> np.ndarray:
        """(K, 2) m: the any-angle shortest path from this episode's start to its goal (for SPL)."""
        plan = self.episodes.current
        return np.zeros((0, 2)) if plan is None else plan.placed[2]

    def prefetch(self) -> bool:
        """Plan the next automatic reset now, while there is time (:meth:`EpisodePlanner.prefetch`). The vector env
        calls this while a process waits for another env's reset, which hides the planning (~70% of a box-scene
        reset) behind that wait; results are unchanged. True when a plan was made."""
        return self.episodes.prefetch(self.np_random)

    @property
    def prefetched(self) -> bool:
        """True when the next automatic reset has been planned ahead (:meth:`prefetch`)."""
        return self.episodes.prefetched

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
