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
    if res.reason == "preflight":  # the bad value came before takeoff: nothing was sent at all
        assert motors.sent == [] and motors.landed == 0 and tick == 0
        return
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


class _SlowLander(_Motors):
    def __init__(self, on_land=None):
        super().__init__()
        self.on_land = on_land

    def land(self):
        if self.on_land is not None:
            self.on_land()
        import time

        time.sleep(0.3)  # a signal arrives while the drone lands
        self.landed += 1


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGHUP", "SIGINT"])
def test_stop_signals_land_and_a_second_one_does_not_interrupt_landing(sig, tmp_path):
    import os
    import signal
    import threading
    import time

    signum = getattr(signal, sig)
    pid = os.getpid()
    motors = _SlowLander(on_land=lambda: os.kill(pid, signal.SIGINT))  # a second Ctrl-C during landing
    script = _Script(time.monotonic, "none", -1, 0.0, 0)
    loop = ControlLoop(_Policy(script), motors, _Reader(script.frame), _Reader(script.pose), (50.0, 0.0),
                       safety=Safety(max_time_s=30.0, geofence=(-1e6, 1e6, -1e6, 1e6)),
                       log_path=tmp_path / "flight.csv")  # fmt: skip
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    timer = threading.Timer(0.3, lambda: os.kill(pid, signum))
    timer.start()
    try:
        res = loop.fly()
    finally:
        timer.cancel()
    assert res.reason == "interrupted" and res.error == sig and motors.landed == 1
    assert motors.sent[-1] == (0.0, 0.0, 0.0)
    assert "1 more stop signals during landing" in (tmp_path / "flight.csv").read_text().splitlines()[-1]
    assert {s: signal.getsignal(s) for s in before} == before  # handlers restored


def test_camera_view_maps_the_tello_frame_onto_the_simulator_geometry():
    """A red ball seen by the simulator's square camera and by a Tello-geometry camera at the same pose: after
    :class:`CameraView`, the ball sits on the same pixels of the policy's input (rendered, not drawn)."""
    from omcrl.deploy.camera import TELLO, CameraIntrinsics, CameraView
    from omcrl.envs import make_env

    ball = [{"kind": "sphere", "position": (3.0, 1.2, 1.6), "size": (0.15,), "color": (1.0, 0.0, 0.0)}]
    env = make_env("box", seed=0, image_size=64, layout=ball)
    obs, _ = env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (-3.0, -3.0)})
    sim = obs["rgb"][-1].transpose(1, 2, 0)
    tello = TELLO.scaled(240, 180)
    frame = env.render_camera(tello.width, tello.height, tello.fov_deg()[1])
    env.close()
    view = CameraView(tello, env.cfg.fov_deg, 64)
    mapped = view(frame)

    def centre(img):
        red = (img[..., 0] > 150) & (img[..., 1] < 80) & (img[..., 2] < 80)
        assert red.sum() >= 3
        v, u = np.nonzero(red)
        return np.array([u.mean() + 0.5, v.mean() + 0.5])

    want = CameraIntrinsics.square(64, env.cfg.fov_deg).project(np.array([[3.0, 1.2, 0.6]]))[0]
    np.testing.assert_allclose(centre(sim), want, atol=0.8)  # the simulator is the pinhole we assume
    np.testing.assert_allclose(centre(mapped), centre(sim), atol=0.8)
    # A plain resize (the loop before) squashes 4:3 into the square: the ball lands elsewhere.
    import cv2

    squashed = cv2.resize(frame, (64, 64), interpolation=cv2.INTER_AREA)
    assert np.abs(centre(squashed) - centre(sim)).max() > 3.0
    assert abs(view.coverage - 0.48) < 0.02 and CameraView(tello, 55.6, 64).coverage == 1.0


def _q(roll=0.0, pitch=0.0, yaw=0.0):
    """Quaternion (w, x, y, z) of ZYX Euler angles."""
    cr, sr, cp, sp, cy, sy = (f(a / 2) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy)  # fmt: skip


