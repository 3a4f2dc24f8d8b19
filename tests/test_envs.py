"""NavEnv contract: spaces, sensors, termination, determinism, memory, bad input; planners."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from omcrl.config import ConfigError
from omcrl.envs import SCENES, make_env, make_vec_env
from omcrl.planners import HybridAPF, build_grid, shortest_path
from omcrl.scenes.geometry import Geometry, Primitive

WALL = {"kind": "box", "position": (3.0, 0.0), "size": (0.2, 6.0, 3.0), "color": (0.8, 0.2, 0.2)}


def _run(env, action, n):
    out = None
    for _ in range(n):
        out = env.step(np.asarray(action, np.float32))
        if out[2] or out[3]:
            break
    return out


@pytest.mark.parametrize("scene", SCENES)
def test_check_env_passes(scene):
    env = make_env(scene, seed=3, image_size=32)
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=4)
    assert obs["rgb"].shape == (3, 3, 32, 32) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].shape == (3, 32, 32) and obs["depth"].dtype == np.float32
    assert obs["state"].shape == (12,) and obs["privileged"].shape == (6,)
    # Reset places start and goal free, reachable, at the configured distance.
    d = np.linalg.norm(info["goal"] - info["pose"][:2])
    lo, hi = env.cfg.goal_distance
    assert lo - 0.2 <= d <= hi + 0.2
    assert math.isfinite(info["optimal_path_length"]) and info["optimal_path_length"] >= d - 1e-6
    env.close()


@pytest.mark.parametrize("d", [1.0, 2.5, 4.0])
def test_depth_matches_wall_distance(d):
    wall = dict(WALL, position=(d + 0.1, 0.0))  # wall face (half thickness 0.1 m) at x = d
    env = make_env("box", seed=0, image_size=64, layout=[wall], goal_distance=(0.5, 10.0))
    obs, _ = env.reset(options={"start": (0.0, 0.0, 0.0), "goal": (-2.0, 0.0)})
    centre = obs["depth"][-1, 31:33, 31:33].mean()
    assert abs(centre - d) / d < 0.02, (centre, d)
    # The privileged nearest-obstacle vector points straight ahead at the same distance.
    assert np.allclose(obs["privileged"][:3], [d, 0.0, 0.0], atol=1e-4)
    env.close()


def test_collision_ends_episode():
    env = make_env("box", seed=0, image_size=32, layout=[WALL], goal_distance=(0.5, 10.0))
    env.reset(options={"start": (0.0, 0.0, 0.0), "goal": (-3.0, 0.0)})
    _obs, r, term, trunc, info = _run(env, [1, 0, 0], 200)
    m = info["metrics"]
    assert term and not trunc and m["collision"] and not m["success"] and not m["out_of_arena"]
    assert r < -0.9  # -1 collision + small progress and step terms
    assert m["final_distance"] > 2.5 and m["steps"] > 10
    # Contact is detected on the first (sub)step whose sphere touches the wall face at x = 2.9.
    contact = 2.9 - env.cfg.drone_radius
    assert contact - 1e-9 <= info["pose"][0] < contact + env.cfg.max_speed / env.cfg.control_hz
    env.close()


def test_success_ends_episode_with_goal_reward():
    env = make_env("box", seed=0, image_size=32, layout=[], goal_distance=(0.5, 10.0))
    _, info = env.reset(options={"start": (0.0, 0.0, 0.0), "goal": (2.0, 0.0)})
    assert info["optimal_path_length"] == pytest.approx(2.0)  # empty arena: the straight line
    _obs, r, term, trunc, info = _run(env, [0.5, 0, 0], 200)
    m = info["metrics"]
    assert term and not trunc and m["success"] and not m["collision"]
    assert m["final_distance"] <= env.cfg.goal_radius
    assert r > 9.9
    assert m["path_length"] == pytest.approx(2.0 - m["final_distance"], abs=0.05)
    assert m["optimal_path_length"] == pytest.approx(2.0)
    env.close()


def test_leaving_arena_ends_episode():
    env = make_env("box", seed=0, image_size=32, layout=[], goal_distance=(0.5, 15.0))
    a = env.cfg.arena_half
    env.reset(options={"start": (a - 1.0, 0.0, 0.0), "goal": (0.0, 0.0)})
    _obs, r, term, _trunc, info = _run(env, [1, 0, 0], 100)
    m = info["metrics"]
    assert term and m["out_of_arena"] and not m["collision"] and not m["success"]
    assert r < -0.9
    env.close()


def test_truncation_at_max_steps():
    env = make_env("box", seed=0, image_size=32, layout=[], max_steps=7, goal_distance=(0.5, 10.0))
    env.reset(options={"start": (0.0, 0.0, 0.0), "goal": (3.0, 0.0)})
    for i in range(7):
        _obs, r, term, trunc, info = env.step(np.zeros(3, np.float32))
        assert not term
        assert trunc == (i == 6)
        assert r == pytest.approx(-1.0 / 7)  # no progress, step penalty -1/H_max
    assert info["metrics"]["steps"] == 7 and not info["metrics"]["success"]
    env.close()


def test_literal_progress_option():
    env = make_env("box", seed=0, image_size=32, layout=[], progress="literal", goal_distance=(0.5, 10.0))
    env.reset(options={"start": (0.0, 0.0, 0.0), "goal": (3.0, 0.0)})
    rs = [env.step(np.array([1, 0, 0], np.float32))[1] for _ in range(3)]
    # 0.1 (d_init - d_t) grows as the drone closes in; the difference form would stay near-constant.
    assert rs[0] < rs[1] < rs[2]
    env.close()


def _rollout(seed, n=200):
    env = make_env("furniture", seed=seed, image_size=32)
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(0)
    frames, rewards = [obs["rgb"].copy()], []
    for _ in range(n):
        obs, r, term, trunc, info = env.step(rng.uniform(-0.3, 0.6, 3).astype(np.float32))
        frames.append(obs["rgb"].copy())
        rewards.append(r)
        if term or trunc:
            obs, _info = env.reset()
    prims = [(p.kind, p.center, p.size) for p in env.primitives]
    env.close()
    return np.stack(frames), np.array(rewards), prims


def test_same_seed_same_episode_different_seed_differs():
    f1, r1, p1 = _rollout(11)
    f2, r2, p2 = _rollout(11)
    f3, _r3, p3 = _rollout(12)
    assert p1 == p2 and np.array_equal(f1, f2) and np.array_equal(r1, r2)
    assert p1 != p3 and not np.array_equal(f1, f3)


def test_layout_is_deterministic_per_seed_for_every_scene():
    for scene in SCENES:
        a = make_env(scene, seed=5, image_size=16)
        b = make_env(scene, seed=5, image_size=16)
        oa, ia = a.reset(seed=5)
        ob, ib = b.reset(seed=5)
        assert np.array_equal(oa["rgb"], ob["rgb"]) and np.array_equal(ia["pose"], ib["pose"])
        a.close()
        b.close()


def test_resets_do_not_leak_memory():
    psutil = pytest.importorskip("psutil")
    env = make_env("box", seed=0, image_size=32)
    for _ in range(30):  # warm-up: allocator pools, texture cache
        env.reset()
    rss0 = psutil.Process().memory_info().rss
    for _ in range(300):
        env.reset()
    grown = (psutil.Process().memory_info().rss - rss0) / 2**20
    env.close()
    # 1000 resets must stay under 50 MB (the slow test below); 300 here must stay well under a third.
    assert grown < 15, f"RSS grew {grown:.1f} MB over 300 resets"


@pytest.mark.slow
def test_thousand_resets_memory():
    psutil = pytest.importorskip("psutil")
    env = make_env("tree", seed=0, image_size=64)
    for _ in range(20):
        env.reset()
    rss0 = psutil.Process().memory_info().rss
    for _ in range(1000):
        env.reset()
    grown = (psutil.Process().memory_info().rss - rss0) / 2**20
    env.close()
    print(f"RSS growth over 1000 tree resets: {grown:.1f} MB")
    assert grown < 50


def test_bad_input_gets_clear_errors():
    with pytest.raises(ConfigError, match="scene"):
        make_env("moon")
    with pytest.raises(ConfigError, match="image_size.*8"):
        make_env("box", image_size=8)
    with pytest.raises(ConfigError, match="frame_stack.*0"):
        make_env("box", frame_stack=0)
    env = make_env("box", seed=0, image_size=32, layout=[WALL], goal_distance=(0.5, 10.0))
    with pytest.raises(ValueError, match="start.*obstacle"):
        env.reset(options={"start": (3.0, 0.0, 0.0), "goal": (-3.0, 0.0)})
    with pytest.raises(ValueError, match="outside the arena"):
        env.reset(options={"start": (30.0, 0.0), "goal": (-3.0, 0.0)})
    env.reset(options={"start": (0.0, 0.0, 0.0), "goal": (-3.0, 0.0)})
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan, 0, 0], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(2, np.float32))
    with pytest.raises(ValueError, match="layout\\[0\\]"):
        make_env("box", layout=[{"kind": "cone", "position": (0, 0), "size": (1,)}])
    env.close()


def test_out_of_range_actions_are_clipped():
    poses = []
    for a in ([1.0, -1.0, 1.0], [7.0, -3.0, 42.0]):
        env = make_env("box", seed=0, image_size=16, layout=[], goal_distance=(0.5, 10.0))
        env.reset(options={"start": (0.0, 0.0, 0.0), "goal": (-3.0, 0.0)})
        for _ in range(5):
            _, _, _, _, info = env.step(np.array(a, np.float32))
        poses.append(info["pose"])
        env.close()
    assert np.allclose(poses[0], poses[1])


def test_velocity_response_is_first_order_and_limited():
    env = make_env("box", seed=0, image_size=16, layout=[], goal_distance=(0.5, 10.0))
    env.reset(options={"start": (0.0, 0.0, 0.0), "goal": (-3.0, 0.0)})
    speeds = []
    for _ in range(15):
        obs, *_ = env.step(np.array([1, 0, 0], np.float32))
        speeds.append(obs["state"][0])
    c = env.cfg
    assert np.all(np.diff(speeds) >= -1e-9) and speeds[-1] == pytest.approx(c.max_speed, rel=0.02)
    assert speeds[0] <= c.max_accel / c.control_hz + 1e-6  # acceleration limit in the first step
    env.close()


def test_disturbance_changes_images_not_geometry():
    base = make_env("box", seed=1, image_size=32)
    dist = make_env(
        "box",
        seed=1,
        image_size=32,
        disturbance={"obstacle_colors": "random", "hue": 60, "brightness": 0.6, "switch_step": 1},
    )
    ob, ib = base.reset(seed=2)
    od, idd = dist.reset(seed=2)
    assert np.array_equal(ib["pose"], idd["pose"])
    assert not np.array_equal(ob["rgb"], od["rgb"])
    assert ob["rgb"].mean() > od["rgb"].mean()
    np.testing.assert_allclose(ob["depth"], od["depth"], atol=1e-4)
    with pytest.raises(ConfigError, match="unknown"):
        make_env("box", disturbance={"glitter": 1})
    base.close()
    dist.close()


def test_vector_env_seeds_workers_differently():
    venv = make_vec_env("box", 2, seed=3, image_size=16)
    obs, info = venv.reset(seed=3)
    assert obs["rgb"].shape == (2, 3, 3, 16, 16)
    assert not np.array_equal(info["pose"][0], info["pose"][1])
    for _ in range(3):
        obs, r, _term, _trunc, info = venv.step(np.zeros((2, 3), np.float32))
    assert r.shape == (2,)
    venv.close()


def test_geometry_distances():
    g = Geometry.from_primitives(
        [
            Primitive("box", (0, 0, 1), (1, 0.5, 1), yaw=math.pi / 2),
            Primitive("cylinder", (5, 0, 1), (0.5, 0.5, 1)),
            Primitive("sphere", (0, 5, 1), (1, 1, 1)),
        ]
    )
    pts = np.array([[0, 2, 1], [2, 0, 1], [5, 2, 1], [0, 7, 1], [5, 0, 3]], float)
    _, d = g.closest(pts)
    # Rotated box: half extents (1, 0.5) become (0.5, 1) in the world.
    np.testing.assert_allclose(d, [1.0, 1.5, 1.5, 1.0, 1.0], atol=1e-9)


@pytest.mark.parametrize("scene", SCENES)
def test_single_point_nearest_equals_batched_closest(scene):
    """The env's per-step ``nearest`` gives the same surface point and distance as ``closest``."""
    env = make_env(scene, seed=2, image_size=16)
    env.reset(seed=2)
    geo = env.geometry
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.uniform(-9, 9, (300, 3)) * [1, 1, 0.3] + [0, 0, 1], [[0, 0, env.cfg.altitude]]])
    cp, cd = geo.closest(pts)
    for p, q, d in zip(pts, cp, cd):
        np_, nd = geo.nearest(p)
        assert nd == pytest.approx(d, abs=1e-9)
        np.testing.assert_allclose(np_, q, atol=1e-9)
    env.close()
    empty = Geometry.from_primitives([])
    assert empty.nearest(np.zeros(3))[1] == math.inf


