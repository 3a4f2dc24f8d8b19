"""Oracle → guided student → evaluation on the real PyBullet env at smoke sizes (32 px, 2 envs, 512 steps).

One module-scoped chain keeps the whole file well under a minute: the oracle and the student are trained once
and shared by the tests below.
"""

from __future__ import annotations

import importlib
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from omcrl.config import load_config
from omcrl.eval import evaluate, summarize
from omcrl.models import load_encoder, random_encoder, save_encoder
from omcrl.planners import HybridAPF
from omcrl.rl import CheckpointError, load_policy, train_oracle, train_visuomotor
from omcrl.rl.policy import make_oracle_features, policy_payload
from omcrl.rl.ppo import ActorCritic

torch.set_num_threads(1)
# The module, not the function ``omcrl.rl.train`` that the package re-exports under the same name.
rl_train = importlib.import_module("omcrl.rl.train")


def _save_random_encoder(path: Path, cfg) -> Path:
    enc = random_encoder(cfg, seed=cfg.seed)
    return save_encoder(path, enc.f, enc.phi, cfg)


def _state(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in module.state_dict().items()}


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    root = tmp_path_factory.mktemp("integration")
    cfg = load_config("smoke", overrides=[f"results_dir={root}"])
    oracle = train_oracle(cfg, progress=False)
    enc_path = _save_random_encoder(root / "encoder.pt", cfg)
    before = _state(load_encoder(enc_path, cfg.env.image_size, cfg.env.frame_stack))

    # Keep a handle on the encoder object the trainer really uses, to check it is not updated in place.
    used: list = []
    real = rl_train.make_student_features

    def spy(path, space):
        feats = real(path, space)
        used.append(feats)
        return feats

    rl_train.make_student_features = spy
    try:
        student = train_visuomotor(cfg, enc_path, oracle.final_path, name="ours", progress=False)
    finally:
        rl_train.make_student_features = real
    return {
        "cfg": cfg,
        "root": root,
        "oracle": oracle,
        "student": student,
        "enc_path": enc_path,
        "before": before,
        "used": used,
    }


def test_oracle_and_guided_student_train_on_real_env(chain):
    cfg, oracle, student = chain["cfg"], chain["oracle"], chain["student"]
    assert oracle.final_path.exists() and student.final_path.exists()
    assert oracle.steps == student.steps == cfg.rl.total_steps  # 512 = 4 updates of 128 transitions
    m = pd.read_csv(student.metrics_path)
    alpha = m[m.metric == "alpha"].sort_values("step").value.to_numpy()
    assert alpha[0] == pytest.approx(cfg.rl.alpha_start) and alpha[-1] < alpha[0]
    kl = m[m.metric == "kl"].value.to_numpy()
    assert len(kl) and np.isfinite(kl).all() and (kl > 0).any()
    spec = torch.load(student.final_path, weights_only=True)["spec"]["features"]
    assert spec["kind"] == "student" and spec["encoder_path"] == str(chain["enc_path"])


def test_frozen_encoder_is_unchanged_by_student_training(chain):
    before = chain["before"]
    (feats,) = chain["used"]
    # The encoder object the trainer used, and the file on disk, still hold the initial weights.
    for state in (_state(feats.encoder), _state(load_encoder(chain["enc_path"]))):
        assert state.keys() == before.keys()
        for k, v in before.items():
            assert torch.equal(state[k], v), k
    # ... and it is not part of the optimised / saved student parameters.
    pol = load_policy(chain["student"].final_path)
    assert not any(k.startswith("features.encoder") for k in pol.agent.state_dict())


