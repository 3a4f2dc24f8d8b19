"""A simulated drone, camera and motion-capture system behind the control loop's interfaces.

:class:`SimulatedDrone` runs the kit's PyBullet :class:`~omcrl.envs.NavEnv` in real time in a background thread:
each ``1 / control_hz`` s it applies the last velocity command, renders the camera and updates the pose. Its
:meth:`~SimulatedDrone.camera` and :meth:`~SimulatedDrone.mocap` give the video and pose sources (they can be
cut, to test the loop's loss-of-signal landing). Env disturbances (colours, lighting switches, brightness, hue)
pass through, so the whole loop can fly in the visual conditions of the disturbance tests.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from typing import Any

import numpy as np

from omcrl.config import EnvConfig
from omcrl.deploy.timing import LAND_S, TAKEOFF_S
from omcrl.envs import make_env


class SimulatedDrone:
    """A NavEnv flown by velocity commands in real time.

    Parameters
    ----------
    env_config : the env (image size, limits, control rate); ``max_steps`` is raised so the env never truncates.
    scene, seed : the layout; ``layout`` / ``disturbance`` as for :func:`omcrl.envs.make_env`.
    start : (x, y, yaw) m, rad; goal : (x, y) m (the env needs one; the loop has its own).
    speed : real-time factor (2.0 runs the physics twice as fast as the wall clock).
    camera : a :class:`~omcrl.deploy.camera.CameraIntrinsics` to render frames through (e.g. the Tello's at a
        reduced resolution, for the fake Tello's stream); None: the simulator's own square camera.
    takeoff_s, land_s : how long :meth:`takeoff` and :meth:`land` take (s; they block that long, as djitellopy's
        calls do, while the height rises to or falls from the flight altitude); defaults a Tello's
        (:mod:`omcrl.deploy.timing`); 0: instant, for tests that do not test timing.

    Attributes
    ----------
    flying : the drone moves horizontally (between the end of a takeoff and the start of a landing).
    height : m above the floor now (0 on the ground, ``env.altitude`` in flight; the pose's z).
    landed_at : when the landing began (``land()`` or ``emergency()`` was received), ``time.monotonic()``.
    touchdown_at : when the height reached 0.
    motors_cut : ``emergency()`` was received (the drone dropped).
    """

    def __init__(
        self,
        env_config: EnvConfig,
        scene: str = "box",
        seed: int = 0,
        start: tuple[float, float, float] = (0.0, 0.0, 0.0),
        goal: tuple[float, float] = (5.0, 0.0),
        layout: list | None = None,
        disturbance: Any = None,
        speed: float = 1.0,
        camera: Any = None,
        takeoff_s: float = TAKEOFF_S,
        land_s: float = LAND_S,
    ) -> None:

        cfg = dataclasses.replace(env_config, max_steps=10**6)
        self.cfg = cfg
        self.env = make_env(scene, seed=seed, config=cfg, layout=layout, disturbance=disturbance)
        obs, info = self.env.reset(seed=seed, options={"start": start, "goal": goal})
        self.dt = 1.0 / cfg.control_hz
        self.speed = float(speed)
        self.camera_intrinsics = camera  # None: the simulator's own square camera
        self._lock = threading.Lock()
        self._cmd = np.zeros(3)
        self.takeoff_s, self.land_s = float(takeoff_s), float(land_s)
        self.flying = False
        self.crashed = False
        self.motors_cut = False
        self.height = 0.0
        self.landed_at: float | None = None
        self.touchdown_at: float | None = None
        self._landing = threading.Event()  # set once a landing (or the motor cut) began: a takeoff stops climbing
        self._cut = threading.Event()  # set by the motor cut: a descent stops where it is, the drone drops
        self._set(obs, info)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _set(self, obs: dict, info: dict) -> None:
        now = time.monotonic()
        x, y, yaw = (float(v) for v in info["pose"])
        roll, pitch = float(obs["state"][6]), float(obs["state"][7])
        with self._lock:
            self._frame = (self._render(), now)
            self._pose = (np.array([x, y, self.height, roll, pitch, yaw]), now)

    def _render(self) -> np.ndarray:
        k = self.camera_intrinsics
        if k is None:
            return self.env.render()
        return self.env.render_camera(k.width, k.height, k.fov_deg()[1])

    def _run(self) -> None:
        """Sensors stream all the time (like a camera and a mocap system); the drone moves only while flying."""
        nxt = time.monotonic()
        scale = np.array([self.cfg.max_speed, self.cfg.max_speed, self.cfg.max_yaw_rate])
        while not self._stop.is_set():
            if self.flying:
                with self._lock:
                    action = np.clip(self._cmd / scale, -1.0, 1.0)
                obs, _, term, _, info = self.env.step(action)
                self._set(obs, info)
                m = info.get("metrics", {})
                if term and (m.get("collision") or m.get("out_of_arena")):
                    self.crashed, self.flying = True, False
            else:
                now = time.monotonic()
                with self._lock:  # on the ground, climbing or descending: same picture, fresh timestamps
                    self._frame = (self._frame[0], now)
                    pose = self._pose[0].copy()
                    pose[2] = self.height
                    self._pose = (pose, now)
            nxt += self.dt / self.speed
            time.sleep(max(0.0, nxt - time.monotonic()))

    # ---------------------------------------------------------------- the Drone interface
    def _ramp(self, target: float, duration: float, stop: threading.Event | None = None) -> bool:
        """Move the height to ``target`` m linearly over ``duration`` s (scaled by the share of the full climb
        left), returning False when ``stop`` was set on the way."""
        start, h0 = time.monotonic(), self.height
        span = duration * abs(target - h0) / max(self.cfg.altitude, 1e-9)
        while True:
            if stop is not None and stop.is_set():
                return False
            f = 1.0 if span <= 0 else min(1.0, (time.monotonic() - start) / span)
            self.height = h0 + (target - h0) * f
            if f >= 1.0:
                return True
            time.sleep(min(0.02, span / 10))

    def takeoff(self) -> None:
        """Climb to the flight altitude over ``takeoff_s`` (blocking, as a Tello acknowledges ``takeoff`` when it is
        up); a landing or motor cut received meanwhile ends the climb. A new takeoff starts a new flight
        (``landed_at`` and ``touchdown_at`` cleared; ``motors_cut`` stays as the record of an emergency)."""
        self._landing.clear()
        self._cut.clear()
        self.landed_at = self.touchdown_at = None
        if self._ramp(self.cfg.altitude, self.takeoff_s, self._landing) and not self._landing.is_set():
            self.flying = True

    def send_velocity(self, vx: float, vy: float, wz: float) -> None:
        """Body-frame command: m/s forward, m/s left, rad/s counter-clockwise."""
        if not all(math.isfinite(v) for v in (vx, vy, wz)):
            raise ValueError(f"non-finite velocity command {(vx, vy, wz)}")
        with self._lock:
            self._cmd[:] = (vx, vy, wz)

    def emergency(self) -> None:
        """Motors cut (the Tello's ``emergency``): the drone stops where it is and drops at once; recorded as such."""
        self.motors_cut = True
        self._cut.set()
        self._begin_landing()
        self.height = 0.0
        self.touchdown_at = self.touchdown_at or time.monotonic()

    def _begin_landing(self) -> None:
        self.flying = False
        if self.landed_at is None:
            self.landed_at = time.monotonic()
        self._landing.set()

    def land(self) -> None:
        """Stop moving and descend to the floor over ``land_s`` (blocking, as a Tello acknowledges ``land`` when it
        is down)."""
        self._begin_landing()
        self._ramp(0.0, self.land_s, self._cut)
        self.height = 0.0
        self.touchdown_at = self.touchdown_at or time.monotonic()

    @property
    def pose(self) -> np.ndarray:
        """(x, y, z, roll, pitch, yaw) now."""
        with self._lock:
            return self._pose[0].copy()

    def latest_frame(self) -> tuple[np.ndarray, float]:
        with self._lock:
            return self._frame

    def camera(self) -> SimulatedCamera:
        return SimulatedCamera(self)

    def mocap(self) -> SimulatedMocap:
        return SimulatedMocap(self)

    def close(self) -> None:
        self.land_s = 0.0  # whatever was in the air is put down at once: the simulation ends
        self.land()
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.env.close()


class _Cuttable:
    """A source that can be cut at a wall-clock time: from then on it repeats its last reading (so its age grows)."""

    def __init__(self) -> None:
        self.cut_at: float | None = None
        self._last: Any = None

    def cut(self, at: float | None = None) -> None:
        self.cut_at = time.monotonic() if at is None else at

    def _gate(self, value: Any) -> Any:
        if self.cut_at is not None and time.monotonic() >= self.cut_at:
            return self._last
        self._last = value
        return value


class SimulatedCamera(_Cuttable):
    """Video source: the drone's newest rendered frame (H, W, 3) uint8 RGB and when it was rendered."""

    def __init__(self, drone: SimulatedDrone) -> None:
        super().__init__()
        self.drone = drone

    def read(self) -> tuple[np.ndarray, float] | None:
        return self._gate(self.drone.latest_frame())


class SimulatedMocap(_Cuttable):
    """Pose source standing in for the motion-capture system: the simulated drone's pose, timestamped."""

    def __init__(self, drone: SimulatedDrone) -> None:
        super().__init__()
        self.drone = drone

    def read(self) -> tuple[np.ndarray, float] | None:
        with self.drone._lock:
            pose = self.drone._pose
        return self._gate((pose[0].copy(), pose[1]))