def test_shortest_path_goes_around_a_wall():
    wall = Primitive("box", (0, 0, 1), (0.1, 2.0, 1.5))
    grid = build_grid(Geometry.from_primitives([wall]), 5.0, 1.0, 0.05, 0.15)
    path, length = shortest_path(grid, np.array([-2.0, 0.0]), np.array([2.0, 0.0]))
    # Around the wall end (y = 2 + 0.15 inflation): two straight legs of ~sqrt(2^2 + 2.15^2) m each.
    ideal = 2 * math.hypot(1.9, 2.15) + 0.2
    assert ideal - 0.05 < length < ideal + 0.25
    assert all(grid.line_of_sight(a, b) for a, b in itertools.pairwise(path))
    empty = build_grid(Geometry(), 5.0, 1.0, 0.1, 0.15)
    assert shortest_path(empty, np.array([-3.0, -3.0]), np.array([3.0, 2.0]))[1] == pytest.approx(math.hypot(6, 5))


def test_hybrid_apf_succeeds_in_box():
    env = make_env("box", seed=0, image_size=16)
    pol = HybridAPF(env.cfg)
    successes = 0
    n = 50
    for ep in range(n):
        obs, info = env.reset(seed=10_000 + ep)
        while True:
            obs, _r, term, trunc, info = env.step(pol.act(obs, info))
            if term or trunc:
                successes += info["metrics"]["success"]
                break
    env.close()
    assert successes / n >= 0.85, f"HybridAPF success {successes}/{n}"


