"""The drone control loop (paper VI-B): camera frames + motion-capture pose → ONNX policy → velocity commands.

One loop, three interfaces (any object with these methods works):

* a **drone**: ``takeoff()``, ``send_velocity(vx, vy, wz)`` (body frame: m/s forward, m/s left, rad/s
  counter-clockwise), ``land()``;
* a **video source**: ``read() -> (frame (H, W, 3) uint8 RGB, t)`` or None before the first frame, ``t`` the
  ``time.monotonic()`` at which the frame arrived;
* a **pose source**: ``read() -> (pose (6,) = x, y, z m, roll, pitch, yaw rad in the world frame, t)`` or None.

Each tick (at the model's ``control_hz``) the loop checks its safety rules, builds the observation exactly as
the simulator does (frames resized to the model's image size and stacked, state v, ω, θ, Δp_goal in the body
frame), runs the policy, scales, clamps and rate-limits the command and sends it. It lands, and says why, on:
arrival within ``goal_radius`` (the paper's real-world success rule, 0.5 m), video or pose older than
``stale_s`` (0.4 s, checked every 20 ms between ticks too), leaving the geofence, the time limit, a low battery,
any exception, and the signals in ``STOP_SIGNALS`` (Ctrl-C, SIGTERM, SIGHUP). Nothing non-finite reaches the
motors: a pose, frame, state, policy output or command that is not finite (or not of its shape) stops the flight
with reason ``bad_pose`` / ``bad_frame`` / ``bad_state`` / ``bad_action`` / ``bad_command`` before it is used:
the drone hovers (a zero command) and lands. Before take-off a preflight check refuses to fly without a fresh,
finite pose and frame; in flight a watchdog process (:mod:`omcrl.deploy.watchdog`) lands a drone whose loop
stops beating, in every phase (the loop beats from a thread while it waits seconds on a Tello's ``takeoff`` and
``land``), and the loop lands when its watchdog dies (``watchdog_lost``). A policy output beyond ``ACTION_FAULT``
is a fault (``bad_action``); within it the command is clamped. An unacknowledged ``land`` is given
:data:`omcrl.deploy.timing.LAND_FALLBACK_S` before ``emergency``, by the loop and the watchdog alike. Every tick
is appended to a CSV flight log and flushed, so a crash loses nothing.
"""

from __future__ import annotations

import csv
import math
import signal
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from omcrl.deploy.camera import CameraView
from omcrl.deploy.timing import LAND_FALLBACK_S
from omcrl.envs.observation import pack_state


class Drone(Protocol):
    def takeoff(self) -> None: ...
    def send_velocity(self, vx: float, vy: float, wz: float) -> None: ...
    def land(self) -> None: ...


class VideoSource(Protocol):
    def read(self) -> tuple[np.ndarray, float] | None: ...


class PoseSource(Protocol):
    def read(self) -> tuple[np.ndarray, float] | None: ...


@dataclass
class Safety:
    """Safety settings of a flight. Units: m, m/s, rad/s, s, %.

    The defaults are a conservative first-flight profile (0.5 m/s, a 6 m × 6 m fence, 2 m ceiling); raise them
    once a policy has flown well (``Safety(max_speed=None, ...)`` gives the model's own action scale).

    Attributes
    ----------
    max_speed, max_yaw_rate : command clamps (None: the model's action scale; never above it).
    max_accel : rate limit on |Δv| per second (m/s²); max_yaw_accel likewise (rad/s²).
    geofence : (x_min, x_max, y_min, y_max) the drone must stay in, world frame; start and goal must lie in it.
    max_altitude : the fence's ceiling (m above the mocap origin).
    stale_s : land when the newest video frame or pose is older than this (checked every 20 ms, between ticks
        too; with the frame's arrival time, the drone gets ``land`` within ``stale_s`` + 20 ms of the last frame).
    goal_radius : arrival distance that ends the flight as a success.
    max_time_s : land after this long in the air.
    min_battery : no takeoff below this charge, and land when the drone reports less in flight (%), for drones
        that report it (``drone.battery()``).
    """

    max_speed: float | None = 0.5
    max_yaw_rate: float | None = 0.8
    max_accel: float = 3.0
    max_yaw_accel: float = 6.0
    geofence: tuple[float, float, float, float] = (-3.0, 3.0, -3.0, 3.0)
    max_altitude: float = 2.0
    stale_s: float = 0.4
    goal_radius: float = 0.5
    max_time_s: float = 120.0
    min_battery: float = 20.0


