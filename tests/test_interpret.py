"""Interpretability: Grad-CAM, feature stability, the disturbance conditions of the simulated room."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from torch import nn

from omcrl.config import ConfigError, load_config
from omcrl.envs import make_env
from omcrl.interpret.disturb import CONDITIONS, condition, disturbance_table, encoder_policy, room_config
from omcrl.interpret.gradcam import TARGETS, grad_cam, mass_share, policy_cam
from omcrl.interpret.stability import perturb, stability


# ---------------------------------------------------------------- Grad-CAM
class ColourReader(nn.Module):
    """Channel 0 fires on red, channel 1 on green (fixed 1x1 conv); the output reads one of the channels."""

    def __init__(self, channel: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, 2, 1, bias=False)
        with torch.no_grad():
            self.conv.weight.zero_()
            self.conv.weight[0, 0] = 1.0  # red
            self.conv.weight[1, 1] = 1.0  # green
        self.act = nn.ReLU()
        self.channel = channel

    def forward(self, x):
        return self.act(self.conv(x))[:, self.channel].mean((1, 2))[:, None].repeat(1, 3)


def _two_squares(n=4):
    x = torch.zeros(n, 3, 32, 32)
    x[:, 0, 2:10, 2:10] = 1.0  # red square, top left
    x[:, 1, 20:30, 18:28] = 1.0  # green square, bottom right
    red = torch.zeros(32, 32, dtype=torch.bool)
    red[2:10, 2:10] = True
    green = torch.zeros(32, 32, dtype=torch.bool)
    green[20:30, 18:28] = True
    return x, red.numpy(), green.numpy()


def test_grad_cam_puts_the_mass_where_the_action_looks():
    x, red, green = _two_squares()
    for channel, region, other in ((0, red, green), (1, green, red)):
        model = ColourReader(channel)
        cams = grad_cam(model, model.act, x, TARGETS["all"])
        assert cams.shape == (4, 32, 32) and (cams >= 0).all()
        share = mass_share(cams, np.broadcast_to(region, cams.shape))
        assert share["share"] > 0.9, share  # the square covers 6-10 % of the image
        assert mass_share(cams, np.broadcast_to(other, cams.shape))["share"] < 0.05


def test_mass_share_of_a_uniform_map_is_the_obstacle_fraction():
    cams = np.ones((3, 8, 8))
    masks = np.zeros((3, 8, 8), bool)
    masks[:, :2] = True
    s = mass_share(cams, masks)
    assert s["share"] == pytest.approx(0.25) and s["lift"] == pytest.approx(1.0) and s["frames_used"] == 3
    cams[0] = 0.0  # a frame without mass is analysed but left out of the means
    assert mass_share(cams, masks)["frames"] == 3 and mass_share(cams, masks)["frames_used"] == 2
    with pytest.raises(ValueError, match="differ"):
        mass_share(cams, masks[:, :4])


def _smoke_policy(tmp_path, kind):
    from omcrl.models import random_encoder, save_encoder
    from omcrl.models.actor_critic import ActorCritic
    from omcrl.rl.policy import Policy, make_oracle_features, make_pixel_features, make_student_features

    cfg = load_config("smoke")
    env = make_env("box", seed=0, config=cfg.env)
    space = env.observation_space
    obs, _ = env.reset(seed=0)
    env.close()
    torch.manual_seed(0)
    if kind == "student":
        enc = random_encoder(cfg, seed=0)
        feats = make_student_features(save_encoder(tmp_path / "e.pt", enc.f, enc.phi, cfg), space)
    elif kind == "pixel":
        feats = make_pixel_features(space, cfg.pretrain.crop_to, cfg.pretrain.feature_dim)
    else:
        feats = make_oracle_features(space, 16, cfg.env.far)
    return Policy(ActorCritic(feats, 3, 32)), obs, cfg


@pytest.mark.parametrize("kind", ["student", "pixel"])
def test_policy_cam_on_camera_policies_and_refusal_of_the_oracle(tmp_path, kind):
    pol, obs, cfg = _smoke_policy(tmp_path, kind)
    stacks = np.repeat(obs["rgb"].reshape(1, -1, *obs["rgb"].shape[-2:]), 2, 0)
    states = np.repeat(obs["state"][None], 2, 0)
    cams = policy_cam(pol, stacks, states, "yaw")
    c = cfg.pretrain.crop_to
    assert cams.shape == (2, c, c) and np.isfinite(cams).all() and (cams >= 0).all()
    np.testing.assert_allclose(cams[0], cams[1], rtol=1e-5, atol=1e-7)  # same frame, same map
    with pytest.raises(ConfigError, match="target"):
        policy_cam(pol, stacks, states, "pitch")
    oracle, _, _ = _smoke_policy(tmp_path, "oracle")
    with pytest.raises(ConfigError, match="camera images"):
        policy_cam(oracle, stacks, states)


# ---------------------------------------------------------------- feature stability
def test_stability_is_zero_for_identical_features_and_grows_with_noise():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(200, 16))
    same = stability(z, z.copy())
    assert same["rel_distance"] == pytest.approx(0.0, abs=1e-12) and same["knn_acc"] == 1.0
    rel = [stability(z, z + s * rng.normal(size=z.shape))["rel_distance"] for s in (0.05, 0.3, 1.0, 10.0)]
    assert all(a < b for a, b in itertools.pairwise(rel)), rel
    assert 0.85 < rel[-1] < 1.15  # noise 10x the signal: about as far as an unrelated frame


def test_perturbations_are_reproducible_and_do_what_they_say():
    rng = np.random.default_rng(1)
    stacks = rng.integers(30, 200, (6, 9, 16, 16), dtype=np.uint8)
    for kind in ("brightness", "hue", "mask"):
        a, b = perturb(stacks, kind, seed=3), perturb(stacks, kind, seed=3)
        assert np.array_equal(a, b) and a.shape == stacks.shape and a.dtype == np.uint8
        assert not np.array_equal(a, stacks)
        assert not np.array_equal(a, perturb(stacks, kind, seed=4))
    gray = np.full((2, 9, 8, 8), 120, np.uint8)
    assert np.array_equal(perturb(gray, "hue", seed=0), gray)  # hue rotation leaves gray alone
    masked = perturb(stacks, "mask", seed=0)
    black = (masked == 0).all(1).mean()
    assert 0.15 < black < 0.45  # about 30 % of the grid cells, every frame of a stack alike
    with pytest.raises(ConfigError, match="perturbation"):
        perturb(stacks, "blur")


# ---------------------------------------------------------------- disturbance conditions
def _room_frames(cond, steps=12, seed=3_000_001):
    cfg = load_config("smoke")
    env = make_env("box", seed=0, config=room_config(cfg.env), disturbance=condition(cond, 0) or None)
    try:
        obs, _ = env.reset(seed=seed)
        frames, masks = [obs["rgb"][-1].copy()], [env.obstacle_mask()]
        for _ in range(steps):
            obs, _, term, trunc, _ = env.step(np.array([0.0, 0.0, 0.3], np.float32))  # turn in place
            frames.append(obs["rgb"][-1].copy())
            masks.append(env.obstacle_mask())
        return np.stack(frames), np.stack(masks), env.light_switch_step
    finally:
        env.close()


def test_room_conditions_change_the_frames_as_specified():
    normal, mask, _ = _room_frames("normal")
    color, mask_c, _ = _room_frames("color")
    assert np.array_equal(mask, mask_c) and mask.any()  # same geometry, same obstacle pixels
    on = np.broadcast_to(mask[:, None], normal.shape)
    assert not np.array_equal(normal[on], color[on])  # obstacles recoloured
    np.testing.assert_array_equal(normal[~on], color[~on])  # the rest of the room untouched
    # Illumination: the switch step is drawn per episode, reproducibly, within the condition's range.
    lit, _, step = _room_frames("illumination", steps=45)
    again, _, step2 = _room_frames("illumination", steps=45)
    lo, hi = CONDITIONS["illumination"]["switch_range"]
    assert step == step2 and lo <= step <= hi and np.array_equal(lit, again)
    ref, _, _ = _room_frames("normal", steps=45)
    # Frame t is rendered after step t: identical to the normal room before the switch, darker from it on.
    np.testing.assert_array_equal(lit[:step], ref[:step])
    assert lit[step:].mean() < 0.8 * ref[step:].mean()


def test_bad_conditions_methods_and_missing_runs_get_clear_errors(tmp_path):
    from omcrl.rl.policy import CheckpointError

    with pytest.raises(ConfigError, match="known conditions"):
        condition("fog")
    cfg = load_config("smoke", overrides={"results_dir": str(tmp_path)})
    with pytest.raises(ConfigError, match="no camera encoder"):
        encoder_policy(cfg, "oracle")
    with pytest.raises(ConfigError, match="known methods"):
        encoder_policy(cfg, "dreamer")
    with pytest.raises(CheckpointError, match="train --method curl"):
        encoder_policy(cfg, "curl")


def test_disturbance_table_has_cis_and_the_papers_numbers():
    import pandas as pd

    df = pd.DataFrame(
        {
            "method": ["ours"] * 4 + ["curl"] * 4,
            "condition": ["normal"] * 8,
            "success": [1, 1, 0, 1, 0, 0, 1, 0],
            "train_seed": [0] * 8,
        }
    )
    t = disturbance_table(df, reps=500).set_index("method")
    assert t.loc["ours", "SR"] == 75.0 and t.loc["curl", "SR"] == 25.0
    assert t.loc["ours", "lo"] <= 75.0 <= t.loc["ours", "hi"]
    assert t.loc["ours", "paper_SR"] == 70 and t.loc["curl", "paper_SR"] == 45