@pytest.mark.parametrize("layout_every", [1, 3])
def test_prefetched_reset_equals_plain_reset(layout_every):
    """A reset planned ahead (``prefetch``) gives exactly the episode a plain reset gives; a seeded reset
    discards the plan."""
    kw = dict(image_size=16, max_steps=5, layout_every=layout_every)
    a, b = make_env("box", seed=4, **kw), make_env("box", seed=4, **kw)
    a.reset(seed=4)
    b.reset(seed=4)
    plans = []
    plan = a.episodes.plan
    a.episodes.plan = lambda *args, **kw: plans.append(1) or plan(*args, **kw)
    for ep in range(6):
        assert a.prefetch() and not a.prefetch()  # one plan at a time
        _run(a, [0.3, 0, 0], 5)
        _run(b, [0.3, 0, 0], 5)
        n = len(plans)
        if ep == 4:  # a seeded reset ignores the plan
            oa, ia = a.reset(seed=99)
            ob, ib = b.reset(seed=99)
            assert len(plans) == n + 1
        else:
            oa, ia = a.reset()
            ob, ib = b.reset()
            assert len(plans) == n  # the prefetched plan was used
        assert all(np.array_equal(oa[k], ob[k]) for k in oa)
        assert ia["layout_seed"] == ib["layout_seed"] and ia["path"] == ib["path"]
        assert a.np_random.bit_generator.state == b.np_random.bit_generator.state
    a.close()
    b.close()