@dataclass
class FlightResult:
    """How a flight ended: ``reason`` is arrived | video_lost | pose_lost | geofence | timeout | error |
    interrupted | bad_frame | bad_pose | bad_state | bad_action | bad_command | battery_low | watchdog_lost |
    preflight (nothing was
    sent; ``error`` says why); ``final_distance`` (m) from the last valid pose to the goal; ``poses`` the
    (x, y, z) of every tick."""

    reason: str
    success: bool
    ticks: int
    duration_s: float
    log_path: Path | None
    final_distance: float
    error: str = ""
    poses: list = field(default_factory=list)


def _resize(frame: np.ndarray, size: int) -> np.ndarray:
    """(H, W, 3) uint8 → (3, size, size) uint8, bilinear (what a camera driver's resize does)."""
    from PIL import Image

    if frame.shape[0] == size and frame.shape[1] == size:
        return np.ascontiguousarray(frame.transpose(2, 0, 1))
    img = Image.fromarray(np.ascontiguousarray(frame)).resize((size, size), Image.BILINEAR)
    return np.asarray(img, np.uint8).transpose(2, 0, 1)


# How often the streams' freshness (and the geofence) is checked between control ticks (s).
WATCH_S = 0.02
# The watchdog lands the drone when no heartbeat came for this long (s). The loop beats every tick and every WATCH_S
# between ticks, and from a thread while it waits on takeoff or land, so a live loop beats every ~20 ms; a dead or
# frozen one gets `land` within this plus the watchdog's 20 ms poll, under half a second.
WATCHDOG_TIMEOUT_S = 0.3
# A policy output beyond this (the action range is [-1, 1]) is a fault, not an action to clamp: the flight stops
# with bad_action. Within it the command is clamped, as the simulator clips an action (PPO's Gaussian means can
# leave [-1, 1] a little).
ACTION_FAULT = 10.0

# Signals that end a flight (the drone hovers and lands): Ctrl-C, a kill (SIGTERM) and a closed terminal (SIGHUP).
STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


def _finite(values: Any, size: int) -> bool:
    """``values`` holds exactly ``size`` finite numbers."""
    try:
        a = np.asarray(values, np.float64).reshape(-1)
    except (TypeError, ValueError):
        return False
    return a.shape == (size,) and bool(np.isfinite(a).all())


def _beat(dog: Any, what: bytes) -> None:
    if dog is None:
        return
    try:
        dog.stdin.write(what)
        dog.stdin.flush()
    except (OSError, ValueError):  # the watchdog already acted (or was stopped): nothing to tell it
        pass


class _Beating:
    """Heartbeats to the watchdog (``phase`` bytes every WATCH_S) from a thread, while the loop waits on a
    blocking drone call (``takeoff``, ``land``: a Tello answers them when the manoeuvre is done, seconds later).
    The thread lives in the loop's process, so it dies and freezes with it: the watchdog still notices."""

    def __init__(self, dog: Any, phase: bytes) -> None:
        self.dog, self.phase = dog, phase
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            _beat(self.dog, self.phase)
            self._stop.wait(WATCH_S)

    def __enter__(self) -> _Beating:
        if self.dog is not None:
            self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(1.0)


def _reading(drone: Any, name: str) -> float | None:
    """``drone.<name>()`` (battery %, temperature °C) where the drone reports it, else None."""
    fn = getattr(drone, name, None)
    if fn is None:
        return None
    try:
        v = float(fn())
    except Exception:
        return None
    return v if math.isfinite(v) else None


