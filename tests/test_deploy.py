"""Deployment: ONNX export and parity, the onnxruntime policy in evaluation, the control loop's safety rules on
the simulated drone, and the loop through the real djitellopy client against the loopback fake Tello."""

from __future__ import annotations

import os
import re
import signal
import threading
import time

import numpy as np
import pytest
import torch

from omcrl.config import load_config, save_config
from omcrl.deploy import ExportError, ModelSpecError, OnnxPolicy, export_onnx
from omcrl.deploy.loop import ControlLoop, Safety
from omcrl.deploy.sim import SimulatedDrone
from omcrl.eval import evaluate
from omcrl.models.actor_critic import ActorCritic
from omcrl.models.features import make_oracle_features, make_pixel_features
from omcrl.rl import load_policy
from omcrl.rl.policy import policy_payload

torch.set_num_threads(1)
EMPTY = [{"kind": "box", "position": (7.5, 7.5), "size": (0.2, 0.2, 0.2)}]  # one far-away box: an empty room
# Takeoff and landing at once: these tests are about the loop's rules in flight, not a Tello's manoeuvre times
# (tests/test_tello_timing.py flies with those).
INSTANT = {"takeoff_s": 0.0, "land_s": 0.0}


def _cfg(tmp_path):
    return load_config("smoke", overrides=[f"results_dir={tmp_path}", "env.image_size=32", "env.max_steps=80"])


def _space(cfg):
    from omcrl.envs import make_env

    env = make_env("box", seed=0, config=cfg.env)
    space = env.observation_space
    env.close()
    return space


def goal_seeker(tmp_path, cfg, name="seeker"):
    """A pixel policy whose actor is a saturating P-controller on Δp_goal (its encoder is random and ignored):
    it flies straight to the goal, so flights through the loop have a known good outcome."""
    torch.manual_seed(0)
    space = _space(cfg)
    feats = make_pixel_features(space, cfg.pretrain.crop_to, cfg.pretrain.feature_dim)
    agent = ActorCritic(feats, 3, 16, layer_norm=False)
    gx = feats.feature_dim + 9
    with torch.no_grad():
        for layer in (agent.actor[1], agent.actor[3], agent.actor[5]):
            layer.weight.zero_()
            layer.bias.zero_()
        agent.actor[1].weight[0, gx] = agent.actor[1].weight[1, gx + 1] = 0.5
        agent.actor[3].weight[0, 0] = agent.actor[3].weight[1, 1] = 1.0
        agent.actor[5].weight[0, 0] = agent.actor[5].weight[1, 1] = 3.0
    run = tmp_path / name
    run.mkdir()
    shapes = {k: list(s.shape) for k, s in space.spaces.items()}
    torch.save(policy_payload(agent, shapes, 0, meta={"method": name}), run / "final.pt")
    save_config(cfg, run)
    return run


@pytest.fixture(scope="module")
def seeker(tmp_path_factory):
    """(config, run folder, exported ONNX file) of the goal seeker, exported once for the module."""
    root = tmp_path_factory.mktemp("deploy")
    cfg = _cfg(root)
    run = goal_seeker(root, cfg)
    return cfg, run, export_onnx(run)


def test_export_parity_metadata_and_refusals(tmp_path, seeker):
    cfg, run, path = seeker
    pol, ref = OnnxPolicy(path), load_policy(run / "final.pt")
    assert pol.spec["image_size"] == 32 and pol.spec["frame_stack"] == cfg.env.frame_stack
    assert pol.spec["action_scale"] == {"max_speed": cfg.env.max_speed, "max_yaw_rate": cfg.env.max_yaw_rate}
    rng = np.random.default_rng(0)
    diff = 0.0
    for _ in range(200):
        obs = {
            "rgb": rng.integers(0, 256, (cfg.env.frame_stack, 3, 32, 32), dtype=np.uint8),
            "state": (rng.normal(size=12) * 3).astype(np.float32),
        }
        diff = max(diff, float(np.abs(pol.act(obs) - ref.act(obs)).max()))
    assert diff <= 1e-4
    pol.check(32, cfg.env.frame_stack)
    with pytest.raises(ModelSpecError, match="image_size configured 64, model 32"):
        pol.check(64, cfg.env.frame_stack)
    # The oracle needs privileged inputs: refused with a reason.
    space = _space(cfg)
    oracle = ActorCritic(make_oracle_features(space, 16, cfg.env.far), 3, 16)
    (tmp_path / "oracle").mkdir()
    torch.save(
        policy_payload(oracle, {k: list(s.shape) for k, s in space.spaces.items()}, 0), tmp_path / "oracle/final.pt"
    )
    save_config(cfg, tmp_path / "oracle")
    with pytest.raises(ExportError, match="privileged"):
        export_onnx(tmp_path / "oracle")
    with pytest.raises(FileNotFoundError, match="final.pt"):
        export_onnx(tmp_path / "nothing")


