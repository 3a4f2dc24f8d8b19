"""Episode metrics, tables and the evaluation runner (omcrl.eval)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
import torch

from omcrl.eval import EvalPool, eval_seeds, evaluate, format_table, summarize, summary_table

torch.set_num_threads(1)


def episodes() -> pd.DataFrame:
    # Four hand-made episodes: two successes (one on the optimal path, one with a 2x detour),
    # one near miss (within OS radius, then collided), one far timeout.
    return pd.DataFrame(
        {
            "final_distance": [0.2, 0.3, 0.6, 5.0],
            "min_distance": [0.2, 0.3, 0.4, 3.0],
            "success": [True, True, False, False],
            "collision": [False, False, True, False],
            "path_length": [10.0, 16.0, 7.0, 20.0],
            "optimal_path_length": [10.0, 8.0, 9.0, 12.0],
            "steps": [100, 150, 70, 400],
        }
    )


def test_summarize_matches_hand_computation():
    s = summarize(episodes())
    assert s["NE"] == pytest.approx((0.2 + 0.3 + 0.6 + 5.0) / 4)
    assert s["OS"] == pytest.approx(75.0)  # 0.2, 0.3, 0.4 <= 0.5
    assert s["SR"] == pytest.approx(50.0)
    assert s["SPL"] == pytest.approx((10 / 10 + 8 / 16 + 0 + 0) / 4)
    assert s["CR"] == pytest.approx(25.0)
    assert s["TTS"] == pytest.approx(125.0)  # successful episodes only
    assert s["episodes"] == 4
    # SPL uses max(d, ℓ): a path shorter than the "optimal" one cannot score above 1.
    short = episodes().assign(path_length=[5.0, 8.0, 7.0, 20.0])
    assert summarize(short)["SPL"] == pytest.approx((1.0 + 1.0) / 4)


def test_summarize_without_successes_gives_nan_tts():
    df = episodes().assign(success=False)
    s = summarize(df)
    assert math.isnan(s["TTS"])
    assert s["SR"] == 0.0 and s["SPL"] == 0.0
    with pytest.raises(KeyError, match="steps"):
        summarize(df.drop(columns="steps"))


def test_summary_table_groups_by_method_and_scene():
    a = episodes().assign(method="omc", scene="box")
    b = episodes().assign(method="omc", scene="tree", success=False)
    c = episodes().assign(method="ppo", scene="box")
    table = summary_table(pd.concat([a, b, c]))
    assert list(table.columns) == ["NE", "OS", "SR", "SPL", "CR", "TTS", "episodes"]
    assert table.loc[("omc", "box"), "SR"] == pytest.approx(50.0)
    assert math.isnan(table.loc[("omc", "tree"), "TTS"])
    wide = format_table(table)
    assert wide.loc["omc", ("tree", "TTS")] == "-"
    assert wide.loc["ppo", ("box", "SR")] == pytest.approx(50.0)


class LineEnv(gym.Env):
    """1-D corridor with the metrics contract: goal at x = 3 m, success within 0.3 m, 50-step limit."""

    observation_space = gym.spaces.Box(-10, 10, (1,), np.float32)
    action_space = gym.spaces.Box(-1, 1, (3,), np.float32)

    def __init__(self, scene: str, seed: int = 0) -> None:
        self.scene = scene

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.seed_, self.x, self.t, self.path, self.min_d = seed, 0.0, 0, 0.0, 3.0
        return np.array([3.0 - self.x], np.float32), {"pose": np.array([self.x, 0.0, 0.0])}

    def step(self, action):
        dx = 0.5 * float(np.clip(action[0], -1, 1))
        self.x += dx
        self.path += abs(dx)
        self.t += 1
        d = abs(3.0 - self.x)
        self.min_d = min(self.min_d, d)
        success, trunc = d <= 0.3, self.t >= 50
        info = {"pose": np.array([self.x, 0.0, 0.0])}
        if success or trunc:
            info["metrics"] = {
                "final_distance": d,
                "min_distance": self.min_d,
                "success": success,
                "collision": False,
                "path_length": self.path,
                "optimal_path_length": 3.0,
                "steps": self.t,
                "scene": self.scene,
                "seed": self.seed_,
            }
        return np.array([3.0 - self.x], np.float32), 0.0, success, trunc and not success, info


class GoRight:
    name, checkpoint = "go_right", "none"

    def __init__(self, speed: float) -> None:
        self.speed, self.resets = speed, 0

    def reset(self) -> None:
        self.resets += 1

    def act(self, obs, info):
        return np.array([self.speed, 0.0, 0.0], np.float32)


def test_evaluate_rows_seeds_and_trajectories():
    pol = GoRight(1.0)
    df = evaluate(pol, "box", episodes=3, seed=2, seed_offset=1_000_000, make_env=LineEnv)
    assert len(df) == 3 and pol.resets == 3
    assert list(df.eval_seed) == eval_seeds(3, 2, 1_000_000) == [1_000_006, 1_000_007, 1_000_008]
    assert (df.seed == df.eval_seed).all()
    assert (df.method == "go_right").all() and df.success.all()
    assert df.steps.iloc[0] == 6 and len(df.trajectory.iloc[0]) == 7
    assert df.trajectory.iloc[0][-1] == pytest.approx((3.0, 0.0))
    s = summarize(df)
    assert s["SR"] == 100.0 and s["SPL"] == pytest.approx(1.0) and s["TTS"] == 6.0
    stuck = summarize(evaluate(GoRight(0.0), "box", episodes=2, make_env=LineEnv))
    assert stuck["SR"] == 0.0 and math.isnan(stuck["TTS"]) and stuck["NE"] == pytest.approx(3.0)


def _smoke_student(tmp_path):
    from omcrl.config import load_config
    from omcrl.envs import make_env
    from omcrl.models import random_encoder, save_encoder
    from omcrl.models.actor_critic import ActorCritic
    from omcrl.rl.policy import Policy, make_student_features

    cfg = load_config("smoke")
    enc = random_encoder(cfg, seed=0)
    path = save_encoder(tmp_path / "encoder.pt", enc.f, enc.phi, cfg)
    env = make_env("box", seed=0, config=cfg.env)
    space = env.observation_space
    env.close()
    torch.manual_seed(0)
    return cfg, Policy(ActorCritic(make_student_features(path, space), 3, 32), name="student")


def test_parallel_evaluation_gives_the_same_rows_as_in_process(tmp_path):
    from omcrl.eval import EvalPool
    from omcrl.planners import make_planner

    cfg, student = _smoke_student(tmp_path)
    with EvalPool(2) as pool:
        for policy in (student, make_planner("hybrid-apf-perceptive"), make_planner("hybrid-apf")):
            kw = {"seed": 1, "seed_offset": 5_000, "config": cfg.env}
            one = evaluate(policy, "furniture", 5, **kw)
            two = evaluate(policy, "furniture", 5, workers=pool, **kw)
            assert list(two.episode) == list(range(5))
            pd.testing.assert_frame_equal(one, two)
            assert one.steps.sum() > 5  # real episodes, not an empty frame on both sides
        # batched forwards over lanes: rows may differ from lanes=1 in rounding, never with the workers
        lanes = evaluate(student, "furniture", 5, lanes=2, **kw)
        pd.testing.assert_frame_equal(lanes, evaluate(student, "furniture", 5, lanes=2, workers=pool, **kw))


def test_parallel_evaluation_refuses_what_cannot_reach_a_worker():
    with EvalPool(2) as pool, pytest.raises(TypeError, match="picklable.*workers=1"):
        evaluate(GoRight(1.0), "box", 3, workers=pool, make_env=lambda scene, seed: LineEnv(scene, seed))
    with pytest.raises(RuntimeError, match="not open"):
        EvalPool(2).run((None,), [0], "x", False)


class StaggeredLineEnv(LineEnv):
    """LineEnv starting ``seed % 5`` m further back, so episodes end after different numbers of steps."""

    def reset(self, *, seed=None, options=None):
        obs, info = super().reset(seed=seed, options=options)
        self.x = -float(seed % 5)
        return np.array([3.0 - self.x], np.float32), {"pose": np.array([self.x, 0.0, 0.0])}


class Proportional:
    """A policy with ``act_batch`` whose batched actions equal its one-at-a-time actions bit for bit."""

    name, checkpoint = "proportional", "none"

    def __init__(self) -> None:
        self.batches: list[int] = []

    def act(self, obs, info):
        return self.act_batch(np.asarray(obs)[None], [info])[0]

    def act_batch(self, obs, infos):
        self.batches.append(len(obs))
        x = np.clip(0.25 * np.asarray(obs, np.float32)[:, :1] + 0.1, -1.0, 1.0)
        return np.concatenate([x, np.zeros((len(obs), 2), np.float32)], axis=1)


def test_lanes_run_episodes_in_lock_step_with_the_same_rows():
    kw = {"seed": 0, "seed_offset": 100, "make_env": StaggeredLineEnv}
    one = evaluate(pol := Proportional(), "box", 11, **kw)
    assert set(pol.batches) == {1} and one.steps.nunique() > 2  # episodes of unequal length
    lanes = evaluate(pol := Proportional(), "box", 11, lanes=3, **kw)
    # 11 episodes in chunks of 4, 4, 3: three lanes refill from their chunk as episodes end, then drain
    assert max(pol.batches) == 3 and 1 in pol.batches and 2 in pol.batches
    assert sum(pol.batches) == one.steps.sum()  # every step of every episode, each once
    pd.testing.assert_frame_equal(one, lanes)
    with EvalPool(2) as pool:
        pd.testing.assert_frame_equal(lanes, evaluate(Proportional(), "box", 11, lanes=3, workers=pool, **kw))
    # a planner (no act_batch) steps one env whatever lanes says
    pd.testing.assert_frame_equal(
        evaluate(GoRight(1.0), "box", 5, make_env=StaggeredLineEnv),
        evaluate(GoRight(1.0), "box", 5, lanes=4, make_env=StaggeredLineEnv),
    )
    with pytest.raises(ValueError, match="lanes must be >= 1, got 0"):
        evaluate(Proportional(), "box", 3, lanes=0, **kw)


def test_eval_look_swaps_other_families_looks_and_keys_the_cache(tmp_path):
    """Issue 75's attribution: eval.look=box-v2 draws tree-v2's own layouts in box-v2's look (an appearance swap),
    leaves box-v2 (its own family) alone, is refused for an unknown scene, and gives an evaluation another cache run
    than the own-look one, with the same layouts."""
    from omcrl.config import ConfigError, load_config
    from omcrl.eval.stage import evaluate_methods, look_disturbance

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}", "eval.look=box"])
    assert cfg.eval.look == "box-v2"
    assert look_disturbance(cfg, "tree-v2") == {"appearance": "box-v2"} and look_disturbance(cfg, "box-v2") is None
    assert look_disturbance(load_config("smoke"), "tree-v2") is None
    with pytest.raises(ConfigError, match="eval.look"):
        load_config("smoke", overrides=["eval.look=moon"])
    own = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    a = evaluate_methods(own, {"hybrid-apf": "hybrid-apf"}, ["tree-v2"], 2)
    b = evaluate_methods(cfg, {"hybrid-apf": "hybrid-apf"}, ["tree-v2"], 2)
    assert list(a["seed"]) == list(b["seed"])  # the same layouts
    runs = sorted(p.name for p in (tmp_path / "smoke" / "eval" / "hybrid-apf" / "seed0").iterdir() if p.is_dir())
    assert len(runs) == 2 and any("box-v2" in r for r in runs)