def test_split_vector_env_reports_bad_input_worker_errors_and_deaths():
    venv = make_vec_env("box", 2, seed=0, image_size=16)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions of shape \(3,\), expected \(2, 3\)"):
        venv.step(np.zeros(3, np.float32))
    bad = np.zeros((2, 3), np.float32)
    bad[1, 0] = np.nan  # env 1 lives in the worker: its error comes back with the worker's traceback
    with pytest.raises(ValueError, match="NaN") as err:
        venv.step(bad)
    assert any("vector env worker 1" in n for n in getattr(err.value, "__notes__", []))
    obs, *_ = venv.step(np.zeros((2, 3), np.float32))  # still usable afterwards
    assert obs["rgb"].shape[0] == 2
    venv._procs[0].kill()
    venv._procs[0].join()
    with pytest.raises(RuntimeError, match="worker 1 died"):
        venv.step(np.zeros((2, 3), np.float32))
    venv.close()


def test_split_vector_env_matches_sync_vector_env():
    """Env 0 in-process + workers gives exactly SyncVectorEnv's observations, rewards, flags and infos."""
    a = make_vec_env("box", 3, seed=5, image_size=16, max_steps=25)
    b = make_vec_env("box", 3, seed=5, image_size=16, max_steps=25, asynchronous=False)
    oa, _ = a.reset(seed=5)
    ob, _ = b.reset(seed=5)
    assert all(np.array_equal(oa[k], ob[k]) for k in oa)
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(80):
        act = rng.uniform(-1, 1, (3, 3)).astype(np.float32)
        ra, rb = a.step(act), b.step(act)
        assert all(np.array_equal(ra[0][k], rb[0][k]) for k in rb[0])
        assert all(np.array_equal(x, y) for x, y in zip(ra[1:4], rb[1:4]))
        assert set(ra[4]) == set(rb[4])
        if "metrics" in rb[4]:
            m = rb[4]["_metrics"]
            ends += int(m.sum())
            assert np.array_equal(ra[4]["_metrics"], m)
            for k in rb[4]["metrics"]:
                assert np.array_equal(np.asarray(ra[4]["metrics"][k])[m], np.asarray(rb[4]["metrics"][k])[m])
    assert ends >= 3  # truncation at 25 steps guarantees episode ends in every env
    a.close()
    b.close()