def test_a_damaged_run_config_is_refused_though_it_still_parses(tmp_path, seeker):
    """A run records its config.yaml's digest (Run.write_config): the export refuses a changed file. Cut at a line
    boundary, the YAML still parses, and the fields after the cut would silently take their defaults."""
    import shutil

    import yaml

    from omcrl.runs import ArtifactMismatch, make_run

    cfg, run, _ = seeker
    r = make_run(cfg.with_overrides([f"results_dir={tmp_path}"]), "rl", "seeker", {"test": "config digest"})
    r.claim()
    shutil.copyfile(run / "final.pt", r.dir / "final.pt")
    r.write_config(cfg)
    r.release()
    assert export_onnx(r.dir).is_file()
    cfg_path = r.dir / "config.yaml"
    lines = cfg_path.read_text().splitlines()
    cfg_path.write_text("\n".join(lines[: len(lines) // 2]) + "\n")
    assert isinstance(yaml.safe_load(cfg_path.read_text()), dict)
    with pytest.raises(ArtifactMismatch, match=r"run config .*config.yaml does not match the digest recorded"):
        export_onnx(r.dir)


def test_exported_policy_flies_evaluate_like_the_torch_policy(seeker):
    cfg, run, path = seeker
    onnx_pol, torch_pol = OnnxPolicy(path), load_policy(run / "final.pt")
    kw = {"config": cfg.env}
    # box-v0: a straight-line goal seeker reaches goals there (box-v2 puts most goals behind a wall).
    a = evaluate(onnx_pol, "box-v0", 4, 0, seed_offset=cfg.eval.seed_offset, **kw)
    b = evaluate(torch_pol, "box-v0", 4, 0, seed_offset=cfg.eval.seed_offset, **kw)
    assert list(a.success) == list(b.success) and a.success.sum() >= 1
    np.testing.assert_allclose(a.final_distance, b.final_distance, atol=1e-3)


def _flight(tmp_path, seeker, goal=(3.0, 0.0), safety=None, **drone_kw):
    cfg, _, path = seeker
    pol = OnnxPolicy(path)
    drone = SimulatedDrone(cfg.env, layout=EMPTY, start=(0.0, 0.0, 0.0), goal=goal, **{**INSTANT, **drone_kw})
    cam, mocap = drone.camera(), drone.mocap()
    # The arena, not the first-flight profile's fence: these flights test the other rules.
    safety = safety or Safety(max_speed=None, max_yaw_rate=None, geofence=(-8.0, 8.0, -8.0, 8.0))
    loop = ControlLoop(pol, drone, cam, mocap, goal, safety=safety, log_path=tmp_path / "flight.csv", camera=(32, 3))
    return loop, drone, cam, mocap


def test_simulated_flight_arrives_and_logs(tmp_path, seeker):
    loop, drone, _, _ = _flight(tmp_path, seeker)
    try:
        res = loop.fly()
    finally:
        drone.close()
    assert res.reason == "arrived" and res.success and res.final_distance <= 0.5
    assert not drone.flying and drone.landed_at is not None and not drone.crashed
    rows = (tmp_path / "flight.csv").read_text().splitlines()
    assert rows[0].startswith("t,tick,x,y") and rows[-1].endswith(",land") and len(rows) == res.ticks + 3
    lat = np.array([float(r.split(",")[11]) for r in rows[1:-2]])
    # The column holds each decision's measured latency; how long it is, is `python -m omcrl.bench deploy`'s
    # business (against the control period), not a unit test's, whose timing depends on the host's load.
    assert len(lat) == res.ticks and np.isfinite(lat).all() and (lat > 0).all()
    # The log replays: per tick the state vector and the policy's raw action beside the command sent.
    import pandas as pd

    log = pd.read_csv(tmp_path / "flight.csv")
    ticks = log[log.event.isna()]
    assert ticks[[f"state_{i}" for i in range(12)] + ["act_vx", "act_vy", "act_wz"]].notna().all().all()
    assert (ticks.frame_age >= 0).all() and (ticks.frame_age < 0.4).all()
    from omcrl.__main__ import main as cli

    assert cli(["replay", str(tmp_path / "flight.csv")]) == 0
    png = (tmp_path / "flight.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    assert cli(["replay", str(tmp_path / "nope.csv")]) == 1


@pytest.mark.parametrize("what", ["video", "pose"])
def test_lost_stream_lands_within_half_a_second(tmp_path, seeker, what):
    loop, drone, cam, mocap = _flight(tmp_path, seeker, goal=(6.0, 0.0))
    cut = time.monotonic() + 1.0
    (cam if what == "video" else mocap).cut(at=cut)
    try:
        res = loop.fly()
    finally:
        drone.close()
    assert res.reason == f"{what}_lost"
    assert 0.0 <= drone.landed_at - cut <= 0.5  # stale after 0.4 s, watched every 20 ms


def test_geofence_and_model_mismatch(tmp_path, seeker):
    loop, drone, _, _ = _flight(tmp_path, seeker, goal=(5.0, 0.0), safety=Safety(geofence=(-1.0, 1.5, -1.0, 1.0)))
    assert "goal (5.00, 0.00) m outside the geofence" in loop.preflight()  # refused before takeoff ...
    loop.preflight = lambda: None  # ... so, to test the fence in flight, skip that check
    try:
        res = loop.fly()
    finally:
        drone.close()
    assert res.reason == "geofence" and 1.5 < drone.pose[0] < 1.8
    # A model that does not match the camera is refused before takeoff.
    with pytest.raises(ModelSpecError, match="frame_stack configured 4"):
        ControlLoop(loop.policy, drone, None, None, (1.0, 0.0), camera=(32, 4))


def test_sigint_lands(tmp_path, seeker):
    # Also when SIGINT was inherited as ignored (a program started in the background by a non-interactive
    # shell): the flight installs Python's handler for its duration and restores the previous one after.
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        _sigint_flight(tmp_path, seeker)
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


def _sigint_flight(tmp_path, seeker):
    loop, drone, _, _ = _flight(tmp_path, seeker, goal=(7.0, 0.0))
    timer = threading.Timer(0.8, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        res = loop.fly()
    finally:
        timer.cancel()
        drone.close()
    assert res.reason == "interrupted" and drone.landed_at is not None and res.ticks >= 3, res


# djitellopy binds its command and state ports (8889, 8890) once per process and never releases them, so a test
# that flies through it runs in a child process: the pytest process must leave those ports free for the
# notebook chain's kernel (notebook 09 flies the fake Tello too).
IN_CHILD = os.environ.get("OMCRL_DJITELLOPY_CHILD") == "1"
child_only = pytest.mark.skipif(not IN_CHILD, reason="runs in a child process (see _in_child)")


def _in_child(repo_root, test: str) -> None:
    import subprocess
    import sys

    env = {**os.environ, "OMCRL_DJITELLOPY_CHILD": "1"}
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"{__file__}::{test}"],
                       cwd=repo_root, capture_output=True, text=True, env=env, timeout=600)  # fmt: skip
    assert r.returncode == 0 and re.search(r"^1 passed", r.stdout, re.M), r.stdout[-4000:] + r.stderr[-2000:]


def test_djitellopy_against_the_loopback_fake_tello(repo_root):
    """Every rule through the real djitellopy client (in a child process): arrival, video cut, pose cut,
    geofence, Ctrl-C."""
    _in_child(repo_root, "test_child_djitellopy_against_the_loopback_fake_tello")


def test_an_unacknowledged_land_falls_back_to_the_emergency_stop(repo_root):
    """Through djitellopy (in a child process): a drone that never answers `land` gets `emergency`."""
    _in_child(repo_root, "test_child_an_unacknowledged_land_falls_back_to_the_emergency_stop")


@child_only
@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_child_djitellopy_against_the_loopback_fake_tello(tmp_path, seeker):
    """Every rule through the real djitellopy client: arrival, video cut, pose cut, geofence, Ctrl-C."""
    from omcrl.deploy.tello import FakeTello, TelloDrone

    cfg, _, path = seeker
    pol = OnnxPolicy(path)
    scenarios = {
        "arrived": ((3.0, 0.0), None),
        "video_lost": ((6.0, 0.0), "video"),
        "pose_lost": ((6.0, 0.0), "pose"),
        "geofence": ((6.0, 0.0), "fence"),
        "interrupted": ((6.0, 0.0), "sigint"),
    }
    from omcrl.deploy.camera import TELLO

    for k, (expected, (goal, event)) in enumerate(scenarios.items()):
        # The fake streams what a Tello-geometry camera sees (4:3, 82.6° diagonal; 240 × 180 to keep it light).
        sim = SimulatedDrone(
            cfg.env, layout=EMPTY, start=(0.0, 0.0, 0.0), goal=goal, camera=TELLO.scaled(240, 180), **INSTANT
        )
        fake = FakeTello(sim, speed_at_100=cfg.env.max_speed, yaw_rate_at_100=cfg.env.max_yaw_rate)
        # A video port per session, asked for with the SDK's port command (djitellopy keeps the last one).
        port = 11200 + k
        tello = TelloDrone("127.0.0.1", fake.command_port, cfg.env.max_speed, cfg.env.max_yaw_rate, video_port=port)
        timer = None
        try:
            tello.connect()
            video = tello.video()
            deadline = time.monotonic() + 10.0
            while video.read() is None and time.monotonic() < deadline:  # the decoder needs a keyframe
                time.sleep(0.05)
            assert video.read() is not None, "no H.264 frame decoded from the fake Tello"
            assert video.read()[0].shape == (180, 240, 3)
            mocap = sim.mocap()
            fence = (-1.0, 1.5, -1.0, 1.0) if event == "fence" else (-8.0, 8.0, -8.0, 8.0)
            safety = Safety(max_speed=None, max_yaw_rate=None, geofence=fence)
            loop = ControlLoop(pol, tello, video, mocap, goal, safety=safety, camera=(32, 3))
            if event == "fence":
                loop.preflight = lambda: None  # the goal lies beyond this fence: test the crossing in flight
            cut = time.monotonic() + 1.0
            action = {"video": fake.cut_video, "pose": mocap.cut, "sigint": lambda: os.kill(os.getpid(), signal.SIGINT)}
            if event in action:
                timer = threading.Timer(1.0, action[event])
                timer.start()
            res = loop.fly()
            assert res.reason == expected, (expected, res)
            assert "takeoff" in fake.received and fake.received[-1] == "land" and fake.video_port == port
            assert any(c.startswith("rc ") for c in fake.received)
            if event in ("video", "pose"):
                # stale after 0.5 s, seen at the next tick; the land command then crosses the loopback
                assert sim.landed_at - cut <= 0.5, sim.landed_at - cut
            if expected == "arrived":
                assert res.final_distance <= 0.5
            if event == "fence":
                assert 1.5 < sim.pose[0] < 1.9
        finally:
            if timer is not None:
                timer.cancel()
            tello.close()
            fake.close()
            sim.close()


def test_cli_export(tmp_path, seeker, repo_root):
    import subprocess
    import sys

    _, run, _ = seeker
    out = tmp_path / "cli.onnx"
    r = subprocess.run(
        [sys.executable, "-m", "omcrl", "export", "--policy", str(run), "--out", str(out)],
        cwd=repo_root,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert OnnxPolicy(out).spec["method"] == "seeker"
    r = subprocess.run(
        [sys.executable, "-m", "omcrl", "export", "--policy", str(tmp_path / "missing")],
        cwd=repo_root,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 1 and "does not exist" in r.stderr and "Traceback" not in r.stderr


class _Policy:
    """A stand-in with an exported model's interface, for the loop's own rules (no network involved)."""

    spec = {"image_size": 8, "frame_stack": 2, "action_scale": {"max_speed": 1.5, "max_yaw_rate": 1.5},
            "control_hz": 50.0, "state_layout": list(range(12))}  # fmt: skip

    def check(self, image_size, frame_stack):
        pass

    def run(self, rgb, state):
        return np.ones((1, 3), np.float32)  # full speed ahead, left and turning


class _Drone:
    def __init__(self, fail_after=None):
        self.sent, self.landed, self.fail_after = [], 0, fail_after

    def takeoff(self):
        pass

    def send_velocity(self, vx, vy, wz):
        if self.fail_after is not None and len(self.sent) >= self.fail_after and (vx, vy, wz) != (0.0, 0.0, 0.0):
            raise OSError("radio link lost")
        self.sent.append((vx, vy, wz))

    def land(self):
        self.landed += 1


class _Source:
    def __init__(self, value):
        self.value = value

    def read(self):
        return self.value, time.monotonic()


def test_commands_are_clamped_and_rate_limited_and_an_exception_lands():
    frame = _Source(np.zeros((8, 8, 3), np.uint8))
    pose = _Source(np.zeros(6))
    safety = Safety(max_speed=0.5, max_yaw_rate=0.8, max_accel=1.0, max_yaw_accel=2.0, max_time_s=0.3,
                    geofence=(-8.0, 8.0, -8.0, 8.0))  # fmt: skip
    drone = _Drone()
    res = ControlLoop(_Policy(), drone, frame, pose, (5.0, 0.0), safety=safety).fly()
    assert res.reason == "timeout" and drone.landed == 1
    cmds = np.array(drone.sent[:-1])  # the last one is the stop before landing
    assert cmds[:, :2].max() <= 0.5 + 1e-9 and cmds[:, 2].max() <= 0.8 + 1e-9  # clamped
    steps = np.abs(np.diff(np.vstack([np.zeros(3), cmds]), axis=0))
    assert steps[:, :2].max() <= 1.0 / 50 + 1e-9 and steps[:, 2].max() <= 2.0 / 50 + 1e-9  # rate-limited
    assert drone.sent[-1] == (0.0, 0.0, 0.0)
    # Any exception in flight: the drone is stopped and landed, and the error is reported.
    drone = _Drone(fail_after=3)
    res = ControlLoop(_Policy(), drone, frame, pose, (5.0, 0.0), safety=safety).fly()
    assert res.reason == "error" and "radio link lost" in res.error and drone.landed == 1


@child_only
def test_child_an_unacknowledged_land_falls_back_to_the_emergency_stop(seeker):
    """Through djitellopy: a drone that never answers `land` gets `emergency` (motors cut) within the bound."""
    from omcrl.deploy.tello import FakeTello, TelloDrone

    cfg, _, _ = seeker
    sim = SimulatedDrone(cfg.env, layout=EMPTY, start=(0.0, 0.0, 0.0), goal=(3.0, 0.0), **INSTANT)
    fake = FakeTello(sim, acknowledge_land=False)
    tello = TelloDrone("127.0.0.1", fake.command_port, video_port=11250)
    try:
        tello.connect(video=False)
        tello.takeoff()
        t0 = time.monotonic()
        with pytest.raises(RuntimeError, match="land not acknowledged within 1 s.*motors cut"):
            tello.land(timeout_s=1.0)
        assert time.monotonic() - t0 <= 2.5
        deadline = time.monotonic() + 2.0  # djitellopy sends `emergency` without waiting for the reply
        while not sim.motors_cut and time.monotonic() < deadline:
            time.sleep(0.01)
        assert fake.received[-1] == "emergency" and sim.motors_cut and not sim.flying
    finally:
        tello.close()
        fake.close()
        sim.close()


_LOOP_PROCESS = """
import sys, time
from omcrl.deploy.loop import ControlLoop

class Drone:
    def watchdog_address(self):
        return "127.0.0.1", int(sys.argv[1])

class Policy:
    spec = {"image_size": 8, "frame_stack": 2, "action_scale": {"max_speed": 1.0, "max_yaw_rate": 1.0},
            "control_hz": 10.0}

import socket
loop = ControlLoop(Policy(), Drone(), None, None, (0.0, 0.0), watchdog=sys.argv[2] == "1")
dog = loop._start_watchdog()
rc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
print("flying", flush=True)
while True:  # each tick: a command to the drone and the heartbeat to the watchdog, until kill -9
    rc.sendto(b"rc 0 0 0 0", ("127.0.0.1", int(sys.argv[1])))
    if dog is not None:
        dog.stdin.write(b"."); dog.stdin.flush()
    time.sleep(0.1)
"""


@pytest.mark.parametrize("watchdog", [True, False])
def test_kill_minus_nine_of_the_loop_lands_the_drone(seeker, repo_root, watchdog):
    """kill -9 of the control process: the watchdog process sends `land` (well under a second, measured on the
    fake drone's side); without it, only the Tello's own auto-land after its timeout (here 2 s, 15 s on a Tello)."""
    import subprocess
    import sys

    from omcrl.deploy.tello import FakeTello

    cfg, _, _ = seeker
    sim = SimulatedDrone(cfg.env, layout=EMPTY, start=(0.0, 0.0, 0.0), goal=(3.0, 0.0), **INSTANT)
    fake = FakeTello(sim, auto_land_s=2.0)
    args = [sys.executable, "-c", _LOOP_PROCESS, str(fake.command_port), "1" if watchdog else "0"]
    proc = subprocess.Popen(args, cwd=repo_root, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "flying"
        sim.takeoff()
        time.sleep(0.5)
        assert sim.flying and "land" not in fake.received
        killed = time.monotonic()
        proc.kill()
        proc.wait(10)
        deadline = killed + 5.0
        while sim.flying and time.monotonic() < deadline:
            time.sleep(0.01)
        delay = sim.landed_at - killed
        print(f"[kill -9] watchdog={watchdog}: landed {delay:.3f} s after the kill")
        if watchdog:
            assert "land" in fake.received and not fake.auto_landed and delay <= 1.0, delay
        else:
            assert fake.auto_landed and "land" not in fake.received and 1.5 <= delay <= 3.0, delay
    finally:
        if proc.poll() is None:
            proc.kill()
        fake.close()
        sim.close()
