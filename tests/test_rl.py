"""PPO, guidance and the training runs (omcrl.rl), on tiny custom envs that run in seconds."""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
import torch
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from omcrl.config import load_config
from omcrl.rl import (
    ActorCritic,
    CheckpointError,
    IdentityFeatures,
    NonFiniteLossError,
    PlannerGuide,
    alpha_at,
    compute_gae,
    gaussian_kl,
    load_policy,
    ppo_loss,
    ppo_update,
    train_oracle,
    train_ppo,
    train_visuomotor,
)

torch.set_num_threads(1)


# ---------------------------------------------------------------- tiny envs
class PointReach(gym.Env):
    """2-D point mass: obs = goal − pos (2,), action = velocity command in [-1, 1]², reward = −distance.

    Episodes last 20 steps (truncation) or end at the goal (+1). The zero-mean initial policy scores about
    −20·|goal|, the optimum a few units better per metre, so learning shows up clearly in the return.
    """

    observation_space = gym.spaces.Box(-4.0, 4.0, (2,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    def __init__(self, nan_after: int | None = None, fail_after: int | None = None) -> None:
        self.nan_after, self.fail_after, self.calls = nan_after, fail_after, 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.pos = np.zeros(2)
        ang = self.np_random.uniform(0, 2 * np.pi)
        self.goal = self.np_random.uniform(1.0, 2.0) * np.array([np.cos(ang), np.sin(ang)])
        self.t = 0
        return (self.goal - self.pos).astype(np.float32), {}

    def step(self, action):
        self.calls += 1
        if self.fail_after is not None and self.calls > self.fail_after:
            raise RuntimeError("simulated crash")
        self.pos = self.pos + 0.25 * np.clip(action, -1, 1)
        self.t += 1
        d = float(np.linalg.norm(self.goal - self.pos))
        success = d < 0.2
        reward = -d + (1.0 if success else 0.0)
        if self.nan_after is not None and self.calls > self.nan_after:
            reward = float("nan")
        trunc = self.t >= 20 and not success
        info = {}
        if success or trunc:
            info["metrics"] = {"success": success, "final_distance": d}
        return (self.goal - self.pos).astype(np.float32), reward, success, trunc, info


def vec(n: int = 2, mode: AutoresetMode = AutoresetMode.NEXT_STEP, **kw):
    def make(seed: int):
        return SyncVectorEnv([lambda: PointReach(**kw) for _ in range(n)], autoreset_mode=mode)

    return make


def rl_cfg(tmp_path, **rl):
    base = {
        "total_steps": 6144,
        "n_envs": 2,
        "horizon": 64,
        "buffer_size": 512,
        "minibatch": 128,
        "epochs": 4,
        "lr": 3e-3,
        "hidden": 64,
        "init_log_std": -0.5,
        "checkpoint_every": 1024,
        "alpha_schedule": "none",
    }
    base.update(rl)
    return load_config("smoke", overrides={"results_dir": str(tmp_path), "rl": base})


def greedy_return(policy_act, episodes: int = 40) -> float:
    env = PointReach()
    total = 0.0
    for ep in range(episodes):
        obs, _ = env.reset(seed=10_000 + ep)
        done = False
        while not done:
            obs, r, term, trunc, _ = env.step(policy_act(obs))
            total += r
            done = term or trunc
    return total / episodes


# ---------------------------------------------------------------- maths
def test_gae_hand_computed_with_done_in_middle():
    # γ = 0.9, λ = 0.8; the episode terminates after t = 2; bootstrap V = 3.0 after t = 4.
    r = torch.tensor([[1.0], [2.0], [3.0], [4.0], [5.0]])
    v = torch.tensor([[0.5], [1.0], [1.5], [2.0], [2.5]])
    nv = torch.tensor([[1.0], [1.5], [99.0], [2.5], [3.0]])  # 99 must be ignored: terminal
    term = torch.tensor([[0.0], [0.0], [1.0], [0.0], [0.0]])
    ends = torch.tensor([[0.0], [0.0], [1.0], [0.0], [1.0]])
    adv, ret = compute_gae(r, v, nv, term, ends, gamma=0.9, lam=0.8)
    # δ4 = 5 + .9·3 − 2.5 = 5.2;  δ3 = 4 + .9·2.5 − 2 = 4.25 → A3 = 4.25 + .72·5.2 = 7.994
    # δ2 = 3 − 1.5 = 1.5 (terminal, recursion stops);  δ1 = 2 + .9·1.5 − 1 = 2.35 → A1 = 2.35 + .72·1.5 = 3.43
    # δ0 = 1 + .9·1 − .5 = 1.4 → A0 = 1.4 + .72·3.43 = 3.8696
    expected = torch.tensor([[3.8696], [3.43], [1.5], [7.994], [5.2]])
    assert torch.allclose(adv, expected, atol=1e-5)
    assert torch.allclose(ret, expected + v, atol=1e-5)


def test_gaussian_kl_matches_monte_carlo():
    g = torch.Generator().manual_seed(0)
    mp, sp = torch.tensor([0.3, -0.5, 1.0]), torch.tensor([0.4, 0.9, 0.3])
    mq, sq = torch.tensor([0.0, 0.2, 0.6]), torch.tensor([0.6, 0.5, 0.5])
    closed = gaussian_kl(mp, sp, mq, sq).item()
    x = mp + sp * torch.randn(400_000, 3, generator=g)
    logp = torch.distributions.Normal(mp, sp).log_prob(x).sum(-1)
    logq = torch.distributions.Normal(mq, sq).log_prob(x).sum(-1)
    mc = (logp - logq).mean().item()
    assert abs(mc - closed) / closed < 0.02
    assert gaussian_kl(mp, sp, mp, sp).item() == pytest.approx(0.0, abs=1e-7)


def test_alpha_schedules():
    assert alpha_at(0, "linear", 0.95, 1000) == pytest.approx(0.95)
    assert alpha_at(500, "linear", 0.95, 1000) == pytest.approx(0.475)
    assert alpha_at(1000, "linear", 0.95, 1000) == 0.0
    assert alpha_at(5000, "linear", 0.95, 1000) == 0.0
    assert alpha_at(0, "exp", 0.8, exp_factor=0.5, exp_every=100) == pytest.approx(0.8)
    assert alpha_at(99, "exp", 0.8, exp_factor=0.5, exp_every=100) == pytest.approx(0.8)
    assert alpha_at(250, "exp", 0.8, exp_factor=0.5, exp_every=100) == pytest.approx(0.2)
    assert alpha_at(12345, "fixed", 0.3) == pytest.approx(0.3)
    assert alpha_at(0, "none", 0.95) == 0.0
    with pytest.raises(ValueError, match="alpha schedule"):
        alpha_at(0, "cosine", 0.5)


def test_total_loss_is_weighted_sum_of_parts():
    torch.manual_seed(0)
    agent = ActorCritic(IdentityFeatures(4), act_dim=3, hidden=16, init_log_std=-0.3)
    m = 32
    mb = {
        "obs": {"x": torch.randn(m, 4)},
        "actions": torch.randn(m, 3),
        "log_probs": torch.randn(m) - 3.0,
        "advantages": torch.randn(m),
        "returns": torch.randn(m),
        "guide_mean": torch.randn(m, 3) * 0.5,
        "guide_std": torch.rand(m, 3) * 0.5 + 0.1,
    }
    alpha, beta, clip, cv, ce = 0.3, 2.0, 0.2, 0.5, 0.01
    parts = ppo_loss(agent, mb, alpha, beta, clip, cv, ce)
    # Recompute every part independently with torch.distributions.
    with torch.no_grad():
        f = agent.features(mb["obs"])
        mean, value = agent.actor(f), agent.critic(f).squeeze(-1)
        pi = torch.distributions.Normal(mean, agent.log_std.exp().expand_as(mean))
        ratio = torch.exp(pi.log_prob(mb["actions"]).sum(-1) - mb["log_probs"])
        a = mb["advantages"]
        l_pi = -torch.min(ratio * a, ratio.clamp(1 - clip, 1 + clip) * a).mean()
        l_v = ((value - mb["returns"]) ** 2).mean()
        ent = pi.entropy().sum(-1).mean()
        guide = torch.distributions.Normal(mb["guide_mean"], mb["guide_std"])
        kl = torch.distributions.kl_divergence(guide, pi).sum(-1).mean()
        l_rl = l_pi + cv * l_v - ce * ent
        total = (1 - alpha) * l_rl + alpha * beta * kl
    assert parts.policy.item() == pytest.approx(l_pi.item(), rel=1e-5)
    assert parts.value.item() == pytest.approx(l_v.item(), rel=1e-5)
    assert parts.kl.item() == pytest.approx(kl.item(), rel=1e-5)
    assert parts.rl.item() == pytest.approx(l_rl.item(), rel=1e-5)
    assert parts.total.item() == pytest.approx(total.item(), rel=1e-5)
    # α = 0 is plain PPO whatever the guide says.
    assert ppo_loss(agent, mb, 0.0, beta, clip, cv, ce).total.item() == pytest.approx(l_rl.item(), rel=1e-5)


# ---------------------------------------------------------------- learning
def test_ppo_learns_point_reach(tmp_path):
    cfg = rl_cfg(tmp_path)
    torch.manual_seed(0)
    init = ActorCritic(IdentityFeatures(2), act_dim=2, hidden=64, layer_norm=False)
    before = greedy_return(lambda o: np.clip(init.actor(torch.as_tensor(o)[None]).detach().numpy()[0], -1, 1))
    res = train_ppo(cfg, vec(), progress=False)
    pol = res.policy()
    after = greedy_return(pol.act)
    # Zero-mean start ≈ −30; moving straight at full speed ≈ −11. Demand most of that gap.
    assert after > before + 10.0, (before, after)
    m = pd.read_csv(res.metrics_path)
    assert {
        "episodic_return",
        "success_rate",
        "alpha",
        "kl",
        "policy_loss",
        "value_loss",
        "entropy",
        "steps_per_s",
    } <= set(m.metric)
    assert (res.run_dir / "config.yaml").exists() and any((res.run_dir / "tb").iterdir())
    # Same config again: skipped, same final step count.
    again = train_ppo(cfg, vec(), progress=False)
    assert again.skipped and again.steps == res.steps


def test_same_seed_same_run_and_another_seed_differs(tmp_path):
    """Two fresh runs with one seed log identical metrics (wall-clock ones aside); another seed does not."""
    timing = {"steps_per_s", "rollout_s", "update_s"}

    def logged(name: str, seed: int) -> pd.DataFrame:
        cfg = rl_cfg(tmp_path, total_steps=1024).with_seed(seed)
        m = pd.read_csv(train_ppo(cfg, vec(), name=name, progress=False).metrics_path)
        return m[~m.metric.isin(timing)].reset_index(drop=True)

    a, b, other = logged("a", 0), logged("b", 0), logged("c", 1)
    pd.testing.assert_frame_equal(a, b)
    assert not a["value"].equals(other["value"])


def test_guided_ppo_follows_planner_same_step_autoreset(tmp_path):
    # A perfect planner as guide with α fixed high: the KL term alone should pull the policy to the goal,
    # and the same-step autoreset path (final_obs bootstrap) must work too.
    cfg = rl_cfg(tmp_path, total_steps=3072, alpha_schedule="fixed", alpha_start=0.9, guide_std=0.3)

    class Planner:
        def act(self, obs, info):
            return np.clip(4.0 * obs, -1, 1)

    res = train_ppo(
        cfg,
        vec(mode=AutoresetMode.SAME_STEP),
        progress=False,
        make_guide=lambda env: PlannerGuide(Planner, cfg.rl.guide_std, n_envs=env.num_envs),
    )
    m = pd.read_csv(res.metrics_path)
    kl = m[m.metric == "kl"].value.to_numpy()
    assert kl[-1] < 0.5 * kl[0]
    assert greedy_return(res.policy().act) > -20.0


# ---------------------------------------------------------------- robustness
def test_nan_loss_stops_with_clear_error_and_keeps_checkpoint(tmp_path):
    # 512 transitions per update, checkpoint every 512: the first update checkpoints, NaN rewards then start.
    cfg = rl_cfg(tmp_path, checkpoint_every=512)
    with pytest.raises(NonFiniteLossError, match=r"non-finite (policy|value|total) loss .* at env step 512"):
        train_ppo(cfg, vec(nan_after=300), progress=False)
    (ckpt,) = (tmp_path / "smoke/runs/rl").glob("ppo-flat-*/seed0/checkpoint.pt")
    state = torch.load(ckpt, weights_only=True)
    assert state["step"] == 512
    assert all(torch.isfinite(v).all() for v in state["model"].values())
    assert not (ckpt.parent / "final.pt").exists()


def test_resume_ends_at_same_step_count(tmp_path):
    cfg = rl_cfg(tmp_path, total_steps=3000, checkpoint_every=1024)
    full = train_ppo(cfg, vec(), name="full", progress=False)
    # Crash during the 4th update (after checkpoint at 1024, before the one at 2048).
    with pytest.raises(RuntimeError, match="simulated crash"):
        train_ppo(cfg, vec(fail_after=700), name="resumed", progress=False)
    (run,) = (tmp_path / "smoke/runs/rl").glob("resumed-*/seed0")
    assert torch.load(run / "checkpoint.pt", weights_only=True)["step"] == 1024
    resumed = train_ppo(cfg, vec(), name="resumed", progress=False)
    assert not resumed.skipped
    assert resumed.steps == full.steps == 3072  # ceil(3000 / 512) updates of 512
    m = pd.read_csv(resumed.metrics_path)
    assert not m.duplicated(["step", "metric"]).any()
    assert m.step.max() == 3072
    assert not (run / "checkpoint.pt").exists()
    # Where each stretch of training began and the env seed it flew (a resume restarts the envs with its own).
    segments = json.loads((run / "run.json").read_text())["segments"]
    assert segments == [{"from_step": 0, "env_seed": 0}, {"from_step": 1024, "env_seed": 100}]
    (whole,) = (tmp_path / "smoke/runs/rl").glob("full-*/seed0")
    assert json.loads((whole / "run.json").read_text())["segments"] == [{"from_step": 0, "env_seed": 0}]


# ---------------------------------------------------------------- oracle and student on a contract-shaped env
class ToyNav(gym.Env):
    """Env with the omcrl.envs observation contract (tiny images) and a 2-D point drone."""

    def __init__(self, size: int = 20, stack: int = 2) -> None:
        self.size, self.stack = size, stack
        self.observation_space = gym.spaces.Dict(
            {
                "rgb": gym.spaces.Box(0, 255, (stack, 3, size, size), np.uint8),
                "depth": gym.spaces.Box(0.0, 20.0, (stack, size, size), np.float32),
                "state": gym.spaces.Box(-np.inf, np.inf, (12,), np.float32),
                "privileged": gym.spaces.Box(-np.inf, np.inf, (6,), np.float32),
            }
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

    def _obs(self):
        dg = self.goal - self.pos
        state = np.zeros(12, np.float32)
        state[9:11] = dg
        priv = np.zeros(6, np.float32)
        priv[0:2] = -self.pos
        priv[3:5] = dg
        shade = np.uint8(min(255, 40 * np.linalg.norm(dg)))
        return {
            "rgb": np.full((self.stack, 3, self.size, self.size), shade, np.uint8),
            "depth": np.full((self.stack, self.size, self.size), np.linalg.norm(dg), np.float32),
            "state": state,
            "privileged": priv,
        }

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos, self.goal, self.t = np.zeros(2), self.np_random.uniform(-2, 2, 2), 0
        return self._obs(), {"pose": (0.0, 0.0, 0.0)}

    def step(self, action):
        self.pos = self.pos + 0.25 * np.clip(action[:2], -1, 1)
        self.t += 1
        d = float(np.linalg.norm(self.goal - self.pos))
        success, trunc = d < 0.3, self.t >= 15
        info = {"pose": (*self.pos, 0.0)}
        if success or trunc:
            info["metrics"] = {"success": success, "final_distance": d}
        return self._obs(), -0.1 * d + 10.0 * success, success, trunc and not success, info


def toy_vec(size: int = 20):
    return lambda seed: SyncVectorEnv([lambda: ToyNav(size) for _ in range(2)])


def save_test_encoder(path, size: int = 20):
    from omcrl.models import PixelEncoder, Projection, save_encoder

    cfg = load_config(
        "smoke",
        overrides={
            "env": {"image_size": size, "frame_stack": 2},
            "pretrain": {"crop_from": size, "crop_to": 16, "feature_dim": 8, "proj_hidden": 8},
        },
    )
    save_encoder(path, PixelEncoder(2, 16, 8), Projection(8, 8, 8), cfg)
    return path


def test_oracle_and_student_train_and_check_checkpoints(tmp_path):
    cfg = rl_cfg(
        tmp_path,
        total_steps=256,
        buffer_size=128,
        minibatch=64,
        horizon=64,
        checkpoint_every=10_000,
        alpha_schedule="linear",
        alpha_decay_steps=256,
    )
    cfg.pretrain.feature_dim = 8
    cfg.oracle.guide = "none"  # the toy env has no map for the HybridAPF guide (tests/test_integration.py has)
    oracle = train_oracle(cfg, make_env=toy_vec(), progress=False)
    pol = oracle.policy()
    env = ToyNav()
    obs, info = env.reset(seed=0)
    assert pol.act(obs, info).shape == (3,)
    enc = save_test_encoder(tmp_path / "enc.pt")
    student = train_visuomotor(cfg, enc, oracle.final_path, name="ours", make_env=toy_vec(), progress=False)
    spol = load_policy(student.final_path)
    assert spol.act(obs, info).shape == (3,)
    assert spol.act_batch({k: np.stack([v, v]) for k, v in obs.items()}).shape == (2, 3)
    m = pd.read_csv(student.metrics_path)
    assert m[(m.metric == "alpha")].value.iloc[0] == pytest.approx(0.95)

    # Missing encoder, missing oracle, and an oracle trained on other image sizes: clear errors, no training.
    with pytest.raises(CheckpointError, match=r"nope\.pt"):
        train_visuomotor(cfg, tmp_path / "nope.pt", oracle.final_path, name="x", make_env=toy_vec(), progress=False)
    with pytest.raises(CheckpointError, match=r"missing_oracle\.pt"):
        train_visuomotor(cfg, enc, tmp_path / "missing_oracle.pt", name="y", make_env=toy_vec(), progress=False)
    cfg24 = rl_cfg(tmp_path / "b", total_steps=128, buffer_size=128, minibatch=64, checkpoint_every=10_000)
    cfg24.pretrain.feature_dim = 8
    cfg24.oracle.guide = "none"
    other = train_oracle(cfg24, make_env=toy_vec(24), progress=False)
    with pytest.raises(CheckpointError, match=r"oracle-\w+/seed0/final.pt.*depth: checkpoint \[2, 24, 24\]"):
        train_visuomotor(cfg, enc, other.final_path, name="z", make_env=toy_vec(), progress=False)
    assert not list((tmp_path / "smoke/runs/rl").glob("z-*"))
    assert math.isfinite(float(m[m.metric == "kl"].value.iloc[0]))


def test_device_setting_resolves_and_refuses_a_missing_gpu_before_training(tmp_path):
    from omcrl.config import ConfigError
    from omcrl.utils.runtime import resolve_device, to_device

    # This machine has no CUDA GPU: auto is the CPU, where moving a batch is the identity.
    assert resolve_device("auto") == torch.device("cpu") == resolve_device("cpu")
    batch = {"obs": {"x": torch.ones(2, 3)}, "guide_mean": None}
    moved = to_device(batch, torch.device("cpu"))
    assert moved["obs"]["x"] is batch["obs"]["x"] and moved["guide_mean"] is None
    with pytest.raises(ConfigError, match="device"):
        resolve_device("tpu")
    if torch.cuda.is_available():
        return
    cfg = rl_cfg(tmp_path, device="cuda")
    with pytest.raises(ConfigError, match="'cuda'.*no CUDA GPU"):
        train_ppo(cfg, vec(), progress=False)
    assert not (tmp_path / "smoke" / "runs").exists()  # refused before a run folder appeared


def test_one_update_takes_its_settings_from_the_rl_section():
    """ppo_update reads cfg.rl itself (no settings object to keep in step): rl.epochs × ceil(M / rl.minibatch)
    optimiser steps, and a knob changed in the config changes the update."""
    import copy

    from omcrl.rl.ppo import Rollout

    rl = load_config("smoke").rl
    t, n = 8, 4
    g = torch.Generator().manual_seed(0)
    roll = Rollout(
        obs={"x": torch.randn(t, n, 4, generator=g)},
        actions=torch.randn(t, n, 3, generator=g),
        log_probs=torch.randn(t, n, generator=g) - 3.0,
        values=torch.randn(t, n, generator=g),
        next_values=torch.randn(t, n, generator=g),
        rewards=torch.randn(t, n, generator=g),
        terminated=torch.zeros(t, n),
        ends=torch.zeros(t, n),
        valid=torch.ones(t, n),
    )
    roll.advantages, roll.returns = compute_gae(
        roll.rewards, roll.values, roll.next_values, roll.terminated, roll.ends, rl.gamma, rl.gae_lambda
    )

    def update(**knobs):
        torch.manual_seed(0)
        agent = ActorCritic(IdentityFeatures(4), act_dim=3, hidden=16)
        opt = torch.optim.Adam(agent.parameters(), lr=1e-3)
        cfg_rl = copy.deepcopy(rl)
        for k, v in knobs.items():
            setattr(cfg_rl, k, v)
        ppo_update(agent, opt, roll, cfg_rl, alpha=0.0)
        steps = {int(st["step"]) for st in opt.state.values()}
        return steps, torch.cat([p.detach().flatten() for p in agent.parameters()])

    steps, w = update(epochs=2, minibatch=12)
    assert steps == {2 * 3}  # 32 transitions in minibatches of 12: three a pass
    steps, _ = update(epochs=1, minibatch=32)
    assert steps == {1}
    _, w_clipped = update(epochs=2, minibatch=12, max_grad_norm=1e-6)
    assert not torch.equal(w, w_clipped)


def test_a_non_finite_action_stops_the_rollout_and_says_whether_the_observations_the_weights_or_an_overflow_gave_it():
    """A NaN action is caught where the policy made it, before the env sees it, with its cause: a non-finite
    observation (named by key), a non-finite weight (named), or an overflow of finite ones (input sizes given)."""
    from omcrl.envs import make_vec_env
    from omcrl.models.actor_critic import ActorCritic
    from omcrl.models.features import make_oracle_features
    from omcrl.rl.ppo import NonFiniteLossError
    from omcrl.rl.rollout import Runner

    cfg = load_config("smoke")
    env = make_vec_env("box", 2, seed=3, config=cfg.env)
    try:
        torch.manual_seed(0)
        space = env.single_observation_space
        agent = ActorCritic(make_oracle_features(space, cfg.pretrain.feature_dim, cfg.env.far), 3, cfg.rl.hidden)
        runner = Runner(env, agent, None, seed=3)
        runner.collect(4, cfg.rl.horizon, use_guide=False)  # finite: no error
        key = next(k for k, v in runner.stored.items() if v.is_floating_point())
        runner.stored[key][1] = float("nan")
        with pytest.raises(NonFiniteLossError, match=rf"lane\(s\) \[1\], from non-finite observations \({key}\)"):
            runner.collect(4, cfg.rl.horizon, use_guide=False)
        runner.stored[key][1] = 0.0
        # Finite inputs through finite weights can still overflow (a huge weight here; the actor's input LayerNorm
        # squashes a huge observation): the message gives both sides' largest magnitude.
        last = agent.actor[-1].weight
        saved = last.detach().clone()
        with torch.no_grad():
            last.fill_(3e38)
        with pytest.raises(
            NonFiniteLossError, match=r"finite weights \(an overflow; largest \|input\|: .*\|weight\| 3e\+38"
        ):
            runner.collect(4, cfg.rl.horizon, use_guide=False)
        with torch.no_grad():
            last.copy_(saved)
        name, param = next(iter(agent.named_parameters()))
        with torch.no_grad():
            param.fill_(float("nan"))
        with pytest.raises(NonFiniteLossError, match=rf"from finite observations \(the policy's weights .*: {name}"):
            runner.collect(4, cfg.rl.horizon, use_guide=False)
    finally:
        env.close()
