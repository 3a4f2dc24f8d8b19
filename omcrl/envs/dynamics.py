"""Flight dynamics of ``NavEnv``'s drone: a body-frame velocity command through a first-order response with an
acceleration limit (a Tello-like model), integrated in substeps against the scene's analytic geometry."""

from __future__ import annotations

import math

import numpy as np

GRAVITY = 9.81


class Dynamics:
    """The motion of a :class:`omcrl.envs.nav_env.NavEnv`'s drone (a mixin over the env's state: ``_pos`` (3,) m,
    ``_vel`` (2,) body m/s, ``_yaw`` rad, ``_wz`` rad/s, ``_acc`` (2,) body m/s², ``_path_len`` m)."""

    def _fly(self, ax: float, ay: float, az: float) -> tuple[np.ndarray, bool, bool]:
        """Move the drone one control step under the command (ax, ay, az) in [-1, 1] (clipped).

        Returns the nearest obstacle point (3,) m, and whether the drone collided or left the arena (either
        stops the motion where it happened).
        """
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
        return closest, collided, out


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