class StateEstimator:
    """Body-frame state vector (12,) from successive poses: v from position differences (low-passed), ω_z from
    yaw differences, θ from the pose, Δp_goal rotated into the body frame (paper IV-C, the env's layout)."""

    def __init__(self, goal: tuple[float, float], altitude: float, smoothing: float = 0.5) -> None:
        self.goal = np.asarray(goal, np.float64)
        self.altitude, self.a = float(altitude), float(smoothing)
        self.prev: tuple[np.ndarray, float] | None = None
        self.v = np.zeros(2)
        self.wz = 0.0

    def update(self, pose: np.ndarray, t: float) -> np.ndarray:
        x, y, _, roll, pitch, yaw = (float(v) for v in pose)
        if self.prev is not None and t > self.prev[1]:
            p0, t0 = self.prev
            dt = t - t0
            c, s = math.cos(yaw), math.sin(yaw)
            dx, dy = (x - p0[0]) / dt, (y - p0[1]) / dt
            v_body = np.array([c * dx + s * dy, -s * dx + c * dy])
            self.v = self.a * self.v + (1 - self.a) * v_body
            dyaw = (yaw - p0[5] + math.pi) % (2 * math.pi) - math.pi
            self.wz = self.a * self.wz + (1 - self.a) * dyaw / dt
        self.prev = (np.asarray(pose, np.float64), t)
        c, s = math.cos(yaw), math.sin(yaw)
        gx, gy = self.goal[0] - x, self.goal[1] - y
        return pack_state((self.v[0], self.v[1], 0.0), (0.0, 0.0, self.wz), (roll, pitch, yaw),
                          (c * gx + s * gy, -s * gx + c * gy, 0.0))  # fmt: skip


