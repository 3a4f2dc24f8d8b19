"""The drone / camera / pose contract of ControlLoop (omcrl.deploy.contract): the kit's simulated drone meets it,
and each kind of breach is named."""

from __future__ import annotations

import time

import numpy as np

from omcrl.config import load_config
from omcrl.deploy.contract import check_drone, check_pose, check_video
from omcrl.deploy.sim import SimulatedDrone


def test_the_simulated_drone_its_camera_and_mocap_meet_the_contract():
    cfg = load_config("smoke")
    drone = SimulatedDrone(cfg.env, layout=[], start=(0.0, 0.0, 0.0), goal=(3.0, 0.0))
    try:
        assert check_drone(drone, period_s=1.0 / cfg.env.control_hz) == []
        assert check_video(drone.camera()) == []
        assert check_pose(drone.mocap()) == []
    finally:
        drone.close()


class _BadDrone:
    def __init__(self):
        self.landed = 0

    def takeoff(self):
        pass

    def send_velocity(self, vx, vy, wz):
        time.sleep(0.05)  # waits for an answer: longer than a 20 ms control period

    def land(self):
        self.landed += 1
        if self.landed > 1:
            raise RuntimeError("already landed")

    def battery(self):
        return 150


def test_each_breach_of_the_drone_contract_is_named():
    problems = check_drone(_BadDrone(), period_s=0.02, sends=3)
    text = "\n".join(problems)
    assert "send_velocity() blocked for up to" in text
    assert "a second land() (the loop's stop paths may land twice) raised RuntimeError: already landed" in text
    assert "battery() returned 150, expected a number of % in [0, 100] or None" in text
    assert "note: no emergency()" in text
    assert check_drone(object())[0] == "object has no method takeoff() (required by ControlLoop)"


class _Reader:
    def __init__(self, value):
        self.value = value

    def read(self):
        return self.value, time.monotonic()


def test_streams_of_the_wrong_kind_are_named():
    assert "expected an H×W×3 uint8 RGB array" in check_video(_Reader(np.zeros((8, 8, 3), np.float32)))[0]
    assert "is not finite" in check_pose(_Reader(np.array([0, 0, 1, 0, 0, np.nan])))[0]
    assert "not (x, y, z, roll, pitch, yaw)" in check_pose(_Reader(np.zeros(3)))[0]
    assert check_video(_Reader(np.zeros((8, 8, 3), np.uint8))) == []


def test_a_stream_on_another_clock_is_named():
    class Wall(_Reader):
        def read(self):
            return self.value, time.time()  # the wall clock, not time.monotonic

    assert "is not on time.monotonic()" in check_pose(Wall(np.zeros(6)))[0]
