"""Planners: the Hybrid APF (an expert on the true map) against NPE's non-expert guide, the local APF on the depth
camera, on a course built to trap a potential field; and the planners as the method registry flies them."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from omcrl.config import load_config
from omcrl.envs import make_env
from omcrl.eval.stage import _load
from omcrl.planners import GUIDES, PLANNERS, BlindPilot, HybridAPF, LocalAPF, PerceptiveHybridAPF, make_planner
from omcrl.rl.methods import METHODS

# A U-shaped pocket open towards the start, the goal behind its bottom wall: the straight line to the goal runs
# into the pocket, where attraction and repulsion cancel (the classical local minimum of potential fields).
POCKET = [
    {"kind": "box", "position": (1.0, 0.0), "size": (0.15, 1.6, 1.5)},  # bottom of the U, across the goal line
    {"kind": "box", "position": (0.0, 1.55), "size": (1.0, 0.15, 1.5)},  # its two arms, towards the start
    {"kind": "box", "position": (0.0, -1.55), "size": (1.0, 0.15, 1.5)},
]


def _fly(planner, env, options) -> dict:
    obs, info = env.reset(seed=0, options=options)
    planner.reset(info)
    while True:
        obs, _r, term, trunc, info = env.step(planner.act(obs, info))
        if term or trunc:
            return info["metrics"]


def test_the_expert_plans_around_a_pocket_the_local_field_gets_stuck_in():
    env = make_env("box", seed=0, image_size=32, layout=POCKET)
    # Off the pocket's symmetry axis: exactly on it, the Hybrid APF stalls too (its forces cancel; noted).
    options = {"start": (-2.5, 0.3, 0.0), "goal": (3.5, 0.0)}
    expert = _fly(HybridAPF(env.cfg).bind(env), env, options)
    local = _fly(LocalAPF(env.cfg), env, options)
    env.close()
    assert expert["success"], expert
    assert not local["success"], local  # no map, no memory: it never leaves the pocket
    assert local["final_distance"] > 1.5 and not local["collision"]


def test_every_planner_method_is_flown_by_its_recipe_and_cached_by_its_name():
    cfg = load_config("smoke")
    planners = {n: s for n, s in METHODS.items() if not s.learned}
    assert set(planners) == {"hybrid-apf", "hybrid-apf-perceptive"}
    kinds = {"hybrid-apf": HybridAPF, "hybrid-apf-perceptive": PerceptiveHybridAPF}
    for name, spec in planners.items():
        agent = spec.recipe.make_agent(cfg, spec)
        assert type(agent) is kinds[name] and spec.recipe.run(cfg, spec) is None
        with pytest.raises(Exception, match="is a planner: it is not trained"):
            spec.recipe.train(cfg, spec, [])
    assert type(make_planner("local-apf")) is LocalAPF and type(make_planner("HybridAPF")) is HybridAPF
    # One table of planners: every planner method and every planner guide of a student is in it.
    assert set(PLANNERS) >= set(planners) and {p for p, _ in GUIDES.values()} <= set(PLANNERS)
    assert {s.guide for s in METHODS.values() if s.guide not in (None, "oracle")} <= set(GUIDES)
    with pytest.raises(ValueError, match="unknown planner 'astar'.*'hybrid-apf'"):
        make_planner("astar")
    # An evaluation of a planner is cached under its name, with the planners' behaviour version beside it
    # (tests/test_identity.py: bumping it flies the planner again).
    _, key = _load("hybrid-apf", "hybrid-apf")
    assert key == "hybrid-apf"


def test_local_apf_uses_only_what_the_camera_sees():
    """The same pose and goal with an empty depth frame (nothing in sight) and with a wall just ahead: only the
    sensed wall changes the command; the true map (``info['path']``) is never read."""
    env = make_env("box", seed=0, image_size=32, layout=POCKET)
    obs, info = env.reset(seed=0, options={"start": (0.3, 0.0, 0.0), "goal": (3.0, 0.0)})
    planner = LocalAPF(env.cfg)
    planner.reset(info)
    near = planner.act(obs, {k: v for k, v in info.items() if k != "path"})
    far_obs = dict(obs, depth=np.full_like(obs["depth"], env.cfg.far))
    planner.reset(info)
    clear = planner.act(far_obs, {k: v for k, v in info.items() if k != "path"})
    env.close()
    assert clear[0] > near[0]  # it slows (or backs off) only for the wall it sees


def test_the_blind_pilot_flies_the_straight_line_and_senses_nothing():
    """Open line: it reaches the goal as the Hybrid APF would; a wall across the line: it flies into it. Its action
    never depends on the observation (depth, RGB, privileged vector)."""
    env = make_env("box-v0", seed=0, image_size=32, layout=[])
    clear = _fly(BlindPilot(env.cfg), env, {"start": (-3.0, 0.3, 0.0), "goal": (3.0, 0.3)})
    env.close()
    assert clear["success"] and clear["path_length"] == pytest.approx(6.0, abs=0.35)
    env = make_env("box-v0", seed=0, image_size=32, layout=POCKET)
    blocked = _fly(BlindPilot(env.cfg), env, {"start": (-2.5, 0.3, 0.0), "goal": (3.5, 0.0)})
    obs, info = env.reset(seed=0, options={"start": (0.3, 0.0, 0.0), "goal": (3.0, 0.0)})
    pilot = BlindPilot(env.cfg)
    pilot.reset(info)
    a = pilot.act(obs, info)
    pilot.reset(info)
    blank = {k: np.zeros_like(v) for k, v in obs.items()}
    np.testing.assert_array_equal(a, pilot.act(blank, info))
    env.close()
    assert blocked["collision"] and not blocked["success"]
    assert type(make_planner("blind")) is BlindPilot


def test_a_pilot_that_does_not_look_is_evaluated_without_frames_and_flies_the_same_episodes(monkeypatch):
    """HybridAPF and the blind pilot never read a frame, so evaluate() flies them in an env that renders none:
    row for row (trajectories too) what the rendering env gives. The pilots that look keep their frames."""
    import omcrl.envs.nav_env as nav
    from omcrl.eval.runner import evaluate

    for name in ("hybrid-apf", "blind"):
        fast = evaluate(make_planner(name), "barrier-v2", 3, 0, seed_offset=2_000_000)
        framed = evaluate(make_planner(name), "barrier-v2", 3, 0, seed_offset=2_000_000, make_env=nav.make_env)
        pd.testing.assert_frame_equal(fast, framed)
    env = make_env("barrier-v2", seed=0, camera=False)
    obs, _ = env.reset(seed=0)
    assert not obs["rgb"].any() and not obs["depth"].any()
    env.close()
    # Which env each pilot gets from evaluate()'s default: frames for those that look.
    built, real = {}, nav.make_env

    def noting(name):
        def make(*args, **kwargs):
            built[name] = kwargs.get("camera", True)
            return real(*args, **kwargs)

        return make

    for name in ("hybrid-apf", "blind", "local-apf", "hybrid-apf-perceptive"):
        monkeypatch.setattr(nav, "make_env", noting(name))
        evaluate(make_planner(name), "barrier-v2", 1, 0, seed_offset=2_000_000)
    assert built == {"hybrid-apf": False, "blind": False, "local-apf": True, "hybrid-apf-perceptive": True}
