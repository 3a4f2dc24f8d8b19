"""Flight safety (issue: a policy or pose that goes bad): nothing non-finite reaches the motors (property tests)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from omcrl.deploy.loop import ControlLoop, Safety

BAD = (math.nan, math.inf, -math.inf)
HUGE = (1e300, -1e300, 1e12)
SAFETY = Safety(max_speed=0.5, max_yaw_rate=0.8, max_accel=1.0, max_yaw_accel=2.0, max_time_s=0.5,
                geofence=(-1e6, 1e6, -1e6, 1e6))  # fmt: skip
HZ = 50.0


class _Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t

    def sleep(self, d):
        self.t += max(d, 1e-4)


class _Script:
    """What each tick reads: a pose, a frame and a policy output, with one value replaced at one tick."""

    def __init__(self, clock, where, tick, value, index):
        self.clock, self.where, self.at, self.value, self.index = clock, where, tick, value, index
        self.n_pose = self.n_frame = self.n_run = 0

    def _tick(self, count):
        return count == self.at

    def pose(self):
        pose = np.array([0.1 * self.n_pose, 0.0, 1.0, 0.0, 0.0, 0.2], np.float64)
        t = self.clock()
        if self.where == "pose" and self._tick(self.n_pose):
            pose[self.index % 6] = self.value
        if self.where == "pose_time" and self._tick(self.n_pose):
            t = self.value
        self.n_pose += 1
        return pose, t

    def frame(self):
        t = self.clock()
        if self.where == "frame_time" and self._tick(self.n_frame):
            t = self.value
        self.n_frame += 1
        return np.zeros((8, 8, 3), np.uint8), t

    def run(self, rgb, state):
        out = np.array([[0.9, -0.4, 0.7]], np.float64)
        if self.where == "policy" and self._tick(self.n_run):
            out[0, self.index % 3] = self.value
        self.n_run += 1
        return out


class _Reader:
    def __init__(self, fn):
        self.read = fn


class _Policy:
    spec = {"image_size": 8, "frame_stack": 2, "action_scale": {"max_speed": 1.5, "max_yaw_rate": 1.5},
            "control_hz": HZ, "altitude": 1.0}  # fmt: skip

    def __init__(self, script):
        self.script = script

    def check(self, *a):
        pass

    def run(self, rgb, state):
        return self.script.run(rgb, state)


class _Motors:
    """Records every command; refuses non-finite ones as a real drone client must never be sent one."""

    def __init__(self):
        self.sent, self.landed = [], 0

    def takeoff(self):
        pass

    def send_velocity(self, vx, vy, wz):
        self.sent.append((vx, vy, wz))

    def land(self):
        self.landed += 1


def _fly(where, tick, value, index):
    clock = _Clock()
    script = _Script(clock, where, tick, value, index)
    motors = _Motors()
    loop = ControlLoop(_Policy(script), motors, _Reader(script.frame), _Reader(script.pose), (50.0, 0.0),
                       safety=SAFETY, clock=clock, sleep=clock.sleep)  # fmt: skip
    return loop.fly(), motors


@settings(max_examples=150, deadline=None)
@given(
    where=st.sampled_from(["pose", "pose_time", "frame_time", "policy"]),
    tick=st.integers(0, 20),
    value=st.sampled_from(BAD + HUGE),
    index=st.integers(0, 5),
)
def test_no_injected_value_reaches_the_motors_unclamped(where, tick, value, index):
    res, motors = _fly(where, tick, value, index)
    sent = np.array(motors.sent, np.float64)
    assert motors.landed == 1 and len(sent) >= 1 and tuple(sent[-1]) == (0.0, 0.0, 0.0)  # hover, then land
    assert np.isfinite(sent).all()
    assert (np.abs(sent[:, :2]) <= 0.5 + 1e-9).all() and (np.abs(sent[:, 2]) <= 0.8 + 1e-9).all()
    steps = np.abs(np.diff(np.vstack([np.zeros(3), sent[:-1]]), axis=0))  # the final stop is not rate-limited
    assert (steps[:, :2] <= 1.0 / HZ + 1e-9).all() and (steps[:, 2] <= 2.0 / HZ + 1e-9).all()
    if value in BAD and tick <= 20:
        # The flight stops at the bad value: nothing is sent from that tick on but the final zero.
        assert res.reason in ("bad_pose", "bad_frame", "bad_action", "bad_state", "video_lost", "pose_lost")
        assert len(sent) - 1 <= tick
    assert not math.isnan(res.final_distance)  # inf when no valid pose was ever seen, never NaN


def test_tello_rc_refuses_non_finite_velocities():
    from omcrl.deploy.tello import TelloDrone

    drone = TelloDrone.__new__(TelloDrone)  # the mapping alone: no connection
    drone.speed_at_100, drone.yaw_at_100 = 1.0, 1.0
    assert drone.rc(0.5, -2.0, 0.25) == (100, 50, 0, -25)
    for bad in BAD:
        with pytest.raises(ValueError, match="non-finite"):
            drone.rc(bad, 0.0, 0.0)