def test_renderers_agree_on_size_and_depth_in_metres():
    import torch

    from omcrl.config import EnvConfig
    from omcrl.envs.render import RendererError, env_identity, resolve_renderer

    def frames(renderer, n=3):
        env = make_env("box", seed=3, renderer=renderer)
        try:
            obs, _ = env.reset(seed=3)
            out = [obs]
            for _ in range(n):
                obs, *_ = env.step(np.array([0.4, 0.0, 0.2], np.float32))
                out.append(obs)
            return env.renderer, out
        finally:
            env.close()

    tiny_name, tiny = frames("tiny")
    auto_name, auto = frames("auto")
    assert tiny_name == "tiny"
    # auto is TinyRenderer, pixel for pixel, on a machine without a CUDA GPU (CI); EGL on one where EGL renders.
    assert auto_name == resolve_renderer("auto")
    if not torch.cuda.is_available():
        assert auto_name == "tiny"
    if auto_name == "tiny":
        for a, b in zip(tiny, auto):
            assert np.array_equal(a["rgb"], b["rgb"]) and np.array_equal(a["depth"], b["depth"])
    # Run keys hold the resolved renderer: auto is the run of what it resolves to here, EGL another than tiny.
    assert env_identity(EnvConfig(renderer="auto")) == {"renderer": auto_name}
    assert env_identity(EnvConfig(renderer="tiny")) == {"renderer": "tiny"}
    assert env_identity(EnvConfig(renderer="egl"))["renderer"] == "egl"
    try:
        egl_name, egl = frames("egl")
    except RendererError as e:  # no EGL device at all: the error says what to use instead
        assert "tiny" in str(e)
        return
    assert egl_name == "egl"
    for a, b in zip(tiny, egl):
        assert a["rgb"].shape == b["rgb"].shape and a["depth"].shape == b["depth"].shape
        # Same scene, camera and z-buffer convention: depth agrees to a few per cent (rasterisers sample
        # pixels differently; measured median 1.6 %, so a wrong unit or convention fails by far).
        assert np.median(np.abs(a["depth"] - b["depth"]) / a["depth"]) < 0.03
        assert 0.0 < b["depth"].min() and b["depth"].max() <= 20.0