def test_missing_or_mismatched_encoder_and_oracle_name_the_file(chain, tmp_path):
    cfg, oracle, enc = chain["cfg"], chain["oracle"], chain["enc_path"]
    kw = {"progress": False}
    with pytest.raises(CheckpointError, match=r"no_encoder\.pt"):
        train_visuomotor(cfg, tmp_path / "no_encoder.pt", oracle.final_path, name="a", **kw)
    junk = tmp_path / "junk_encoder.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match=r"junk_encoder\.pt"):
        train_visuomotor(cfg, junk, oracle.final_path, name="b", **kw)
    # An encoder for 48 px images does not fit the 32 px env.
    cfg48 = load_config("smoke", overrides=["env.image_size=48", "pretrain.crop_from=48", "pretrain.crop_to=40"])
    enc48 = _save_random_encoder(tmp_path / "enc48.pt", cfg48)
    with pytest.raises(CheckpointError, match=r"enc48\.pt.*image_size"):
        train_visuomotor(cfg, enc48, oracle.final_path, name="c", **kw)
    with pytest.raises(CheckpointError, match=r"no_oracle\.pt"):
        train_visuomotor(cfg, enc, tmp_path / "no_oracle.pt", name="d", **kw)
    # An oracle built for 24 px depth stacks (untrained is enough: only its spec is checked).
    import gymnasium as gym

    space = gym.spaces.Dict(
        {
            "depth": gym.spaces.Box(0.0, 20.0, (cfg.env.frame_stack, 24, 24), np.float32),
            "state": gym.spaces.Box(-np.inf, np.inf, (12,), np.float32),
            "privileged": gym.spaces.Box(-np.inf, np.inf, (6,), np.float32),
        }
    )
    agent = ActorCritic(make_oracle_features(space, cfg.pretrain.feature_dim, cfg.env.far), 3, cfg.rl.hidden)
    bad = tmp_path / "oracle24.pt"
    torch.save(policy_payload(agent, {k: list(s.shape) for k, s in space.spaces.items()}, 0), bad)
    with pytest.raises(CheckpointError, match=r"oracle24\.pt.*depth"):
        train_visuomotor(cfg, enc, bad, name="e", **kw)
    # No run folder was started for any of the failed runs.
    runs = chain["root"] / cfg.preset / "runs" / "rl"
    assert sorted(p.name.rsplit("-", 1)[0] for p in runs.iterdir()) == ["oracle", "ours"]


def test_hybrid_apf_as_npe_guide_gets_each_episodes_reset_path():
    # PlannerGuide on the real vector env (next-step autoreset): every new episode hands its reset info to
    # HybridAPF.reset, so the planner follows that episode's shortest path, not the previous one's.
    from omcrl.envs import make_vec_env
    from omcrl.rl import PlannerGuide

    cfg = load_config("smoke", overrides=["env.max_steps=15"])

    class Recording(HybridAPF):
        def reset(self, info=None):
            self.last_reset_path = None if info is None else info.get("path")
            super().reset(info)

    env = make_vec_env("box", 2, seed=3, config=cfg.env)
    try:
        guide = PlannerGuide(lambda: Recording(cfg.env), cfg.rl.guide_std, n_envs=2)
        obs, infos = env.reset(seed=3)
        starts, dummy, n_starts = np.ones(2, bool), np.zeros(2, bool), 0
        for _ in range(40):
            mean, std = guide.distribution(obs, infos, starts)
            assert mean.shape == std.shape == (2, 3) and np.all(np.abs(mean) <= 1.0)
            for i in np.flatnonzero(starts):
                planner, path = guide.planners[i], np.asarray(infos["path"][i], float)
                np.testing.assert_allclose(np.asarray(planner.last_reset_path, float), path)
                np.testing.assert_allclose(planner.path, path)
                n_starts += 1
            obs, _, term, trunc, infos = env.step(mean)
            done = (term | trunc) & ~dummy
            starts, dummy = dummy.copy(), done
    finally:
        env.close()
    assert n_starts >= 4  # the first two episodes and at least two restarts


def test_evaluate_binds_hybrid_apf_to_the_eval_env():
    cfg = load_config("smoke")
    planner = HybridAPF(cfg.env)
    df = evaluate(planner, "barrier", 1, seed_offset=cfg.eval.seed_offset, config=cfg.env)
    assert planner._env is not None and planner._env.scene == "barrier-v2"  # a family is its latest version
    assert len(planner.path) >= 2 and len(df) == 1


def test_oracle_guide_in_chunks_matches_per_step_guide(chain):
    # The rollout evaluates the oracle guide once per chunk of steps; the result must equal per-step evaluation.
    from omcrl.envs import make_vec_env
    from omcrl.rl import PolicyGuide
    from omcrl.rl.policy import make_student_features

    cfg = chain["cfg"]
    oracle = load_policy(chain["oracle"].final_path, expect_kind="oracle")
    means = []
    for chunk in (1, 64):
        env = make_vec_env("box", 2, seed=5, config=cfg.env)
        try:
            torch.manual_seed(0)
            feats = make_student_features(chain["enc_path"], env.single_observation_space)
            agent = ActorCritic(feats, 3, cfg.rl.hidden)
            runner = rl_train.Runner(env, agent, PolicyGuide(oracle.agent), seed=5, guide_chunk=chunk)
            rollout = runner.collect(40, cfg.rl.horizon, use_guide=True)
        finally:
            env.close()
        assert rollout.guide_mean.shape == rollout.guide_std.shape == (40, 2, 3)
        means.append(rollout.guide_mean)
    torch.testing.assert_close(means[0], means[1], rtol=1e-4, atol=1e-5)


