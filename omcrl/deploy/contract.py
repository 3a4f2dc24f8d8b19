"""What :class:`~omcrl.deploy.loop.ControlLoop` needs from a drone, a camera and a pose source, as checks a new
implementation can run before it flies (docs/extending.md, "Your own drone").

Each ``check_*`` exercises an object the way the loop will and returns the problems it found, one line each
(an empty list: it meets the contract). They do not replace flying it: ``tests/test_flight_safety.py`` and
``tests/test_deploy.py`` fly the kit's drones through cut streams, bad values and killed processes, and a new drone
should pass them with its class put in the place of ``SimulatedDrone``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np


def _call(problems: list[str], what: str, fn: Callable[[], Any]) -> tuple[bool, Any]:
    try:
        return True, fn()
    except Exception as e:  # a contract check reports every failure instead of stopping at the first
        problems.append(f"{what} raised {type(e).__name__}: {e}")
        return False, None


def check_drone(drone: Any, *, period_s: float = 0.1, sends: int = 10) -> list[str]:
    """Fly ``drone`` through the loop's calls: ``takeoff()``, ``sends`` × ``send_velocity(vx, vy, wz)`` (m/s, m/s,
    rad/s; small values) one control period apart, ``land()`` twice (the loop's stop paths can land a landed drone),
    and the optional ``battery()`` (%, 0-100), ``temperature()`` (°C) and ``emergency()``.

    Problems reported: a required method missing, a call that raises, a ``send_velocity`` that blocks for longer
    than ``period_s`` (the loop would miss its control period), a second ``land()`` that fails, a battery or
    temperature reading that is not a finite number in range. ``emergency()`` is not called (it cuts the motors);
    its absence is reported only as a note, since the loop then lands instead.
    """
    problems: list[str] = []
    for name in ("takeoff", "send_velocity", "land"):
        if not callable(getattr(drone, name, None)):
            problems.append(f"{type(drone).__name__} has no method {name}() (required by ControlLoop)")
    if problems:
        return problems
    _call(problems, "takeoff()", drone.takeoff)
    slow = []
    for i in range(sends):
        v = 0.1 * math.sin(i)
        t0 = time.monotonic()
        ok, _ = _call(problems, f"send_velocity({v:.2f}, 0.0, 0.0)", lambda v=v: drone.send_velocity(v, 0.0, 0.0))
        took = time.monotonic() - t0
        if not ok:
            break
        if took > period_s:
            slow.append(took)
        time.sleep(max(0.0, period_s - took))
    if slow:
        problems.append(
            f"send_velocity() blocked for up to {max(slow) * 1000:.0f} ms in {len(slow)} of {sends} calls, longer than "
            f"the control period ({period_s * 1000:.0f} ms): send without waiting for an answer"
        )
    _call(problems, "send_velocity(0, 0, 0) before landing", lambda: drone.send_velocity(0.0, 0.0, 0.0))
    _call(problems, "land()", drone.land)
    _call(problems, "a second land() (the loop's stop paths may land twice)", drone.land)
    for name, lo, hi, unit in (("battery", 0.0, 100.0, "%"), ("temperature", -40.0, 150.0, "°C")):
        fn = getattr(drone, name, None)
        if fn is None:
            continue
        ok, value = _call(problems, f"{name}()", fn)
        if ok and value is not None:
            if not isinstance(value, (int, float, np.integer, np.floating)) or not lo <= float(value) <= hi:
                problems.append(f"{name}() returned {value!r}, expected a number of {unit} in [{lo:g}, {hi:g}] or None")
    if not callable(getattr(drone, "emergency", None)):
        problems.append("note: no emergency() - on a fault the loop lands instead of cutting the motors")
    return problems


def _check_stream(
    source: Any, what: str, reads: int, timeout_s: float, check: Callable[[Any], str | None]
) -> list[str]:
    problems: list[str] = []
    if not callable(getattr(source, "read", None)):
        return [f"{type(source).__name__} has no method read() (required of a {what})"]
    got, last_t, deadline = 0, -math.inf, time.monotonic() + timeout_s
    while got < reads and time.monotonic() < deadline:
        ok, item = _call(problems, f"{what} read()", source.read)
        if not ok:
            return problems
        if item is None:  # nothing new yet: allowed, the loop treats it as "no fresh data"
            time.sleep(0.01)
            continue
        if not (isinstance(item, tuple) and len(item) == 2):
            return [f"{what} read() returned {type(item).__name__}, expected (value, time s) or None"]
        value, t = item
        bad = check(value)
        if bad:
            return [f"{what} read(): {bad}"]
        now = time.monotonic()
        if not isinstance(t, (int, float)) or not math.isfinite(t) or abs(now - float(t)) > 5.0:
            return [f"{what} read(): time {t!r} is not on time.monotonic() (now {now:.1f}); the loop ages data by it"]
        if t < last_t:
            return [f"{what} read(): time went backwards ({t:.3f} after {last_t:.3f})"]
        last_t, got = float(t), got + 1
    if got < reads:
        problems.append(f"{what} gave {got} of {reads} readings within {timeout_s:g} s")
    return problems


def check_video(source: Any, *, reads: int = 5, timeout_s: float = 5.0) -> list[str]:
    """``read() -> (frame H×W×3 uint8 RGB, arrival time s on time.monotonic) or None``, ``reads`` times."""

    def frame(v: Any) -> str | None:
        if not isinstance(v, np.ndarray) or v.ndim != 3 or v.shape[2] != 3 or v.dtype != np.uint8:
            shape = getattr(v, "shape", None)
            return f"frame {type(v).__name__} {shape} {getattr(v, 'dtype', '')}, expected an H×W×3 uint8 RGB array"
        return None

    return _check_stream(source, "video source", reads, timeout_s, frame)


def check_pose(source: Any, *, reads: int = 5, timeout_s: float = 5.0) -> list[str]:
    """``read() -> (pose (6,) x, y, z m and roll, pitch, yaw rad in a Z-up world, time s) or None``."""

    def pose(v: Any) -> str | None:
        a = np.asarray(v, dtype=float) if isinstance(v, (np.ndarray, list, tuple)) else None
        if a is None or a.shape != (6,):
            return f"pose {v!r} is not (x, y, z, roll, pitch, yaw) of shape (6,)"
        if not np.isfinite(a).all():
            return f"pose {a.tolist()} is not finite (report None while tracking is lost)"
        return None

    return _check_stream(source, "pose source", reads, timeout_s, pose)