def test_mocap_pose_conventions_z_up_y_up_yaw_wrap_and_body_frame_state():
    from omcrl.deploy.loop import StateEstimator
    from omcrl.deploy.tello import _Y_TO_Z, pose_from_mocap, quat_to_matrix

    # Z-up: position as streamed, yaw counter-clockwise from x, roll and pitch recovered.
    got = pose_from_mocap((1.0, 2.0, 0.9), _q(0.1, -0.05, math.pi / 2))
    np.testing.assert_allclose(got, [1.0, 2.0, 0.9, 0.1, -0.05, math.pi / 2], atol=1e-9)
    # Y-up streaming (Motive's default): the same pose expressed Y-up comes back Z-up.
    r_y = _Y_TO_Z.T @ quat_to_matrix(*_q(0.1, -0.05, 2.5)) @ _Y_TO_Z
    w = math.sqrt(max(0.0, 1 + np.trace(r_y))) / 2
    q_y = (w, (r_y[2, 1] - r_y[1, 2]) / (4 * w), (r_y[0, 2] - r_y[2, 0]) / (4 * w), (r_y[1, 0] - r_y[0, 1]) / (4 * w))
    p_y = _Y_TO_Z.T @ np.array([1.0, 2.0, 0.9])
    np.testing.assert_allclose(pose_from_mocap(p_y, q_y, up="y"), [1.0, 2.0, 0.9, 0.1, -0.05, 2.5], atol=1e-9)
    # Yaw wraps at ±π: a turn through π is a small rotation rate, not 2π per tick.
    est = StateEstimator(goal=(0.0, 5.0), altitude=1.0, smoothing=0.0)
    est.update(pose_from_mocap((0.0, 0.0, 1.0), _q(yaw=math.pi - 0.01)), 0.0)
    s = est.update(pose_from_mocap((0.0, 0.0, 1.0), _q(yaw=-math.pi + 0.01)), 0.1)
    assert s[5] == pytest.approx(0.2, abs=1e-6)  # ω_z = 0.02 rad / 0.1 s, counter-clockwise
    # A 90° turn: facing +y, a goal 5 m along +y is straight ahead in the body frame; moving along +y is forward.
    est = StateEstimator(goal=(0.0, 5.0), altitude=1.0, smoothing=0.0)
    est.update(pose_from_mocap((0.0, 0.0, 1.0), _q(yaw=math.pi / 2)), 0.0)
    s = est.update(pose_from_mocap((0.0, 0.1, 1.0), _q(yaw=math.pi / 2)), 0.1)
    np.testing.assert_allclose(s[[0, 1, 9, 10]], [1.0, 0.0, 4.9, 0.0], atol=1e-9)
    with pytest.raises(ValueError, match="not a rotation"):
        pose_from_mocap((0, 0, 0), (0.0, 0.0, 0.0, 0.0))


class _Battery(_Motors):
    def __init__(self, charge):
        super().__init__()
        self.charge, self.took_off = charge, False

    def takeoff(self):
        self.took_off = True

    def battery(self):
        return self.charge


def test_preflight_refuses_takeoff_and_sends_nothing():
    clock = _Clock()
    ok = _Script(clock, "none", -1, 0.0, 0)

    def flight(drone, pose=ok.pose, goal=(1.0, 0.0), **safety):
        loop = ControlLoop(_Policy(ok), drone, _Reader(ok.frame), _Reader(pose), goal,
                           safety=Safety(**safety), clock=clock, sleep=clock.sleep)  # fmt: skip
        return loop.fly()

    for drone, kw, why in (
        (_Battery(5), {}, "battery 5 % below the floor of 20 %"),
        (_Battery(90), {"pose": lambda: None}, "no fresh pose from the motion capture"),
        (_Battery(90), {"pose": lambda: (np.array([0, 0, 1.0, 0, 0, math.nan]), clock())}, "no fresh pose"),
        (_Battery(90), {"goal": (5.0, 0.0)}, "goal (5.00, 0.00) m outside the geofence"),
    ):
        res = flight(drone, **kw)
        assert res.reason == "preflight" and why in res.error, res
        assert not drone.took_off and drone.sent == [] and drone.landed == 0
    drone = _Battery(90)
    res = flight(drone, max_time_s=0.1)  # all checks pass: it flies
    assert res.reason in ("timeout", "arrived") and drone.took_off and drone.landed == 1


def test_in_flight_battery_floor_and_altitude_ceiling_land():
    clock = _Clock()
    script = _Script(clock, "none", -1, 0.0, 0)
    drone = _Battery(50)
    loop = ControlLoop(_Policy(script), drone, _Reader(script.frame), _Reader(script.pose), (2.5, 0.0),
                       safety=Safety(max_time_s=5.0), clock=clock, sleep=clock.sleep)  # fmt: skip
    orig = script.pose

    def draining():
        if script.n_pose > 10:
            drone.charge = 12
        return orig()

    loop.pose = _Reader(draining)
    res = loop.fly()
    assert res.reason == "battery_low" and drone.landed == 1 and drone.sent[-1] == (0.0, 0.0, 0.0)
    high = _Reader(lambda: (np.array([0.0, 0.0, 2.5, 0.0, 0.0, 0.0]), clock()))
    loop = ControlLoop(_Policy(script), _Battery(80), _Reader(script.frame), high, (2.5, 0.0),
                       safety=Safety(max_time_s=5.0, max_altitude=3.0), clock=clock, sleep=clock.sleep)  # fmt: skip
    loop.safety.max_altitude = 2.0  # the ceiling drops below the drone after takeoff
    loop.preflight = lambda: None
    assert loop.fly().reason == "geofence"
