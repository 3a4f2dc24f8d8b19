"""The methods of Table I: every learned baseline trains on the real env at smoke size and its checkpoint
evaluates; the run registry separates configurations; prerequisites fail clearly before training.

One module-scoped grid (smoke data, three encoders, the oracle and every method at 256 env steps) is shared.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from omcrl.config import ConfigError, load_config
from omcrl.data import collect
from omcrl.eval import evaluate_grid, write_table1
from omcrl.models.features import make_pixel_features
from omcrl.pipeline import pretrain_method, train_method
from omcrl.pipeline.stages import collect_stage
from omcrl.rl import CheckpointError, RunConfigMismatch, load_policy
from omcrl.rl.methods import (
    METHODS,
    TABLE1_METHODS,
    encoder_path,
    final_policy_path,
    oracle_path,
    training_runs,
)
from omcrl.rl.train import oracle_run, policy_run
from omcrl.utils.io import file_digest
from omcrl.utils.runtime import seed_everything

torch.set_num_threads(1)
LEARNED = [m for m, s in METHODS.items() if s.learned]


def _cfg(root, *more):
    return load_config(
        "smoke",
        overrides=[f"results_dir={root}", f"data.file={root}/box.h5", "rl.total_steps=256", "eval.episodes=1", *more],
    )


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    root = tmp_path_factory.mktemp("methods")
    cfg = _cfg(root)
    collect.collect_dataset(cfg, progress=False)
    digests = {}
    for m in [m for m, s in METHODS.items() if s.features == "frozen"]:  # ablation variants included
        pretrain_method(cfg, m, progress=False)
        digests[m] = file_digest(encoder_path(cfg, m))
    results = {m: train_method(cfg, m, progress=False) for m in LEARNED}
    return {"cfg": cfg, "root": root, "results": results, "digests": digests}


def test_every_learned_method_trains_and_its_checkpoint_evaluates(grid):
    cfg, results = grid["cfg"], grid["results"]
    for m, r in results.items():
        assert r.final_path.exists() and r.steps == 256, m
        assert final_policy_path(cfg, m) == r.final_path, m  # found again from the config alone
        ident = json.loads((r.run_dir / "run.json").read_text())
        assert ident["method"] == m and ident["seed"] == 0
    # Distinct runs for distinct methods, all under runs/rl.
    assert len({r.run_dir for r in results.values()}) == len(LEARNED)
    episodes, missing = evaluate_grid(cfg, scenes=["box"])
    assert missing == []
    # Table I: every method but the ablation variants (trained above too, evaluated by the sweeps).
    assert set(episodes.method) == set(TABLE1_METHODS) and len(episodes) == len(TABLE1_METHODS)
    assert episodes.groupby("method").eval_seed.first().nunique() == 1  # the same episode for all
    table, sig, paths = write_table1(episodes, grid["root"] / "tables", reps=200)
    assert set(sig.method) == set(TABLE1_METHODS) - {"ours"}
    md = paths["md"].read_text()
    assert "| Ours |" in md and "**" in md
    assert paths["tex"].read_text().count("\\\\") == len(TABLE1_METHODS) + 2


def test_end_to_end_methods_train_their_encoder_and_frozen_ones_do_not(grid):
    cfg, results = grid["cfg"], grid["results"]
    # The initial pixel encoder of a run: the trainer seeds everything, then builds the features first.
    from omcrl.envs import make_vec_env

    env = make_vec_env("box", 1, seed=0, config=cfg.env)
    space = env.single_observation_space
    env.close()
    seed_everything(cfg.seed)
    init = make_pixel_features(space, cfg.pretrain.crop_to, cfg.pretrain.feature_dim).encoder.state_dict()
    for m in ("ppo", "npe", "npe-ot"):
        trained = load_policy(results[m].final_path).agent.features.encoder.state_dict()
        assert set(trained) == set(init)
        assert any(not torch.equal(init[k], trained[k]) for k in init), f"{m}: encoder weights unchanged"
    for m in ("curl", "curl-phi", "ours", "ours-noOT"):
        pol = load_policy(results[m].final_path)
        # The frozen encoder is not in the policy's weights, its file is unchanged, and the policy uses it.
        assert not any(k.startswith("features.") for k in pol.agent.state_dict()), m
        enc_key = m if m in grid["digests"] else "ours"
        assert file_digest(encoder_path(cfg, enc_key)) == grid["digests"][enc_key]
        assert file_digest(pol.agent.features.encoder_path) == grid["digests"][enc_key]


def test_registry_separates_configs_that_change_the_artifact(grid):
    cfg = grid["cfg"]
    base = oracle_run(cfg)
    # feature_dim sets the oracle's depth-encoder width: another folder (the reported defect).
    assert oracle_run(_cfg(grid["root"], "pretrain.feature_dim=48")).dir != base.dir
    for changed in (
        "rl.total_steps=512",
        "env.max_steps=61",
        "oracle.guide=none",
        "rl.lr=0.001",
        "oracle.alpha_decay_steps=77",
        "oracle.guide_std=0.3",
    ):
        assert oracle_run(_cfg(grid["root"], changed)).dir != base.dir, changed
    # Fields that do not change what is trained: the same folder.
    same_artifact = ("rl.checkpoint_every=128", "rl.update_threads=1", "eval.episodes=7", "eval.workers=1")
    # A student's guidance is not the oracle's: the decay ablation keeps the comparison's oracle.
    students = ("rl.alpha_decay_steps=77", "rl.alpha_schedule=exp", "rl.beta=0.5", "rl.guide_std=0.3")
    for same in (*same_artifact, *students, "pretrain.iterations=99", "seeds=[0,1]"):
        assert oracle_run(_cfg(grid["root"], same)).dir == base.dir, same
    # Another seed: same parent (method and key), its own seed folder.
    other = oracle_run(cfg.with_seed(3))
    assert other.dir.parent == base.dir.parent and other.dir.name == "seed3"
    # An unguided method's folder ignores the guidance schedule; a guided one's does not.
    enc = encoder_path(cfg, "curl")
    unguided = policy_run(cfg, "curl", enc)
    assert policy_run(_cfg(grid["root"], "rl.alpha_decay_steps=77"), "curl", enc).dir == unguided.dir
    guided = policy_run(cfg, "ours", enc, oracle_path(cfg))
    assert policy_run(_cfg(grid["root"], "rl.alpha_decay_steps=77"), "ours", enc, oracle_path(cfg)).dir != guided.dir
    # The encoder enters by content: another encoder file means another run.
    assert policy_run(cfg, "curl", encoder_path(cfg, "curl-phi")).dir != unguided.dir


def test_finished_runs_are_reused_and_never_overwritten_by_another_config(grid):
    cfg, results = grid["cfg"], grid["results"]
    before = file_digest(results["curl"].final_path)
    again = train_method(cfg, "curl", progress=False)
    assert again.skipped and again.final_path == results["curl"].final_path
    # A different config trains in its own folder and leaves the finished run alone.
    other = train_method(_cfg(grid["root"], "rl.total_steps=128"), "curl", progress=False)
    assert other.run_dir != results["curl"].run_dir and other.steps == 128
    assert file_digest(results["curl"].final_path) == before
    # A folder whose record says another configuration is refused, not reused or overwritten.
    rec = results["curl"].run_dir / "run.json"
    saved = rec.read_text()
    try:
        rec.write_text(json.dumps({**json.loads(saved), "key": "0000000000"}))
        with pytest.raises(RunConfigMismatch, match="run.json|key"):
            train_method(cfg, "curl", progress=False)
        assert file_digest(results["curl"].final_path) == before
    finally:
        rec.write_text(saved)


def test_corrupt_finished_policy_is_not_trusted(grid):
    # A final.pt changed after it was written is moved aside and the run trained again (same result).
    cfg, r = grid["cfg"], grid["results"]["ppo"]
    good = file_digest(r.final_path)
    r.final_path.write_bytes(r.final_path.read_bytes()[:1000])
    with pytest.warns(UserWarning, match="does not match the digest"):
        again = train_method(cfg, "ppo", progress=False)
    assert not again.skipped and (r.run_dir / "final.pt.corrupt").exists()
    assert file_digest(again.final_path) == good  # same seed, same config: bit-identical retraining
    assert train_method(cfg, "ppo", progress=False).skipped


def test_prerequisites_and_bad_names_fail_before_training(grid, tmp_path):
    cfg = _cfg(tmp_path)
    with pytest.raises(ConfigError, match="known methods"):
        train_method(cfg, "curl2", progress=False)
    with pytest.raises(CheckpointError, match=r"curl encoder .*pretrain --method curl"):
        train_method(cfg, "curl", progress=False)
    with pytest.raises(CheckpointError, match=r"oracle checkpoint .*train --method oracle"):
        train_method(cfg, "npe-ot", progress=False)
    with pytest.raises(ConfigError, match="planner"):
        train_method(cfg, "hybrid-apf", progress=False)
    assert not (tmp_path / "smoke" / "runs").exists()  # nothing that looks like a run was started


def test_guide_of_the_wrong_shape_is_refused_before_training(grid, tmp_path):
    # An oracle trained on 24 px depth cannot guide a 32 px student: clear error, no run folder.
    cfg = grid["cfg"]
    small = _cfg(grid["root"], "env.image_size=24", "pretrain.crop_from=24", "pretrain.crop_to=20")
    bad = train_method(small, "oracle", progress=False).final_path
    from omcrl.rl.train import train_visuomotor

    with pytest.raises(CheckpointError, match=r"depth: checkpoint \[\d+, 24, 24\]"):
        train_visuomotor(cfg, None, bad, name="npe-ot-bad", progress=False)
    assert not list((grid["root"] / "smoke" / "runs" / "rl").glob("npe-ot-bad-*"))


def test_training_runs_and_seeds_field(grid):
    cfg = grid["cfg"]
    runs = training_runs(cfg)
    assert set(runs) == {m for m in TABLE1_METHODS if METHODS[m].learned} and all(list(v) == [0] for v in runs.values())
    assert training_runs(cfg.with_seed(0), seeds=[5]) == {}
    with pytest.raises(ConfigError, match="seeds"):
        load_config("smoke", overrides=["seeds=[]"])
    with pytest.raises(ConfigError, match="seeds"):
        load_config("smoke", overrides=["seeds=[0,0]"])
    assert load_config("paper").seeds == [0, 1, 2] and load_config("quick").seeds == [0]
    assert np.array_equal(load_config("smoke", overrides=["seeds=[2,0]"]).seeds, [2, 0])


def test_every_visuomotor_method_exports_to_onnx_with_parity(grid, tmp_path):
    from omcrl.deploy import ExportError, OnnxPolicy, export_onnx

    rng = np.random.default_rng(0)
    cfg = grid["cfg"]
    obs = [
        {
            "rgb": rng.integers(0, 256, (cfg.env.frame_stack, 3, 32, 32), dtype=np.uint8),
            "state": rng.normal(size=12).astype(np.float32),
        }
        for _ in range(20)
    ]
    for m, r in grid["results"].items():
        if m == "oracle":
            with pytest.raises(ExportError, match="privileged"):
                export_onnx(r.run_dir, tmp_path / "oracle.onnx")
            continue
        pol, ref = OnnxPolicy(export_onnx(r.run_dir, tmp_path / f"{m}.onnx")), load_policy(r.final_path)
        assert max(np.abs(pol.act(o) - ref.act(o)).max() for o in obs) <= 1e-4, m


def test_pretraining_identity_ignores_where_the_data_lives(grid, tmp_path):
    from omcrl.pretrain import pretrain_run

    cfg = grid["cfg"]
    moved = _cfg(grid["root"], f"data.file={tmp_path}/elsewhere.h5")
    assert pretrain_run(moved).dir == pretrain_run(cfg).dir
    assert pretrain_run(_cfg(grid["root"], "data.episodes=7")).dir != pretrain_run(cfg).dir


def test_data_flown_by_the_trained_oracle(grid):
    # data.policy=oracle: the policy share of the mix is flown by this seed's oracle, into a file of its own.
    cfg = grid["cfg"]
    oc = _cfg(grid["root"], "data.episodes=2", "data.max_steps=10", "data.mix={policy: 1.0}", "data.policy=oracle")
    assert oc.data_path.name == "box-oracle-seed0.h5" and oc.with_seed(1).data_path.name == "box-oracle-seed1.h5"
    assert oracle_path(oc) == oracle_path(cfg)  # the data fields are not the oracle's identity
    res = collect_stage(oc, progress=False)
    assert res.per_source == {"policy": 2} and res.path == oc.data_path and cfg.data_path.exists()
    from omcrl.pretrain.train import pretrain_run

    assert pretrain_run(oc).key != pretrain_run(cfg).key  # other data, another encoder run
    # No oracle at seed 7: a clear error before any file is written.
    with pytest.raises(ConfigError, match=r"oracle of this config at seed 7 is not trained"):
        collect_stage(oc.with_seed(7), progress=False)
    # The data layer itself takes a policy and never looks for the oracle: without one it says who passes it.
    with pytest.raises(ConfigError, match=r"no policy was passed \(data.policy='oracle': the collect stage"):
        collect.collect_dataset(oc.with_seed(7), progress=False)
    assert not oc.with_seed(7).data_path.exists()