def test_unknown_renderer_is_refused():
    with pytest.raises(ConfigError, match="renderer"):
        make_env("box", seed=0, renderer="vulkan")


def test_a_subclass_changes_the_task_through_the_hooks():
    """The task is in ``_reward`` / ``_terminated`` / ``_truncated`` / ``_metrics``: a subclass with a sparse reward
    and no step limit flies the same dynamics and sees the same observations."""
    from omcrl.envs.nav_env import NavEnv

    class Sparse(NavEnv):
        def _reward(self, d, success, crashed):
            return float(success)

        def _truncated(self, terminated):
            return False

        def _metrics(self, d, success, collided, out):
            return {**super()._metrics(d, success, collided, out), "sparse": True}

    kw = {"scene": "box-v0", "seed": 0, "image_size": 32, "max_steps": 5}
    plain, sparse = NavEnv(**kw), Sparse(**kw)
    try:
        o1, _ = plain.reset(seed=3)
        o2, _ = sparse.reset(seed=3)
        a = np.array([0.2, 0.0, 0.1], np.float32)
        for _ in range(5):
            o1, r1, te1, tr1, i1 = plain.step(a)
            o2, r2, te2, tr2, i2 = sparse.step(a)
            np.testing.assert_array_equal(o1["rgb"], o2["rgb"])
            np.testing.assert_array_equal(i1["pose"], i2["pose"])
            assert r2 in (0.0, 1.0) and r1 != r2
        assert tr1 and not tr2 and i1["metrics"]["steps"] == 5
        assert "metrics" not in i2  # not truncated, so not ended
    finally:
        plain.close()
        sparse.close()


def test_the_flight_model_is_a_pure_step_of_one_drone_state():
    """omcrl.envs.dynamics: the env's drone is one DroneState and a control step is fly(state, command, model,
    geometry) -> next state; the state it was given is left as it was, and the env steps through it."""
    import numpy as np

    from omcrl.config import EnvConfig
    from omcrl.envs.dynamics import DroneState, FlightModel, fly
    from omcrl.scenes.geometry import Geometry

    cfg = EnvConfig()
    model = FlightModel.from_config(cfg)
    assert model.substeps >= 1 and model.max_speed * model.dt / model.substeps <= cfg.drone_radius + 1e-9
    start = DroneState(np.array([0.0, 0.0, cfg.altitude]), 0.0)
    state = start
    for _ in range(20):
        state, _, collided, out = fly(state, (1.0, 0.0, 0.0), model, Geometry())
        assert not (collided or out)
    assert start.pos.tolist() == [0.0, 0.0, cfg.altitude] and start.path_len == 0.0  # untouched
    assert state.pos[0] > 0.5 and abs(state.pos[1]) < 1e-12 and state.yaw == 0.0  # straight ahead along +x
    assert 0 < state.vel[0] <= cfg.max_speed and state.path_len == pytest.approx(state.pos[0])
    turned, *_ = fly(start, (0.0, 0.0, 1.0), model, Geometry())
    assert turned.yaw > 0 and turned.wz > 0 and turned.pos.tolist() == start.pos.tolist()


def test_the_env_keeps_its_drone_in_one_record():
    from omcrl.envs.dynamics import DroneState

    env = make_env("box", seed=0)
    try:
        env.reset(seed=3)
        before = env.unwrapped.drone
        assert isinstance(before, DroneState) and before.path_len == 0.0
        env.step(np.array([1.0, 0.0, 0.0], np.float32))
        after = env.unwrapped.drone
        assert after is not before and after.path_len > 0 and before.path_len == 0.0
        assert env.unwrapped.pose.tolist() == [after.pos[0], after.pos[1], after.yaw]
    finally:
        env.close()


