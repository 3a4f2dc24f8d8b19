"""Transfer diagnostics: the appearance swap and the feature-shift measures (issue: zero-shot generalisation)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from omcrl.config import ConfigError, load_config
from omcrl.envs import make_env
from omcrl.envs.stats import geometry_stats, geometry_summary
from omcrl.interpret import (
    feature_shift,
    frechet_distance,
    mmd_rbf,
    pilot_frames,
    saturated_share,
    with_fixed_features,
)
from omcrl.scenes import scene_spec


def _roll(scene: str, look: str | None, steps: int = 40, parts: str = "all") -> dict:
    dist = {"appearance": look, "appearance_parts": parts} if look else None
    env = make_env(scene, seed=2, image_size=32, disturbance=dist)
    obs, info = env.reset(seed=7)
    out = {"rgb": [obs["rgb"][-1].copy()], "depth": [obs["depth"][-1].copy()], "pose": [], "reward": [], "done": []}
    out["path"], out["optimal"], out["occ"] = np.asarray(info["path"]), info["optimal_path_length"], env.grid.occ.copy()
    rng = np.random.default_rng(0)
    for _ in range(steps):
        obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
        out["rgb"].append(obs["rgb"][-1].copy())
        out["depth"].append(obs["depth"][-1].copy())
        out["pose"].append(np.asarray(info["pose"]).copy())
        out["reward"].append(r)
        out["done"].append((term, trunc))
        if term or trunc:
            break
    env.close()
    return out


@pytest.mark.parametrize(
    "scene, look", [("furniture-v0", "box"), ("box", "furniture-v0"), ("furniture-v1", "tree"), ("barrier", "tree")]
)
def test_appearance_swap_changes_frames_not_geometry(scene, look):
    own, swapped = _roll(scene, None), _roll(scene, look)
    # Geometry, start/goal, the shortest path, collisions and rewards are the layout's, whatever its look.
    np.testing.assert_array_equal(own["occ"], swapped["occ"])
    np.testing.assert_array_equal(own["path"], swapped["path"])
    assert own["optimal"] == swapped["optimal"]
    np.testing.assert_array_equal(np.asarray(own["pose"]), np.asarray(swapped["pose"]))
    assert own["reward"] == swapped["reward"] and own["done"] == swapped["done"]
    # Depth sees shapes, not materials: between two indoor looks (same room walls and ceiling) the oracle's
    # input is identical; an outdoor look moves the background (sky instead of walls and ceiling).
    same_depth = np.array_equal(np.asarray(own["depth"]), np.asarray(swapped["depth"]))
    assert same_depth == (scene_spec(scene).indoor == scene_spec(look).indoor)
    # ... but the camera sees another world.
    diff = np.abs(np.asarray(own["rgb"], np.float32) - np.asarray(swapped["rgb"], np.float32)).mean()
    assert diff > 10.0, diff


def test_appearance_parts_swap_one_part_each():
    own, both = _roll("box", None, 3), _roll("box", "furniture-v0", 3)
    parts = {part: _roll("box", "furniture-v0", 3, part) for part in ("surroundings", "obstacles")}
    for part, out in parts.items():
        for other in (own, both):
            assert not np.array_equal(np.asarray(out["rgb"]), np.asarray(other["rgb"])), part


def test_appearance_of_its_own_scene_is_the_identity():
    a, b = _roll("tree", None, 5), _roll("tree", "tree", 5)
    np.testing.assert_array_equal(np.asarray(a["rgb"]), np.asarray(b["rgb"]))


def test_appearance_is_validated():
    with pytest.raises(ConfigError, match="disturbance.appearance"):
        make_env("box", disturbance={"appearance": "moon"})
    with pytest.raises(ConfigError, match="disturbance.appearance_parts"):
        make_env("box", disturbance={"appearance": "tree", "appearance_parts": "sky"})


def test_mmd_and_frechet_are_zero_for_identical_and_grow_with_a_known_shift():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(300, 8))
    fresh = rng.normal(size=(300, 8))  # same distribution, another sample
    assert mmd_rbf(x, x) == 0.0
    assert frechet_distance(x, x) < 1e-8
    mmds = [mmd_rbf(x, fresh + s, bandwidth=2.0) for s in (0.0, 0.5, 1.5)]
    frechets = [frechet_distance(x, fresh + s) for s in (0.0, 0.5, 1.5)]
    assert mmds[0] < mmds[1] < mmds[2] and frechets[0] < frechets[1] < frechets[2]
    # The Fréchet distance of two Gaussians differing in mean only is |Δμ|² (8 dims × 1.5²), up to sampling.
    assert frechets[2] == pytest.approx(8 * 1.5**2, rel=0.15)


def test_saturated_share():
    h = np.array([[0.995, -0.999, 0.5, 0.0], [0.2, 0.98, -0.995, 1.0]])
    assert saturated_share(h) == pytest.approx(4 / 8)


def test_feature_shift_of_an_encoder_on_pilot_frames():
    from omcrl.models import random_encoder

    cfg = load_config("smoke")
    enc = random_encoder(cfg, seed=0)
    box = pilot_frames("box", 2, seed=3, env_config=cfg.env, max_steps=30)
    assert box.dtype == np.uint8 and box.shape[1:] == (3 * cfg.env.frame_stack, cfg.env.image_size, cfg.env.image_size)
    same = feature_shift(enc, box, box)
    assert same["mmd"] == 0.0 and same["frechet"] < 1e-6 and same["saturated"] == same["saturated_ref"]
    dark = (box.astype(np.float32) * 0.3).astype(np.uint8)  # a known, large shift of the input
    shifted = feature_shift(enc, box, dark)
    assert shifted["mmd"] > 0.01 and shifted["frechet"] > 1e-3


def test_fixed_features_policy_ignores_the_camera(tmp_path):
    import torch

    from omcrl.models import ActorCritic, random_encoder, save_encoder
    from omcrl.models.features import make_student_features
    from omcrl.rl.policy import Policy

    cfg = load_config("smoke")
    enc = random_encoder(cfg, seed=1)
    save_encoder(tmp_path / "encoder.pt", enc.f, enc.phi, cfg)
    env = make_env("box", seed=0, config=cfg.env)
    obs, _ = env.reset(seed=0)
    env.close()
    torch.manual_seed(0)
    pol = Policy(ActorCritic(make_student_features(tmp_path / "encoder.pt", env.observation_space), 3, 16), "ours")
    other = dict(obs, rgb=(255 - obs["rgb"]).astype(np.uint8))  # another view, same state
    assert not np.allclose(pol.act(obs), pol.act(other))  # the real policy looks at the camera
    z = np.full(pol.agent.features.enc_dim, 0.1, np.float32)
    blind = with_fixed_features(pol, z)
    np.testing.assert_array_equal(blind.act(obs), blind.act(other))
    assert not np.allclose(pol.act(obs), pol.act(other))  # the original is untouched
    with pytest.raises(ValueError, match="values"):
        with_fixed_features(pol, z[:3])


def test_randomized_look_varies_per_layout_keeps_geometry_and_is_seeded():
    def frames(dist, seeds=(100, 101)):
        env = make_env("box", seed=1, image_size=32, disturbance=dist)
        out = []
        for s in seeds:
            obs, _ = env.reset(seed=s)
            out.append((obs["rgb"][-1].copy(), env.grid.occ.copy()))
        env.close()
        return out

    rand = frames({"randomize_look": True, "seed": 3})
    own = frames(None)
    again = frames({"randomize_look": True, "seed": 3})
    assert not np.array_equal(rand[0][0], rand[1][0])
    for (r, occ_r), (o, occ_o), (a, _) in zip(rand, own, again):
        np.testing.assert_array_equal(occ_r, occ_o)  # geometry untouched
        np.testing.assert_array_equal(r, a)  # reproducible from the seed
        assert np.abs(r.astype(float) - o.astype(float)).mean() > 10


def test_generic_textures_avoid_the_evaluation_scenes_materials():
    from omcrl.envs.nav_env import GENERIC_TEXTURES, appearance_materials
    from omcrl.scenes import SCENE_SPECS

    def looks(spec):
        return {t for _, t in appearance_materials(spec.id, 8.0)} | {spec.floor_texture, spec.wall_texture}

    # What an evaluation scene shows that the training scene does not (furniture-v1's room is box's own).
    seen = looks(SCENE_SPECS["box-v0"])
    unseen = set().union(*(looks(s) for s in SCENE_SPECS.values() if s.difficulty != "training")) - seen
    unseen_kinds = {t.split(":")[0] for t in unseen if t}
    assert {"wood", "brick", "bark", "paint"} <= unseen_kinds
    assert not {t.split(":")[0] for t in GENERIC_TEXTURES} & unseen_kinds


def test_randomized_data_has_its_own_file_and_run_and_the_default_keeps_its_key(tmp_path):
    from omcrl.data.collect import collect_dataset as collect
    from omcrl.data.dataset import DatasetError
    from omcrl.pretrain.train import pretrain_run

    own = load_config("smoke", overrides=[f"results_dir={tmp_path}", f"data.file={tmp_path}/box.h5"])
    rand = load_config(
        "smoke", overrides=[f"results_dir={tmp_path}", f"data.file={tmp_path}/box.h5", "data.look=randomized"]
    )
    assert rand.data_path == tmp_path / "box-randomized.h5" and own.data_path == tmp_path / "box.h5"
    assert "look" not in pretrain_run(own).identity["data"]  # a new field at its default: old keys hold
    assert (
        pretrain_run(rand).identity["data"]["look"] == "randomized" and pretrain_run(rand).key != pretrain_run(own).key
    )
    res = collect(rand, progress=False)
    assert res.path == rand.data_path and res.episodes_added > 0 if hasattr(res, "episodes_added") else True
    # A file of the other look is refused, not reused or overwritten.
    rand.data_path.rename(own.data_path)
    before = own.data_path.read_bytes()
    with pytest.raises(DatasetError, match="data.look='randomized'"):
        collect(own, progress=False)
    assert own.data_path.read_bytes() == before


class _ReadsPixels(torch.nn.Module):
    """A stand-in encoder whose features are the first 5 pixels of channel 0 (f is the identity on them)."""

    def __init__(self) -> None:
        super().__init__()
        self.f = torch.nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.f(x[:, 0, 0, :5].float())


def _probe_samples(n_eps: int, steps: int, seed: int, scramble: bool = False) -> dict:
    """Samples whose pixels encode the probe targets linearly (or, scrambled, belong to other samples)."""
    from omcrl.pretrain.probe import probe_targets

    rng = np.random.default_rng(seed)
    n = n_eps * steps
    priv = rng.normal(0, 2, (n, 6)).astype(np.float32)
    depth = rng.uniform(0.5, 8.0, (n, 16, 16)).astype(np.float32)
    t = probe_targets(priv, depth)
    rgb = np.zeros((n, 3, 16, 16), np.uint8)
    lo, hi = np.array([0.0, -1, -1, 0, -8]), np.array([12.0, 1, 1, 8, 8])  # one scale for every setting
    rgb[:, 0, 0, :5] = np.round(np.clip((t - lo) / (hi - lo), 0, 1) * 255)
    if scramble:
        rgb = rgb[rng.permutation(n)]
    return {"rgb": rgb, "privileged": priv, "depth": depth, "episode": np.repeat(np.arange(n_eps), steps)}


def test_probe_fitted_in_box_is_tested_in_every_setting():
    from omcrl.interpret.shift import pilot_samples, probe_across
    from omcrl.pretrain.probe import TARGETS

    samples = {"box": _probe_samples(10, 40, 0), "same look": _probe_samples(4, 40, 1),
               "scrambled": _probe_samples(4, 40, 2, scramble=True)}  # fmt: skip
    df = probe_across(_ReadsPixels(), samples, alpha=1e-3)
    r2 = df.pivot(index="setting", columns="target", values="r2")
    assert list(df.setting.unique()) == ["box", "same look", "scrambled"] and set(r2.columns) == set(TARGETS)
    assert (r2.loc["box"] > 0.99).all() and (r2.loc["same look"] > 0.99).all()  # geometry carries over
    assert (r2.loc["scrambled"] < 0.1).all()  # features unrelated to the geometry: no better than the mean
    with pytest.raises(KeyError, match="reference setting 'box'"):
        probe_across(_ReadsPixels(), {"tree": samples["box"]})
    with pytest.raises(KeyError, match="lack 'privileged'"):
        probe_across(_ReadsPixels(), {"box": samples["box"], "tree": {"rgb": samples["box"]["rgb"]}})
    from omcrl.viz.shift import plot_probe_across

    fig = plot_probe_across(df.assign(encoder="pixels"), target="depth_ahead")
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["box", "same look", "scrambled"]
    assert f"{r2.loc['box', 'depth_ahead']:.2f}" in [t.get_text() for t in fig.axes[0].texts]
    with pytest.raises(ValueError, match="no rows for target 'nope'"):
        plot_probe_across(df.assign(encoder="pixels"), target="nope")
    # The env gives what the probe needs: the privileged vector and the newest depth frame per kept stack.
    cfg = load_config("smoke")
    s = pilot_samples("box", 1, seed=3, env_config=cfg.env, max_steps=10, privileged=True)
    size = cfg.env.image_size
    assert s["privileged"].shape == (len(s["rgb"]), 6) and s["depth"].shape == (len(s["rgb"]), size, size)


def test_disturbed_evaluations_have_their_own_cache_and_undisturbed_keys_do_not_change(tmp_path):
    from omcrl.eval.stage import evaluate_methods

    cfg = load_config("smoke", overrides={"results_dir": str(tmp_path), "eval": {"workers": 1}})
    own = evaluate_methods(cfg, {"HybridAPF": "HybridAPF"}, ["box"], 2)
    folder = tmp_path / "smoke" / "eval" / "HybridAPF" / "seed0"
    (plain,) = folder.glob("box-v2-*/episodes.csv")
    look = {"appearance": "furniture-v0", "appearance_parts": "surroundings"}
    swapped = evaluate_methods(cfg, {"HybridAPF": "HybridAPF"}, ["box"], 2, disturbance=look)
    (cached,) = folder.glob("box-v2-furniture-v0-surroundings-*/episodes.csv")
    # The undisturbed cache keeps its file; the swapped look is another evaluation of the same layouts.
    runs = sorted(p.parent.name for p in folder.glob("*/episodes.csv"))
    assert runs == sorted([plain.parent.name, cached.parent.name])
    np.testing.assert_allclose(own["optimal_path_length"], swapped["optimal_path_length"])
    mtime = cached.stat().st_mtime_ns
    again = evaluate_methods(cfg, {"HybridAPF": "HybridAPF"}, ["box"], 2, disturbance=look)
    assert cached.stat().st_mtime_ns == mtime  # read from the cache
    cols = ["final_distance", "success", "collision", "steps", "path_length"]
    np.testing.assert_allclose(again[cols].to_numpy(float), swapped[cols].to_numpy(float), rtol=1e-6)
    # A planner has no checkpoint: the cached rows say "" like the fresh ones (not NaN).
    assert list(again.checkpoint) == list(swapped.checkpoint) == ["", ""]


def test_transfer_stage_names_the_missing_run_before_any_work(tmp_path):
    from omcrl.interpret import transfer
    from omcrl.rl.policy import CheckpointError

    cfg = load_config("smoke", overrides={"results_dir": str(tmp_path)})
    with pytest.raises(CheckpointError, match="train --method ours --preset smoke --seed 0"):
        transfer.transfer_stage(cfg)
    assert not (tmp_path / "smoke" / "tables").exists()
    assert transfer.pilot_episodes(cfg) == 2 and transfer.pilot_episodes(load_config("quick")) == 12


# Regenerate only for an intended geometry change, justified in docs/DEVIATIONS.md:
#   geometry_stats(scene, eval_seeds(4, 0, 1_000_000)) for each scene, float_format="%.6f".
GEOMETRY_REFERENCE = Path(__file__).parent / "data" / "geometry_stats.csv"


def test_scene_geometry_statistics_unchanged():
    """Obstacle count, occupied/blocked share at flight altitude and shortest path of Table I's first evaluation
    layouts, pinned: look changes and refactors must leave what the drone can fly through alone."""
    ref = pd.read_csv(GEOMETRY_REFERENCE)
    got = pd.concat([geometry_stats(s, sorted(ref.seed.unique())) for s in ref.scene.unique()], ignore_index=True)
    assert list(got.columns) == list(ref.columns)
    pd.testing.assert_frame_equal(got[["scene", "seed", "obstacles"]], ref[["scene", "seed", "obstacles"]])
    num = ["occupied_pct", "blocked_pct", "shortest_path_m", "straight_line_m"]
    np.testing.assert_allclose(got[num].to_numpy(), ref[num].to_numpy(), atol=2e-6)
    # The clutter ordering the diagnosis relies on: box is the most blocked scene at 1 m, furniture the least.
    summ = geometry_summary(got).set_index("scene")
    assert summ.blocked_pct.idxmax() == "box-v0" and summ.blocked_pct.idxmin() == "furniture-v0"
    assert (summ.shortest_path_m >= summ.straight_line_m - 1e-9).all()


def test_geometry_statistics_ignore_the_look():
    seeds = [1_000_000, 1_000_001]
    own = geometry_stats("furniture-v0", seeds)
    swapped = geometry_stats("furniture-v0", seeds, disturbance={"appearance": "box"})
    pd.testing.assert_frame_equal(own, swapped)


def test_by_detour_splits_success_by_how_far_the_path_bends():
    from omcrl.interpret.transfer import by_detour

    # Two layouts: a clear line (detour 1.0, flown in 3 of 4 episodes) and a wall in the way (1.5, never flown).
    ep = pd.DataFrame(
        {
            "method": "m",
            "scene": "barrier",
            "eval_seed": [1, 1, 1, 1, 2, 2, 2, 2],
            "train_seed": [0, 0, 1, 1, 0, 0, 1, 1],
            "success": [True, True, True, False, False, False, False, False],
            "collision": [False, False, False, True, True, True, False, True],
            "final_distance": 1.0,
            "min_distance": 1.0,
            "path_length": 5.0,
            "optimal_path_length": 5.0,
            "steps": 100,
        }
    )
    detour = pd.Series([1.0, 1.5], index=pd.MultiIndex.from_tuples([("barrier", 1), ("barrier", 2)]))
    got = by_detour(ep, detour, reps=100).set_index("detour")
    assert list(got.index) == ["1.00–1.02", "> 1.30"]  # empty bins are left out, the rest in bin order
    assert got.loc["1.00–1.02", "SR"] == 75.0 and got.loc["> 1.30", "SR"] == 0.0
    assert got.loc["> 1.30", "CR"] == 75.0 and (got.layouts == 50.0).all() and (got.episodes == 4).all()
    assert got.loc["> 1.30", "TO"] == 25.0 and got.loc["1.00–1.02", "TO"] == 0.0  # ran out of steps, nothing else
    with pytest.raises(ValueError, match="no detour for layouts"):
        by_detour(ep.assign(eval_seed=3), detour)
