"""Flight safety with a real Tello's timing, tested from the drone's side.

A Tello answers ``takeoff`` and ``land`` only when the manoeuvre is done, seconds later. The fake Tello does the
same here (``SimulatedDrone(takeoff_s=..., land_s=...)``, much longer than the watchdog's 0.3 s), and every command
is timed where the fake receives it (``FakeTello.log``). The control loop runs in a child process through the real
djitellopy client, so it can be killed (SIGKILL) or frozen (SIGSTOP) in each phase of a flight.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import test_deploy  # its test doubles (tests/ is on sys.path under pytest)

from omcrl.config import load_config
from omcrl.deploy.loop import ACTION_FAULT, WATCHDOG_TIMEOUT_S, ControlLoop, Safety
from omcrl.deploy.sim import SimulatedDrone
from omcrl.deploy.timing import LAND_FALLBACK_S, LAND_S, TAKEOFF_S
from omcrl.deploy.watchdog import watch

EMPTY = [{"kind": "box", "position": (7.5, 7.5), "size": (0.2, 0.2, 0.2)}]
# Manoeuvre times of these tests: far longer than the watchdog's timeout (and than the 1 s its old `land` wait
# allowed), shorter than a Tello's defaults so that the suite stays quick.
TAKEOFF_T, LAND_T = 2.0, 1.5


def _sim(**kw):
    cfg = load_config("smoke", overrides=["env.image_size=16"])
    return SimulatedDrone(cfg.env, "box-v0", layout=EMPTY, start=(0.0, 0.0, 0.0), goal=(3.0, 0.0), **kw)


def test_the_tello_timing_is_one_documented_set_of_numbers():
    assert (TAKEOFF_S, LAND_S) == (5.0, 4.0)
    assert LAND_FALLBACK_S == 2 * LAND_S > LAND_S  # a landing from the fence's 2 m ceiling
    assert WATCHDOG_TIMEOUT_S + 0.05 < 0.5
    import inspect

    from omcrl.deploy.tello import TelloDrone

    assert inspect.signature(TelloDrone.land).parameters["timeout_s"].default == LAND_FALLBACK_S


def _udp_fake(timeout: float):
    """A simulated drone with the tests' manoeuvre times, its fake Tello, and a plain UDP client of it."""
    import socket

    from omcrl.deploy.tello import FakeTello

    sim = _sim(takeoff_s=TAKEOFF_T, land_s=LAND_T)
    fake = FakeTello(sim)
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.settimeout(timeout)
    return sim, fake, client, ("127.0.0.1", fake.command_port)


def test_the_fake_tello_answers_takeoff_and_land_when_the_manoeuvre_is_done():
    """Plain UDP, as the SDK speaks: `takeoff` is answered after the climb, with the height rising meanwhile;
    `land` after the descent; other commands are answered meanwhile; `emergency` drops the drone at once."""

    sim, fake, client, addr = _udp_fake(5.0)
    try:
        t0 = time.monotonic()
        client.sendto(b"takeoff", addr)
        time.sleep(TAKEOFF_T / 2)
        mid = sim.height
        client.sendto(b"battery?", addr)  # still answered during the climb
        assert client.recvfrom(64)[0] == b"ok"
        assert client.recvfrom(64)[0] == b"ok"
        took = time.monotonic() - t0
        assert 0.2 < mid < 0.8 * sim.cfg.altitude and TAKEOFF_T - 0.1 <= took <= TAKEOFF_T + 0.5, (mid, took)
        assert sim.flying and sim.height == pytest.approx(sim.cfg.altitude)
        t0 = time.monotonic()
        client.sendto(b"land", addr)
        assert client.recvfrom(64)[0] == b"ok"
        landed = time.monotonic() - t0
        assert LAND_T - 0.1 <= landed <= LAND_T + 0.5 and sim.height == 0.0 and not sim.motors_cut
        client.sendto(b"takeoff", addr)  # up again, then the emergency stop: down at once
        assert client.recvfrom(64)[0] == b"ok"
        client.sendto(b"emergency", addr)
        assert client.recvfrom(64)[0] == b"ok"
        assert sim.motors_cut and sim.height == 0.0
    finally:
        client.close()
        fake.close()
        sim.close()


def test_a_land_during_the_takeoff_lands_and_the_takeoff_is_never_answered():

    sim, fake, client, addr = _udp_fake(4.0)
    try:
        client.sendto(b"takeoff", addr)
        time.sleep(0.5)
        client.sendto(b"land", addr)
        assert client.recvfrom(64)[0] == b"ok"  # the land's answer, when down
        assert sim.height == 0.0 and not sim.flying and not sim.motors_cut
        client.settimeout(TAKEOFF_T)
        with pytest.raises(TimeoutError):
            client.recvfrom(64)
    finally:
        client.close()
        fake.close()
        sim.close()


