"""The one observation layout: what each entry of the ``state`` and ``privileged`` vectors holds.

The env writes these vectors, the feature extractors read them, the dataset stores them and the deploy loop
rebuilds ``state`` from a pose source; all of them name the entries here instead of slicing by number::

    state (12,)      v (3, body, m/s) | ω (3, rad/s) | θ (roll, pitch, yaw, rad) | Δp_goal (3, body, m)
    privileged (6,)  Δp to the nearest obstacle surface point (3, body, m) | Δp_goal (3, body, m)

Light on purpose (numpy only): the deploy side and the models import it without PyBullet.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

# (name, size, unit): the entries in their order.
STATE_LAYOUT = (
    ("v", 3, "m/s, body frame"),
    ("omega", 3, "rad/s"),
    ("theta", 3, "rad: roll, pitch, yaw"),
    ("goal", 3, "m, body frame"),
)
PRIVILEGED_LAYOUT = (("obstacle", 3, "m, body frame"), ("goal", 3, "m, body frame"))


def _slices(layout: Sequence[tuple[str, int, str]]) -> dict[str, slice]:
    out, start = {}, 0
    for name, size, _ in layout:
        out[name] = slice(start, start + size)
        start += size
    return out


STATE = _slices(STATE_LAYOUT)
PRIVILEGED = _slices(PRIVILEGED_LAYOUT)
STATE_DIM = sum(size for _, size, _ in STATE_LAYOUT)
PRIVILEGED_DIM = sum(size for _, size, _ in PRIVILEGED_LAYOUT)
# v, ω and θ: the part of ``state`` the oracle takes beside the privileged vector (its goal is in both).
KINEMATICS = slice(STATE["v"].start, STATE["theta"].stop)
ORACLE_LOW_DIM = KINEMATICS.stop - KINEMATICS.start + PRIVILEGED_DIM


def pack_state(v: Sequence[float], omega: Sequence[float], theta: Sequence[float], goal: Sequence[float]) -> np.ndarray:
    """The ``state`` vector (12,) float32 from its entries (each of 3 values, units as :data:`STATE_LAYOUT`)."""
    return np.array([*v, *omega, *theta, *goal], np.float32)


def pack_privileged(obstacle: Sequence[float], goal: Sequence[float]) -> np.ndarray:
    """The ``privileged`` vector (6,) float32 from its entries (units as :data:`PRIVILEGED_LAYOUT`)."""
    return np.array([*obstacle, *goal], np.float32)