def test_evaluate_stage_finds_policies_writes_tables_and_caches(chain, monkeypatch):
    import omcrl.eval.stage as stage

    cfg = load_config(
        "smoke", overrides=[f"results_dir={chain['root']}", "eval.scenes=[box, barrier]", "eval.episodes=2"]
    )
    assert list(stage.find_policies(cfg)) == ["oracle", "ours"]
    res = stage.evaluate_stage(cfg, progress=False)
    assert list(res.table.index) == [(m, s) for m in ("oracle", "ours", "HybridAPF") for s in ("box-v2", "barrier-v2")]
    wide = res.wide()
    assert list(wide.columns.get_level_values(0).unique()) == ["box-v2", "barrier-v2"]  # paper order, not sorted
    md = res.paths["md"].read_text()
    assert "| method | box-v2 NE | box-v2 OS | box-v2 SR |" in md and md.count("\n| ") == 4
    # One writer per table file: evaluate writes its one-seed table under its own name, never Table I's.
    tables = chain["root"] / "smoke" / "tables"
    assert res.paths["md"] == tables / "evaluate_seed0.md" and not list(tables.glob("table1*"))
    with pytest.raises(ValueError, match="only `python -m omcrl tables` writes table1"):
        stage.evaluate_stage(cfg, name="table1", progress=False)
    # A Table I file in another form is one line in the summary, not a traceback.
    from omcrl.pipeline.summary import summary_text

    res.paths["csv"].rename(tables / "table1.csv")
    assert "_Table I cannot be read: " in summary_text(cfg) and "by `python -m omcrl tables`" in summary_text(cfg)
    (tables / "table1.csv").unlink()
    df = res.episodes
    assert len(df) == len(pd.read_csv(res.paths["episodes"])) == 12
    # Every method flies the same evaluation layouts.
    assert df.groupby("method").eval_seed.apply(tuple).nunique() == 1
    s = summarize(df[(df.method == "HybridAPF") & (df.scene == "box-v2")])
    assert s["episodes"] == 2 and 0.0 <= s["SR"] <= 100.0 and math.isfinite(s["NE"])
    # A second run reads every (method, scene) from the cache instead of flying the episodes again.
    monkeypatch.setattr(stage, "evaluate", lambda *a, **k: pytest.fail("cache miss"))
    again = stage.evaluate_stage(cfg, progress=False)
    pd.testing.assert_frame_equal(again.table, res.table)


def test_evaluation_cache_keeps_each_checkpoint_under_one_label(chain, monkeypatch, tmp_path):
    """A sweep evaluates several checkpoints under one label (the variants of ``ours``): evaluating the second
    must not evict the first, so a re-run of the first reads its cache."""
    import omcrl.eval.stage as stage

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}", "eval.scenes=[box]", "eval.episodes=2"])
    first = stage.evaluate_methods(cfg, {"ours": chain["oracle"].final_path})
    second = stage.evaluate_methods(cfg, {"ours": chain["student"].final_path})
    assert len(list((cfg.run_root / "eval" / "ours" / "seed0").glob("box-*/episodes.csv"))) == 2
    monkeypatch.setattr(stage, "evaluate", lambda *a, **k: pytest.fail("cache miss"))
    _same_episodes(stage.evaluate_methods(cfg, {"ours": chain["oracle"].final_path}), first)
    _same_episodes(stage.evaluate_methods(cfg, {"ours": chain["student"].final_path}), second)


def _same_episodes(cached: pd.DataFrame, fresh: pd.DataFrame) -> None:
    """Cached episodes equal fresh ones; trajectories are stored rounded to the millimetre."""
    pd.testing.assert_frame_equal(cached.drop(columns="trajectory"), fresh.drop(columns="trajectory"))
    for a, b in zip(cached.trajectory, fresh.trajectory, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=6e-4)