# The control process: the loop through djitellopy (TelloDrone) with the watchdog on, a policy that flies gently
# forward, and a camera and a pose that always have fresh samples; it flies for argv[2] seconds, then lands.
_FLIGHT = r"""
import sys, time
import numpy as np
from omcrl.deploy.loop import ControlLoop, Safety
from omcrl.deploy.tello import TelloDrone

class Policy:
    spec = {"image_size": 8, "frame_stack": 2, "action_scale": {"max_speed": 1.0, "max_yaw_rate": 1.0},
            "control_hz": 10.0}
    def run(self, rgb, state):
        return np.array([[0.1, 0.0, 0.0]], np.float32)

class Fresh:
    def __init__(self, value):
        self.value = value
    def read(self):
        return self.value, time.monotonic()

tello = TelloDrone("127.0.0.1", int(sys.argv[1]), video_port=int(sys.argv[3]))
tello.connect(video=False)
safety = Safety(max_time_s=float(sys.argv[2]), geofence=(-50.0, 50.0, -50.0, 50.0))
loop = ControlLoop(Policy(), tello, Fresh(np.zeros((8, 8, 3), np.uint8)), Fresh(np.array([0, 0, 1.0, 0, 0, 0])),
                   (40.0, 0.0), safety=safety)
res = loop.fly()
print("result", res.reason, res.error, flush=True)
tello.close()
"""


def _flight(fake, fly_s: float, port: int) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", _FLIGHT, str(fake.command_port), str(fly_s), str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip


def _when(fake, cmd: str, after: float = 0.0, n: int = 1, timeout: float = 15.0) -> float:
    """The arrival time of the ``n``-th ``cmd`` (a prefix) the fake received after ``after``; waits for it."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        hits = [t for t, c in list(fake.log) if c.startswith(cmd) and t >= after]
        if len(hits) >= n:
            return hits[n - 1]
        time.sleep(0.005)
    raise AssertionError(f"the fake never received {cmd!r} (x{n}) after {after}: {fake.log[-8:]}")


def _table_row(fake, t0: float) -> str:
    return ", ".join(f"{c} +{1000 * (t - t0):.0f} ms" for t, c in fake.log if not c.startswith("rc "))


def test_a_normal_flight_with_a_tellos_timing_never_cuts_the_motors():
    """Takeoff answered after 2 s, landing after 1.5 s, a watchdog timeout of 0.3 s: the watchdog hears the loop
    all along (it beats from a thread while it waits), so the drone receives `takeoff`, rc commands, one `land` and
    never `emergency`."""
    from omcrl.deploy.tello import FakeTello

    sim = _sim(takeoff_s=TAKEOFF_T, land_s=LAND_T)
    fake = FakeTello(sim)
    proc = _flight(fake, 1.0, 11600)
    try:
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err[-3000:]
        t0 = _when(fake, "takeoff")
        print(f"[normal flight] {_table_row(fake, t0)}")
        assert "result timeout" in out, out + err[-2000:]
        cmds = [c for _, c in fake.log]
        assert "emergency" not in cmds and cmds.count("land") == 1 and any(c.startswith("rc ") for c in cmds)
        assert sim.touchdown_at is not None and not sim.motors_cut
        assert "watchdog: released" in err  # the loop landed and let it go; it never acted
    finally:
        if proc.poll() is None:
            proc.kill()
        fake.close()
        sim.close()


@pytest.mark.parametrize("phase", ["takeoff", "cruise", "landing"])
@pytest.mark.parametrize("sig", ["SIGKILL", "SIGSTOP"])
def test_a_dead_or_frozen_loop_is_landed_within_half_a_second_in_every_phase(phase, sig):
    """Kill -9 or freeze the control process during the takeoff, the cruise or its own landing: the watchdog's
    `land` reaches the drone within 0.5 s, and no `emergency` follows (a landing drone answers `land` when down)."""
    from omcrl.deploy.tello import FakeTello

    sim = _sim(takeoff_s=TAKEOFF_T, land_s=LAND_T)
    fake = FakeTello(sim)
    proc = _flight(fake, 1.0, 11610 + ["takeoff", "cruise", "landing"].index(phase))
    try:
        t_takeoff = _when(fake, "takeoff")
        anchor = {
            "takeoff": lambda: t_takeoff + 0.5,  # half a second into the 2 s climb
            "cruise": lambda: _when(fake, "rc ") + 0.3,
            "landing": lambda: _when(fake, "land") + 0.3,  # the loop's own land, 0.3 s into the descent
        }[phase]()
        time.sleep(max(0.0, anchor - time.monotonic()))
        hit = time.monotonic()
        os.kill(proc.pid, getattr(signal, sig))
        lands_before = sum(c == "land" for t, c in fake.log if t < hit)
        t_land = _when(fake, "land", after=hit)
        deadline = time.monotonic() + LAND_T + 1.0
        while sim.touchdown_at is None and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.2)
        print(f"[{sig} in {phase}] {_table_row(fake, hit)} (fault at +0 ms)")
        assert t_land - hit <= 0.5, t_land - hit
        assert "emergency" not in [c for _, c in fake.log] and not sim.motors_cut
        assert sim.touchdown_at is not None and sim.height == 0.0
        assert lands_before == (1 if phase == "landing" else 0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        fake.close()
        sim.close()


def test_the_watchdog_gives_an_unanswered_land_the_fallback_time_then_cuts_the_motors():
    """A drone that never answers `land`: `emergency` comes LAND_FALLBACK_S after the watchdog's `land` (here a
    shortened fallback, passed as the real one is)."""
    from omcrl.deploy.tello import FakeTello

    sim = _sim(takeoff_s=0.0, land_s=0.0)
    fake = FakeTello(sim, acknowledge_land=False)
    r, w = os.pipe()
    try:
        sim.takeoff()
        os.close(w)  # the loop's end of the pipe closes: it died
        what = watch("127.0.0.1", fake.command_port, 0.3, 1.2, stdin=r)
        t_land, t_em = _when(fake, "land"), _when(fake, "emergency")
        assert what == ("emergency", "takeoff") and 1.15 <= t_em - t_land <= 1.5 and sim.motors_cut
    finally:
        os.close(r)
        fake.close()
        sim.close()


class _Policy:
    def __init__(self, action):
        self.action = np.asarray(action, np.float64)[None]  # 1e300 stays finite (an ONNX float64 head)

    spec = {"image_size": 8, "frame_stack": 2, "action_scale": {"max_speed": 1.0, "max_yaw_rate": 1.0},
            "control_hz": 20.0}  # fmt: skip

    def run(self, rgb, state):
        return self.action


_Drone, _Fresh = test_deploy._Drone, test_deploy._Source  # a recording drone; a source of fresh samples


@pytest.mark.parametrize(("value", "reason"), [(5.0, "timeout"), (-9.9, "timeout"), (11.0, "bad_action"),
                                               (1e300, "bad_action")])  # fmt: skip
def test_an_absurd_policy_output_is_a_fault_a_large_one_is_clamped(value, reason):
    drone = _Drone()
    loop = ControlLoop(_Policy([value, 0.0, 0.0]), drone, _Fresh(np.zeros((8, 8, 3), np.uint8)),
                       _Fresh(np.array([0, 0, 1.0, 0, 0, 0])), (40.0, 0.0),
                       safety=Safety(max_time_s=0.3, geofence=(-50.0, 50.0, -50.0, 50.0)))  # fmt: skip
    res = loop.fly()
    assert res.reason == reason and drone.landed == 1
    assert all(abs(c[0]) <= loop.max_speed + 1e-9 for c in drone.sent)
    assert (len(drone.sent) > 2) == (reason == "timeout")
    assert ACTION_FAULT == 10.0


def test_the_geofence_is_watched_between_ticks():
    """At 2 Hz a tick comes every 0.5 s; the fence is watched every 20 ms between them, so a pose that leaves it is
    landed on within that, not at the next tick."""

    class Moving:
        def __init__(self):
            self.t0 = time.monotonic()

        def read(self):
            t = time.monotonic()
            return np.array([1.0 * (t - self.t0), 0, 1.0, 0, 0, 0]), t  # 1 m/s along x

    class Slow(_Policy):
        spec = {**_Policy.spec, "control_hz": 2.0}

    pose = Moving()
    loop = ControlLoop(Slow([0.0, 0.0, 0.0]), _Drone(), _Fresh(np.zeros((8, 8, 3), np.uint8)), pose, (0.0, 0.9),
                       safety=Safety(max_time_s=5.0, geofence=(-1.0, 0.7, -1.0, 1.0)))  # fmt: skip
    res = loop.fly()
    assert res.reason == "geofence"
    assert 0.65 <= res.duration_s <= 0.8, res.duration_s  # crossed at 0.70 s: seen within 20 ms, not at the 1.0 s tick


def test_a_dead_watchdog_lands_the_drone():
    """The watchdog process dies in flight: nothing would land the drone if the loop died next, so the loop lands
    (``watchdog_lost``) within a watch period."""
    import threading

    from omcrl.deploy.tello import FakeTello

    sim = _sim(takeoff_s=0.0, land_s=0.0)
    fake = FakeTello(sim)

    class Commanded(_Drone):
        def watchdog_address(self):
            return "127.0.0.1", fake.command_port

    loop = ControlLoop(_Policy([0.1, 0.0, 0.0]), Commanded(), _Fresh(np.zeros((8, 8, 3), np.uint8)),
                       _Fresh(np.array([0, 0, 1.0, 0, 0, 0])), (40.0, 0.0),
                       safety=Safety(max_time_s=10.0, geofence=(-50.0, 50.0, -50.0, 50.0)))  # fmt: skip
    dogs = []
    start = loop._start_watchdog
    loop._start_watchdog = lambda: dogs.append(start()) or dogs[-1]
    killed = {}
    timer = threading.Timer(0.5, lambda: (killed.setdefault("t", time.monotonic()), dogs[0].kill()))
    timer.start()
    try:
        res = loop.fly()
    finally:
        timer.cancel()
        fake.close()
        sim.close()
    assert res.reason == "watchdog_lost" and loop.drone.landed == 1
    assert res.duration_s - 0.5 < 0.2  # seen within a watch period or a tick of the kill
