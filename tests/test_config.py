"""Config: presets load, bad values are rejected with a message naming field and value, save/load round trip,
and the CLI turns a bad ``--set`` into exit code 2 without a traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

from omcrl.config import PRESETS, Config, ConfigError, load_config, project_root, save_config


@pytest.mark.parametrize("preset", PRESETS)
def test_presets_load(preset):
    cfg = load_config(preset)
    assert isinstance(cfg, Config)
    assert cfg.preset == preset
    assert cfg.run_root == project_root() / "results" / preset
    assert cfg.pretrain.crop_to <= cfg.pretrain.crop_from
    assert cfg.rl.minibatch <= cfg.rl.buffer_size


def test_presets_scale_up():
    smoke, quick, paper = (load_config(p) for p in ("smoke", "quick", "paper"))
    assert smoke.env.image_size < quick.env.image_size < paper.env.image_size
    assert smoke.rl.total_steps < quick.rl.total_steps < paper.rl.total_steps
    assert paper.env.image_size == 224 and paper.pretrain.crop_to == 192
    assert paper.eval.episodes == 200


@pytest.mark.parametrize(
    ("override", "field", "value"),
    [
        ("env.scene=moon", "env.scene", "moon"),
        ("env.image_size=8", "env.image_size", "8"),
        ("env.frame_stack=0", "env.frame_stack", "0"),
        ("pretrain.use_projection=maybe", "pretrain.use_projection", "maybe"),
        ("pretrain.mask_prob=.nan", "pretrain.mask_prob", "nan"),
        ("rl.lr=fast", "rl.lr", "fast"),
        ("env.image_size=32.5", "env.image_size", "32.5"),
        ("data.scene=forest", "data.scene", "forest"),
    ],
)
def test_bad_values_name_field_and_value(override, field, value):
    with pytest.raises(ConfigError) as e:
        load_config("smoke", overrides=[override])
    msg = str(e.value)
    assert field in msg and value in msg


def test_unknown_field_is_named():
    with pytest.raises(ConfigError, match=r"env\.wings.*does not exist"):
        load_config("smoke", overrides=["env.wings=2"])
    with pytest.raises(ConfigError, match="nosection"):
        load_config("smoke", overrides={"nosection": {"x": 1}})
    # A run's config.yaml from before a field moved names where it went.
    with pytest.raises(ConfigError, match=r"'rl\.oracle_guide' does not exist \(it is now 'oracle\.guide'\)"):
        load_config("smoke", overrides={"rl": {"oracle_guide": "apf"}})


def test_nan_float_from_a_mapping():
    with pytest.raises(ConfigError, match=r"pretrain\.temperature.*nan"):
        load_config("smoke", overrides={"pretrain": {"temperature": float("nan")}})


def test_bad_preset():
    with pytest.raises(ConfigError, match="nope"):
        load_config("nope")


def test_good_override_applies():
    cfg = load_config("smoke", overrides=["env.image_size=48", "pretrain.use_projection=false"])
    assert cfg.env.image_size == 48 and cfg.pretrain.use_projection is False


def test_save_and_load_round_trip(tmp_path):
    cfg = load_config(
        "smoke",
        overrides=[
            "env.scene=tree",
            "env.goal_distance=[3, 6]",
            "rl.beta=0.5",
            "data.mix={pilot: 1.0, random: 0.0, policy: 0.0}",
            "seed=7",
        ],
    )
    path = save_config(cfg, tmp_path / "run")
    assert path == tmp_path / "run" / "config.yaml"
    assert yaml.safe_load(path.read_text())["env"]["scene"] == "tree-v2"  # a family is stored as its latest id
    again = load_config("smoke", path=path)
    assert again == cfg
    assert again.to_dict() == cfg.to_dict()
    # saving the reloaded config gives the same file
    assert save_config(again, tmp_path / "again").read_text() == path.read_text()


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "omcrl", *args], capture_output=True, text=True, timeout=120, cwd=cwd)


def test_cli_bad_set_exits_2_with_message(repo_root):
    r = _cli("config", "--preset", "smoke", "--set", "env.image_size=8", cwd=repo_root)
    assert r.returncode == 2
    assert "env.image_size" in r.stderr and "8" in r.stderr
    assert "Traceback" not in r.stderr


def test_cli_unknown_field_exits_2(repo_root):
    r = _cli("config", "--preset", "smoke", "--set", "env.wings=2", cwd=repo_root)
    assert r.returncode == 2 and "env.wings" in r.stderr and "Traceback" not in r.stderr


def test_cli_config_prints_resolved_yaml(repo_root, tmp_path):
    r = _cli("config", "--preset", "smoke", "--set", "env.image_size=48", cwd=repo_root)
    assert r.returncode == 0, r.stderr
    data = yaml.safe_load(r.stdout)
    assert data["preset"] == "smoke" and data["env"]["image_size"] == 48
    # the printed YAML is a valid --config file
    f = tmp_path / "c.yaml"
    f.write_text(r.stdout)
    r2 = _cli("config", "--preset", "smoke", "--config", str(f), cwd=repo_root)
    assert r2.returncode == 0 and yaml.safe_load(r2.stdout) == data


def test_cli_unknown_stage_exits_2(repo_root):
    r = _cli("fly", "--preset", "smoke", cwd=repo_root)
    assert r.returncode == 2 and "unknown stage" in r.stderr


def test_stage_loader_reports_missing_stage():
    from omcrl.__main__ import STAGES, StageUnavailable, load_stage

    assert {"notebooks", "collect", "pretrain", "oracle", "student", "evaluate", "config"} <= set(STAGES)
    fake = {"later": ("omcrl.not_written_yet:run", ""), "nofunc": ("omcrl.config:no_such_function", "")}
    with pytest.raises(StageUnavailable, match="cannot be loaded"):
        load_stage("later", fake)
    with pytest.raises(StageUnavailable, match="no_such_function"):
        load_stage("nofunc", fake)
    assert callable(load_stage("config"))


def test_data_policy_oracle_needs_a_policy_share_and_keeps_default_keys():
    with pytest.raises(ConfigError, match=r"data.policy.*no weight"):
        load_config("smoke", overrides=["data.policy=oracle"])
    with pytest.raises(ConfigError, match="data.policy"):
        load_config("smoke", overrides=["data.policy=expert"])
    from omcrl.pretrain.train import pretrain_run

    # At its neutral default the new field leaves existing runs' keys alone.
    base = load_config("quick")
    assert "policy" not in pretrain_run(base).identity["data"]


def test_each_training_seed_pretrains_on_data_of_its_own():
    """The collection is seeded by the training seed, so the default data file names it: a file shared by every
    seed held whichever seed collected it first (the v2 grid's seed 3 pretrained on seed 2's data that way)."""
    from omcrl.pipeline.plan import sweep_plan
    from omcrl.pretrain.train import pretrain_run

    cfg = load_config("quick")
    paths = {cfg.with_seed(k).data_path for k in range(5)}
    assert len(paths) == 5 and cfg.with_seed(3).data_path.name == "box-seed3.h5"
    # A location, not identity: the run key is the same whatever the file is called.
    moved = cfg.with_overrides(["data.file=elsewhere/box.h5"])
    assert pretrain_run(moved).key == pretrain_run(cfg).key
    # A path without {seed} is one file for every seed (the user's choice); the oracle's data is per seed anyway.
    assert moved.with_seed(1).data_path == moved.with_seed(2).data_path
    oracle = cfg.with_overrides(["data.policy=oracle", "data.mix={pilot: 0.5, random: 0.2, policy: 0.3}"])
    assert oracle.with_seed(2).data_path.name == "box-seed2-oracle.h5"
    # A sweep over seeds collects once per seed, the budget ladder too (at each of its scales).
    for grid in ("table1", "ladder-pretrain"):
        plan = sweep_plan(cfg, [grid], [0, 1, 2])
        collect = plan[plan["kind"] == "collect"]
        per_scale = 1 if grid == "table1" else 2
        assert len(collect) == 3 * per_scale and collect["id"].is_unique, collect["id"].tolist()
