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
        self.flying = False
        self.crashed = False
        self.motors_cut = False
        self.landed_at: float | None = None
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
            self._pose = (np.array([x, y, self.cfg.altitude, roll, pitch, yaw]), now)

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
                with self._lock:  # on the ground or landed: same picture and pose, fresh timestamps
                    self._frame = (self._frame[0], now)
                    self._pose = (self._pose[0], now)
            nxt += self.dt / self.speed
            time.sleep(max(0.0, nxt - time.monotonic()))

    # ---------------------------------------------------------------- the Drone interface
    def takeoff(self) -> None:
        self.flying = True

    def send_velocity(self, vx: float, vy: float, wz: float) -> None:
        """Body-frame command: m/s forward, m/s left, rad/s counter-clockwise."""
        if not all(math.isfinite(v) for v in (vx, vy, wz)):
            raise ValueError(f"non-finite velocity command {(vx, vy, wz)}")
        with self._lock:
            self._cmd[:] = (vx, vy, wz)

    def emergency(self) -> None:
        """Motors cut (the Tello's ``emergency``): the drone stops where it is and drops; recorded as such."""
        self.motors_cut = True
        self.land()

    def land(self) -> None:
        self.flying = False
        if self.landed_at is None:
            self.landed_at = time.monotonic()

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