def _reset_on_a_tile_edge(clearance_m: float | None, conn) -> None:
    """In a forked child: reset box-v2 at (6, 6) looking along -x (its camera plane holds the floor-tile edge x = 6 m)
    and send back whether the observation is finite ("finite", "nan" or the error)."""
    import omcrl.envs.nav_env as nav
    from omcrl.config import load_config

    if clearance_m is not None:
        nav.RENDER_PLANE_CLEARANCE_M = clearance_m
    corner = [{"kind": "box", "position": (-7.5, -7.5), "size": (0.2, 0.2, 0.2)}]
    env = nav.NavEnv("box-v2", config=load_config("quick").env, layout=corner)
    try:
        obs, _ = env.reset(seed=0, options={"start": (6.0, 6.0, math.pi), "goal": (3.0, 3.0)})
        conn.send("finite" if np.isfinite(obs["depth"]).all() else "nan")
    except RuntimeError as e:
        conn.send(f"error: {e}")
    finally:
        env.close()


def _in_fork(target, *args, timeout_s: float) -> str:
    """``target(*args, conn)`` in a forked process: what it sent, or "hung" when it did not end in ``timeout_s``."""
    import multiprocessing

    ctx = multiprocessing.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=target, args=(*args, send))
    proc.start()
    proc.join(timeout_s)
    if proc.is_alive():
        proc.kill()
        proc.join()
        return "hung"
    return recv.recv() if recv.poll() else f"exit code {proc.exitcode}"


def test_a_camera_looking_along_a_floor_tile_edge_is_rendered_and_returns():
    """At (6, 6) with yaw pi the camera's plane holds a row of floor-tile corners; TinyRenderer drawing from there
    may never return (measured: 29 of 120 axis-aligned poses within 1e-7 m of a tile edge hung). The env renders
    such a pose a millimetre forward instead: a finite frame, at once."""
    assert _in_fork(_reset_on_a_tile_edge, None, timeout_s=120) == "finite"
    # Without the clearance (as before the fix) the same reset does not come back: the fault is real.
    assert _in_fork(_reset_on_a_tile_edge, 0.0, timeout_s=10) == "hung"


def test_a_camera_right_above_a_floor_tile_corner_renders_finite_depth(monkeypatch):
    """The pose that gave seed 2's oracle a NaN action: at (-6, -6), a floor tile's corner right below the camera,
    TinyRenderer's depth holds NaN over that tile. The frame is rendered again a millimetre forward (finite), and a
    frame without the fault stays the one render from the pose itself."""
    from dataclasses import replace

    import pybullet as pb

    import omcrl.envs.nav_env as nav
    from omcrl.config import load_config

    corner = [{"kind": "box", "position": (7.5, 7.5), "size": (0.2, 0.2, 0.2)}]
    env = nav.NavEnv("box-v2", config=load_config("quick").env, layout=corner)
    try:
        env.reset(seed=0, options={"start": (-6.0, -6.0), "goal": (-3.0, -3.0)})
        env.drone = replace(env.drone, yaw=2.42118196)
        rgb, depth = env._render_frame()
        assert np.isfinite(depth).all() and depth.min() > 0.0
        assert (rgb.reshape(3, -1).max(0) > 0).mean() > 0.99  # no black patch where the tile was lost
        with monkeypatch.context() as m:  # the pose itself only, as before the fix: the fault is real
            m.setattr(nav, "RENDER_NUDGES_M", (0.0,))
            with pytest.raises(RuntimeError, match=r"pose \[-6\.0, -6\.0, 2\.4212\].*non-finite depth"):
                env._render_frame()
        env.drone = replace(env.drone, pos=np.array([-5.3, -4.1, env.drone.pos[2]]), yaw=0.7)
        rgb, depth = env._render_frame()
        S = env.cfg.image_size
        *_, rgba, zbuf, _ = pb.getCameraImage(
            S, S, env.view_matrix(), env._proj, renderer=env._pb_renderer, shadow=0,
            flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=env._client, **env._light(),
        )  # fmt: skip
        assert np.array_equal(rgb, np.asarray(rgba, np.uint8).reshape(S, S, 4)[..., :3].transpose(2, 0, 1))
    finally:
        env.close()