class ControlLoop:
    """Fly ``policy`` (an :class:`omcrl.deploy.OnnxPolicy`) to ``goal`` with a drone, a camera and a pose source.

    Parameters
    ----------
    policy : has ``run(rgb (1, 3L, H, W) uint8, state (1, 12)) -> (1, 3)`` and ``spec`` (image_size,
        frame_stack, action_scale, control_hz).
    drone, video, pose : the interfaces above.
    goal : (x, y) world frame, m.
    safety : :class:`Safety`; clamps default to the model's action scale.
    log_path : CSV flight log, one row per tick (written and flushed as it goes).
    camera : (image_size, frame_stack) the camera pipeline is configured for; checked against the model
        before takeoff (ModelSpecError).
    clock, sleep : time functions (``time.monotonic``, ``time.sleep``).
    watchdog : start :mod:`omcrl.deploy.watchdog` for a drone with a command address (a real or fake Tello):
        it lands the drone when this process dies, ``kill -9`` included.
    """

    LOG_FIELDS = (
        "t",
        "tick",
        "x",
        "y",
        "z",
        "yaw",
        "pose_age",
        "frame_age",
        "cmd_vx",
        "cmd_vy",
        "cmd_wz",
        "latency_ms",
        "goal_distance",
        "battery",
        "temperature",
        *(f"state_{i}" for i in range(12)),
        "act_vx",
        "act_vy",
        "act_wz",
        "event",
    )

    def __init__(
        self,
        policy: Any,
        drone: Drone,
        video: VideoSource,
        pose: PoseSource,
        goal: tuple[float, float],
        safety: Safety | None = None,
        log_path: str | Path | None = None,
        camera: tuple[int, int] | None = None,
        clock: Any = time.monotonic,
        sleep: Any = time.sleep,
        watchdog: bool = True,
    ) -> None:
        self.policy, self.drone, self.video, self.pose = policy, drone, video, pose
        spec = policy.spec
        if camera is not None:
            policy.check(camera[0], camera[1])
        self.size, self.stack = int(spec["image_size"]), int(spec["frame_stack"])
        self.safety = safety or Safety()
        sc = spec["action_scale"]
        self.max_speed = min(self.safety.max_speed or sc["max_speed"], sc["max_speed"])
        self.max_yaw = min(self.safety.max_yaw_rate or sc["max_yaw_rate"], sc["max_yaw_rate"])
        self.scale = np.array([sc["max_speed"], sc["max_speed"], sc["max_yaw_rate"]])
        self.dt = 1.0 / float(spec["control_hz"])
        self.goal = np.asarray(goal, np.float64)
        self.estimator = StateEstimator(goal, spec.get("altitude", 1.0))
        self.log_path = Path(log_path) if log_path is not None else None
        self.clock, self.sleep = clock, sleep
        self.watchdog = bool(watchdog)
        self.frames: deque = deque(maxlen=self.stack)
        self.cmd = np.zeros(3)
        self._camera_view: Any = None

    # ---------------------------------------------------------------- one tick
    def command(self, action: np.ndarray) -> np.ndarray:
        """Policy action in [−1, 1] → clamped and rate-limited (vx, vy, wz) in m/s and rad/s."""
        target = np.asarray(action, np.float64) * self.scale
        target[:2] = np.clip(target[:2], -self.max_speed, self.max_speed)
        target[2] = np.clip(target[2], -self.max_yaw, self.max_yaw)
        step = np.array([self.safety.max_accel, self.safety.max_accel, self.safety.max_yaw_accel]) * self.dt
        self.cmd = self.cmd + np.clip(target - self.cmd, -step, step)
        return self.cmd.copy()

    def _within_clamps(self, cmd: np.ndarray) -> bool:
        return bool(abs(cmd[0]) <= self.max_speed + 1e-9 and abs(cmd[1]) <= self.max_speed + 1e-9
                    and abs(cmd[2]) <= self.max_yaw + 1e-9)  # fmt: skip

    def _view(self, frame: np.ndarray) -> np.ndarray:
        """(H, W, 3) camera frame → (3, size, size): through both cameras' intrinsics when the video source
        declares its camera (``video.camera``, :mod:`omcrl.deploy.camera`), else a plain resize (a source that
        already renders the simulator's view, as the simulated drone does)."""
        cam = getattr(self.video, "camera", None)
        if cam is None:
            return _resize(frame, self.size)
        h, w = frame.shape[:2]
        if (w, h) != (cam.width, cam.height):
            cam = cam.scaled(w, h)
        if self._camera_view is None or self._camera_view.source != cam:
            self._camera_view = CameraView(cam, float(self.policy.spec.get("fov_deg", 82.6)), self.size)
        return np.ascontiguousarray(self._camera_view(frame).transpose(2, 0, 1))

    def observation(self, frame: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        img = self._view(frame)
        if not self.frames:
            self.frames.extend([img] * self.stack)  # the env also starts with the first frame repeated
        else:
            self.frames.append(img)
        rgb = np.concatenate(list(self.frames), axis=0)[None]
        return np.ascontiguousarray(rgb), state[None]

    def _check(self, now: float, t_start: float, frame: Any, pose: Any) -> str | None:
        s = self.safety
        if frame is not None and not _finite(frame[1], 1):
            return "bad_frame"
        if frame is None or now - frame[1] > s.stale_s:
            return "video_lost"
        img = frame[0]
        if not (isinstance(img, np.ndarray) and img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8):
            return "bad_frame"
        if pose is not None and not (_finite(pose[1], 1) and _finite(pose[0], 6)):
            return "bad_pose"
        if pose is None or now - pose[1] > s.stale_s:
            return "pose_lost"
        x, y = float(pose[0][0]), float(pose[0][1])
        if self._outside(pose[0]):
            return "geofence"
        if math.hypot(x - self.goal[0], y - self.goal[1]) <= s.goal_radius:
            return "arrived"
        if now - t_start > s.max_time_s:
            return "timeout"
        return None

    def _start_watchdog(self) -> Any:
        """The watchdog process (:mod:`omcrl.deploy.watchdog`) for a drone that gives a command address, else
        None (the simulated drone)."""
        address = getattr(self.drone, "watchdog_address", None)
        if address is None or not self.watchdog:
            return None
        import subprocess
        import sys

        host, port = address()
        # The script itself, not ``-m omcrl...``: it imports only the standard library and starts in milliseconds.
        script = Path(__file__).with_name("watchdog.py")
        return subprocess.Popen(
            [sys.executable, str(script), host, str(port), str(WATCHDOG_TIMEOUT_S), str(LAND_FALLBACK_S)],
            stdin=subprocess.PIPE,
            start_new_session=True,  # a Ctrl-C or SIGHUP to the loop's process group must not end it
        )

    def _wait(self, until: float, dog: Any = None) -> str | None:
        """Sleep until the next tick, watching every ``WATCH_S``: a video or pose that goes stale, a non-finite
        sample, a pose outside the geofence or a watchdog that died is seen within that, not at the next tick
        (``video_lost`` / ``pose_lost`` / ``bad_frame`` / ``bad_pose`` / ``geofence`` / ``watchdog_lost``, else
        None). Each watch is also a heartbeat to the watchdog ``dog``."""
        s = self.safety
        while True:
            now = self.clock()
            if now >= until:
                return None
            self.sleep(min(WATCH_S, until - now))
            now = self.clock()
            if dog is not None:
                if dog.poll() is not None:
                    return "watchdog_lost"
                _beat(dog, b".")
            frame, pose = self.video.read(), self.pose.read()
            if frame is not None and not _finite(frame[1], 1):
                return "bad_frame"
            if pose is not None and not (_finite(pose[1], 1) and _finite(pose[0], 6)):
                return "bad_pose"  # a bad sample stops the flight whenever it is seen
            for name, got in (("video_lost", frame), ("pose_lost", pose)):
                if got is None or now - got[1] > s.stale_s:
                    return name
            if self._outside(pose[0]):
                return "geofence"

    def _outside(self, p: Any) -> bool:
        """The pose (6,) lies outside the geofence or above its ceiling."""
        xmin, xmax, ymin, ymax = self.safety.geofence
        x, y, z = float(p[0]), float(p[1]), float(p[2])
        return not (xmin <= x <= xmax and ymin <= y <= ymax and z <= self.safety.max_altitude)

    def preflight(self) -> str | None:
        """What forbids takeoff, or None: the battery below ``min_battery``, no fresh finite pose from the mocap
        (the rigid body not seen), no video, start or goal outside the fence, the start above the ceiling."""
        s = self.safety
        battery = _reading(self.drone, "battery")
        if battery is not None and battery < s.min_battery:
            return f"battery {battery:.0f} % below the floor of {s.min_battery:.0f} %"
        now = self.clock()
        pose = self.pose.read()
        if pose is None or not (_finite(pose[1], 1) and _finite(pose[0], 6)) or now - pose[1] > s.stale_s:
            return "no fresh pose from the motion capture (is the rigid body visible?)"
        frame = self.video.read()
        if frame is None or not _finite(frame[1], 1) or now - frame[1] > s.stale_s:
            return "no fresh video frame"
        xmin, xmax, ymin, ymax = s.geofence
        for name, (x, y) in (("start", pose[0][:2]), ("goal", self.goal)):
            if not (xmin <= x <= xmax and ymin <= y <= ymax):
                return f"{name} ({x:.2f}, {y:.2f}) m outside the geofence {s.geofence}"
        if pose[0][2] > s.max_altitude:
            return f"start altitude {pose[0][2]:.2f} m above the ceiling {s.max_altitude} m"
        return None

    # ---------------------------------------------------------------- the flight
    def fly(self) -> FlightResult:
        """Take off, fly until a rule ends the flight, land (always), and return how it ended."""
        fh = open(self.log_path, "w", newline="") if self.log_path else None
        writer = csv.writer(fh) if fh else None
        if writer:
            writer.writerow(self.LOG_FIELDS)
            fh.flush()
        reason, error, tick, poses = "error", "", 0, []
        t_start = self.clock()
        last_pose = None
        # Ctrl-C, SIGTERM and SIGHUP must land the drone however the program was started (a process launched in
        # the background by a non-interactive shell inherits SIGINT as ignored) and however often they come: the
        # first stops the flight, later ones during landing are logged and do not interrupt it.
        previous: dict[int, Any] = {}
        stopping = {"raised": False, "signals": 0}

        def on_signal(signum: int, _frame: Any) -> None:
            # Only the first signal interrupts: one arriving between the interruption and the landing code (or
            # during the landing) must not cut the hover and land short.
            stopping["signals"] += 1
            if not stopping["raised"]:
                stopping["raised"] = True
                raise KeyboardInterrupt(signal.Signals(signum).name)

        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                previous[sig] = signal.signal(sig, on_signal)
        why = self.preflight()
        if why is not None:  # nothing was sent to the drone
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            if writer:
                self._log(writer, fh, 0.0, 0, None, None, self.clock(), None, 0.0, f"preflight: {why}")
                fh.close()
            return FlightResult("preflight", False, 0, 0.0, self.log_path, math.inf, why, [])
        dog = self._start_watchdog()
        try:
            with _Beating(dog, b"t"):  # the takeoff takes seconds; the watchdog is told the loop is alive
                self.drone.takeoff()
            t_start = self.clock()
            next_tick = t_start
            while True:
                now = self.clock()
                frame, pose = self.video.read(), self.pose.read()
                last_pose = pose if pose is not None and _finite(pose[0], 6) else last_pose
                stop = self._check(now, t_start, frame, pose)
                if stop is None and dog is not None and dog.poll() is not None:
                    stop = "watchdog_lost"  # nothing would land the drone if this process died now
                battery = _reading(self.drone, "battery")
                if stop is None and battery is not None and battery < self.safety.min_battery:
                    stop = "battery_low"
                if stop is not None:
                    reason = stop
                    self._log(writer, fh, now - t_start, tick, pose, frame, now, None, 0.0, stop)
                    break
                t0 = time.perf_counter()
                state = self.estimator.update(pose[0], pose[1])
                rgb, st = self.observation(frame[0], state)
                action = np.asarray(self.policy.run(rgb, st))[0] if _finite(state, 12) else None
                bad = "bad_state" if action is None else None if _finite(action, 3) else "bad_action"
                if bad is None and float(np.max(np.abs(action))) > ACTION_FAULT:
                    bad = "bad_action"  # finite but absurd (a broken model), not a command to clamp
                cmd = self.command(action) if bad is None else None
                if bad is None and not (_finite(cmd, 3) and self._within_clamps(cmd)):
                    bad = "bad_command"
                if bad is not None:  # hover, then land (finally), with the reason in the log and the result
                    reason = bad
                    self._log(writer, fh, now - t_start, tick, pose, frame, now, None, 0.0, bad)
                    break
                self.drone.send_velocity(*cmd.tolist())
                latency = (time.perf_counter() - t0) * 1e3
                poses.append(np.asarray(pose[0][:3], float).tolist())
                self._log(writer, fh, now - t_start, tick, pose, frame, now, cmd, latency, "", state, action)
                tick += 1
                _beat(dog, b".")
                next_tick += self.dt
                lost = self._wait(next_tick, dog)
                if lost is not None:
                    reason = lost
                    now = self.clock()
                    self._log(writer, fh, now - t_start, tick, pose, frame, now, None, 0.0, lost)
                    break
        except KeyboardInterrupt as e:
            reason = "interrupted"
            error = str(e) or "SIGINT"
        except Exception as e:  # any failure: land first, report after
            reason, error = "error", f"{type(e).__name__}: {e}"
        finally:
            stopping["raised"] = True  # no later signal interrupts the hover and the landing
            try:
                self.drone.send_velocity(0.0, 0.0, 0.0)
            except Exception as e:  # the link may be gone: still try to land
                error = error or f"hover command failed: {type(e).__name__}: {e}"
            try:
                # The Tello answers `land` when it is down (seconds); meanwhile the watchdog hears the loop is alive
                # and landing, so it never cuts the motors of a landing that goes on normally.
                with _Beating(dog, b"l"):
                    self.drone.land()
                event = "land"
            except Exception as e:
                event = f"land failed: {type(e).__name__}: {e}"
                error = f"{error}; {event}" if error else event
            if dog is not None:  # landed by the loop itself: release the watchdog
                _beat(dog, b"x")
                try:
                    dog.stdin.close()
                    dog.wait(2.0)
                except Exception:
                    dog.kill()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            if stopping["signals"] > 1:
                event += f" ({stopping['signals'] - 1} more stop signals during landing)"
            if writer:
                self._log(writer, fh, self.clock() - t_start, tick, last_pose, None, self.clock(), None, 0.0, event)
            if fh:
                fh.close()
        d = math.inf
        if last_pose is not None:
            d = math.hypot(float(last_pose[0][0]) - self.goal[0], float(last_pose[0][1]) - self.goal[1])
        return FlightResult(reason, reason == "arrived", tick, self.clock() - t_start, self.log_path, d, error, poses)

    def _log(self, writer: Any, fh: Any, t: float, tick: int, pose: Any, frame: Any, now: float, cmd: Any,
             latency: float, event: str, state: Any = None, action: Any = None) -> None:  # fmt: skip
        if writer is None:
            return
        p = pose[0] if pose is not None else [math.nan] * 6
        d = math.hypot(float(p[0]) - self.goal[0], float(p[1]) - self.goal[1]) if pose is not None else math.nan
        c = cmd if cmd is not None else [math.nan] * 3
        writer.writerow(
            [
                f"{t:.4f}",
                tick,
                *(f"{float(v):.4f}" for v in (p[0], p[1], p[2], p[5])),
                f"{now - pose[1]:.4f}" if pose is not None else "",
                f"{now - frame[1]:.4f}" if frame is not None else "",
                *(f"{float(v):.4f}" for v in c),
                f"{latency:.3f}",
                f"{d:.4f}",
                *(
                    "" if v is None else f"{v:.0f}"
                    for v in (_reading(self.drone, "battery"), _reading(self.drone, "temperature"))
                ),
                *([""] * 12 if state is None else [f"{float(v):.5g}" for v in state]),
                *([""] * 3 if action is None else [f"{float(v):.5g}" for v in action]),
                event,
            ]
        )
        fh.flush()
