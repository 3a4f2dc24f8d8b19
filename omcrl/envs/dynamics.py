"""Flight dynamics of ``NavEnv``'s drone: a body-frame velocity command through a first-order response with an
acceleration limit (a Tello-like model), integrated in substeps against the scene's analytic geometry.

The drone's state is one record (:class:`DroneState`); one control step is a pure function of it
(:func:`fly`: state, command, model and geometry in, the next state out), so the flight model can be read, tested
and reused apart from the env.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

GRAVITY = 9.81


@dataclass(frozen=True)
class DroneState:
    """Where the drone is and how it moves.

    Attributes
    ----------
    pos : (3,) world position, m (z is the flight altitude).
    yaw : heading, rad in [-π, π).
    vel : (vx, vy) body-frame velocity, m/s.
    wz : yaw rate, rad/s.
    acc : (ax, ay) body-frame acceleration of the last substep, m/s² (the observed tilt follows it).
    path_len : distance flown since the episode began, m.
    """

    pos: np.ndarray
    yaw: float
    vel: tuple[float, float] = (0.0, 0.0)
    wz: float = 0.0
    acc: tuple[float, float] = (0.0, 0.0)
    path_len: float = 0.0


@dataclass(frozen=True)
class FlightModel:
    """The drone's limits and the integration of one control step.

    Attributes
    ----------
    max_speed : m/s per axis at a command of 1; max_yaw_rate : rad/s at a command of 1.
    max_accel : m/s², the acceleration limit; drone_radius : m, a collision below it; arena_half : m.
    dt : s per control step; substeps : integration substeps per control step; k_resp : the first-order response's
        share of the gap to the command closed per substep (1 − exp(−dt_sub / τ)).
    """

    max_speed: float
    max_yaw_rate: float
    max_accel: float
    drone_radius: float
    arena_half: float
    dt: float
    substeps: int
    k_resp: float

    @classmethod
    def from_config(cls, cfg: Any) -> FlightModel:
        """The model of an :class:`omcrl.config.EnvConfig`: substeps keep each move shorter than the drone radius,
        so thin walls cannot be tunnelled through."""
        dt = 1.0 / cfg.control_hz
        substeps = max(1, math.ceil(cfg.max_speed * dt / cfg.drone_radius - 1e-9))
        k = 1.0 - math.exp(-(dt / substeps) / cfg.velocity_tau) if cfg.velocity_tau > 0 else 1.0
        return cls(cfg.max_speed, cfg.max_yaw_rate, cfg.max_accel, cfg.drone_radius, cfg.arena_half, dt, substeps, k)


def fly(
    state: DroneState, command: tuple[float, float, float], model: FlightModel, geometry: Any
) -> tuple[DroneState, np.ndarray, bool, bool]:
    """One control step of the drone from ``state`` under ``command`` (ax, ay, az) in [-1, 1] (clipped), against
    ``geometry`` (:class:`omcrl.envs.geometry.Geometry`: ``nearest(pos) -> (point, distance)``).

    Returns the next state, the nearest obstacle point (3,) m, and whether the drone collided or left the arena
    (either stops the motion where it happened). ``state`` is not changed.
    """
    ax, ay, az = command
    # Scalar math on purpose: on 2-vectors plain floats are several times cheaper than numpy calls, and
    # this loop is the only per-step work besides the render.
    cx = min(1.0, max(-1.0, ax)) * model.max_speed
    cy_cmd = min(1.0, max(-1.0, ay)) * model.max_speed
    cw = min(1.0, max(-1.0, az)) * model.max_yaw_rate
    dt = model.dt / model.substeps
    # First-order response toward the command, then the acceleration limit (Tello-like).
    k = model.k_resp
    lim = model.max_accel * dt
    collided = out = False
    pos = np.array(state.pos, dtype=float)
    vx, vy = state.vel
    wz, yaw, acc, path_len = state.wz, state.yaw, state.acc, state.path_len
    px, py = float(pos[0]), float(pos[1])
    for _ in range(model.substeps):
        dvx, dvy = (cx - vx) * k, (cy_cmd - vy) * k
        n = math.hypot(dvx, dvy)
        if n > lim:
            dvx, dvy = dvx * lim / n, dvy * lim / n
        vx, vy = vx + dvx, vy + dvy
        acc = (dvx / dt, dvy / dt)
        wz += (cw - wz) * k
        yaw = _wrap(yaw + wz * dt)
        cyaw, syaw = math.cos(yaw), math.sin(yaw)
        mx, my = (cyaw * vx - syaw * vy) * dt, (syaw * vx + cyaw * vy) * dt
        px, py = px + mx, py + my
        path_len += math.hypot(mx, my)
        pos[0], pos[1] = px, py
        closest, dist = geometry.nearest(pos)
        if dist <= model.drone_radius:
            collided = True
            break
        if abs(px) > model.arena_half or abs(py) > model.arena_half:
            out = True
            break
    return replace(state, pos=pos, yaw=yaw, vel=(vx, vy), wz=wz, acc=acc, path_len=path_len), closest, collided, out


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
