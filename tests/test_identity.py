"""One identity rule for runs and cached evaluations (issue 43): the fields of the sections a run reads that differ
from their defaults, less execution-only fields, plus the behaviour versions of the code it depends on."""

from __future__ import annotations

import copy
import dataclasses

import pytest

import omcrl.runs as R
from omcrl.config import (
    Config,
    ConfigError,
    DataConfig,
    EnvConfig,
    EvalConfig,
    GuidanceConfig,
    OracleConfig,
    PretrainConfig,
    RLConfig,
    _f,
    config_hash,
    load_config,
    section_identity,
    validate,
)
from omcrl.pretrain.train import pretrain_run
from omcrl.rl.methods import planner_factory
from omcrl.rl.train import oracle_run, policy_run

SECTIONS = {
    "env": EnvConfig,
    "data": DataConfig,
    "pretrain": PretrainConfig,
    "rl": RLConfig,
    "oracle": OracleConfig,
    "eval": EvalConfig,
}
GUIDANCE = {f.name for f in dataclasses.fields(GuidanceConfig)}


def _cfg(tmp_path, *overrides: str) -> Config:
    return load_config("quick", overrides=[f"results_dir={tmp_path}", *overrides])


def _keys(cfg: Config, tmp_path) -> dict[str, str]:
    """The keys of the runs a Table I grid opens: the oracle, the OMC encoder, a student on both, an unguided and a
    planner-guided pixel student."""
    enc, orc = tmp_path / "enc.pt", tmp_path / "oracle.pt"
    enc.write_bytes(b"encoder"), orc.write_bytes(b"oracle")
    return {
        "oracle": oracle_run(cfg).key,
        "encoder": pretrain_run(cfg).key,
        "student": policy_run(cfg, "ours", enc, orc).key,
        "ppo": policy_run(cfg, "ppo", None).key,
        "npe": policy_run(cfg, "npe", None, None, planner_factory(cfg, "local-apf")).key,
    }


def _other(section: type, f: dataclasses.Field, value):
    """A valid value of field ``f`` other than ``value`` (None when the field has no natural other value)."""
    md = f.metadata
    if f.name == "renderer":
        return "egl"  # "tiny" is what "auto" resolves to on a CPU: the same run
    if md.get("choices"):
        return next(c for c in md["choices"] if c != value)
    if f.name == "scene":
        return "tree-v2" if value != "tree-v2" else "box-v2"
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        hi = md.get("hi")
        return value + 1 if hi is None or value + 1 <= hi else value - 1
    if isinstance(value, float):
        hi = md.get("hi")
        new = value * 0.9 if value else 0.1
        return new if hi is None or new <= hi else value * 0.9
    if isinstance(value, tuple):
        return (value[0], value[1] + 1.0)
    if isinstance(value, str) and f.name == "file":
        return value + ".other"
    return None


def test_section_identity_is_the_fields_off_their_defaults_less_execution_only():
    assert section_identity(RLConfig()) == {}
    got = section_identity(RLConfig(lr=1e-4, num_threads=4, device="cpu", update_threads=3, checkpoint_every=7))
    assert got == {"lr": 1e-4}  # threads, device and checkpoint cadence are execution-only
    assert section_identity(EnvConfig(goal_distance=(4.0, 12.0)))["goal_distance"] == [4.0, 12.0]  # JSON-able
    # A machine-resolved value is compared resolved: "tiny" for the default "auto" is always in the identity.
    assert section_identity(EnvConfig(), renderer="tiny") == {"renderer": "tiny"}
    with pytest.raises(ConfigError, match="no field"):
        section_identity(EnvConfig(), rendrer="tiny")
    declared = {s: [f.name for f in dataclasses.fields(c) if f.metadata.get("execution")] for s, c in SECTIONS.items()}
    assert declared == {
        "env": [],
        "data": ["file"],
        "pretrain": ["checkpoint_every", "num_threads", "device"],
        "rl": ["checkpoint_every", "num_threads", "device", "update_threads"],
        "oracle": [],
        "eval": ["workers"],
    }


def test_a_field_added_at_its_default_changes_no_key(tmp_path):
    cfg = _cfg(tmp_path)
    before = _keys(cfg, tmp_path)
    sections = {
        "rl": RLConfig,
        "oracle": OracleConfig,
        "env": EnvConfig,
        "pretrain": PretrainConfig,
        "data": DataConfig,
    }
    for name, base in sections.items():
        grown = dataclasses.make_dataclass(
            f"Grown{base.__name__}", [("new_knob", float, _f(0.5, lo=0.0, hi=1.0, doc="added later"))], bases=(base,)
        )
        c = copy.deepcopy(cfg)
        setattr(c, name, grown(**dataclasses.asdict(getattr(cfg, name))))
        assert _keys(c, tmp_path) == before, name
        # ... and set off its default, the same field is identity.
        setattr(c, name, grown(**dataclasses.asdict(getattr(cfg, name)), new_knob=0.25))
        changed = {k for k, v in _keys(c, tmp_path).items() if v != before[k]}
        assert changed, name


@pytest.mark.parametrize("section", ["rl", "oracle", "env", "pretrain", "data"])
def test_every_identity_field_changes_a_key_and_no_execution_field_does(tmp_path, section):
    cfg = _cfg(tmp_path)
    before = _keys(cfg, tmp_path)
    # The runs that read each section: the oracle reads rl (less a student's guidance), oracle and env, pretraining
    # reads pretrain, data and env.
    reader = {"rl": "oracle", "oracle": "oracle", "env": "oracle", "pretrain": "encoder", "data": "encoder"}[section]
    tried = 0
    for f in dataclasses.fields(getattr(cfg, section)):
        value = getattr(getattr(cfg, section), f.name)
        new = _other(type(getattr(cfg, section)), f, value)
        if new is None:
            continue
        c = copy.deepcopy(cfg)
        setattr(getattr(c, section), f.name, new)
        if section == "pretrain" and f.name == "crop_from":
            c.env.image_size = new  # the two must agree (validated)
        try:
            c = validate(c)
        except ConfigError:
            continue
        keys = _keys(c, tmp_path)
        if f.metadata.get("execution"):
            assert keys == before, f"{section}.{f.name} is execution-only but changed a key"
        elif section == "rl" and f.name in GUIDANCE:
            # A student's guidance: the oracle-guided student reads the schedule and β, the planner-guided one its std.
            who = "npe" if f.name == "guide_std" else "student"
            assert keys["oracle"] == before["oracle"] and keys[who] != before[who], f"rl.{f.name}"
        elif section == "oracle":
            assert keys["oracle"] != before["oracle"], f"oracle.{f.name}"
            assert keys["student"] == before["student"]  # a student sees its oracle by the oracle file's digest
        elif section == "env" and f.name == "scene":
            assert keys["oracle"] != before["oracle"] and keys["encoder"] == before["encoder"]  # data.scene is its
        else:
            assert keys[reader] != before[reader], f"{section}.{f.name}: {value!r} -> {new!r} kept the key"
        tried += 1
    assert tried >= {"rl": 20, "oracle": 7, "env": 25, "pretrain": 20, "data": 9}[section]


def test_unread_fields_do_not_key_a_run(tmp_path):
    """An unguided method does not read the α/β fields; the oracle does not read a student's, nor a student the
    oracle's (it sees its oracle by the file's digest)."""
    cfg = _cfg(tmp_path)
    before = _keys(cfg, tmp_path)
    after = _keys(_cfg(tmp_path, "rl.alpha_decay_steps=12345", "rl.beta=0.5"), tmp_path)
    assert after["ppo"] == before["ppo"] and after["student"] != before["student"]
    assert after["oracle"] == before["oracle"]
    after = _keys(_cfg(tmp_path, "oracle.alpha_decay_steps=12345", "oracle.beta=0.5"), tmp_path)
    assert after["oracle"] != before["oracle"]
    assert {k for k in after if after[k] != before[k]} == {"oracle"}


def test_a_behaviour_version_rekeys_what_depends_on_it(tmp_path, monkeypatch):
    cfg = _cfg(tmp_path)
    before = _keys(cfg, tmp_path)
    for component, moved in (
        ("rl", {"oracle", "student", "ppo", "npe"}),
        ("pretrain", {"encoder"}),
        ("data", {"encoder"}),
        ("env", {"oracle", "encoder", "student", "ppo", "npe"}),
        ("planners", {"oracle", "student", "ppo", "npe"}),
        ("eval", set()),
    ):
        monkeypatch.setitem(R.BEHAVIOUR, component, R.BEHAVIOUR[component] + 1)
        keys = _keys(cfg, tmp_path)
        assert {k for k in keys if keys[k] != before[k]} == moved, component
        monkeypatch.setitem(R.BEHAVIOUR, component, R.BEHAVIOUR[component] - 1)
    with pytest.raises(KeyError, match="unknown kind"):
        R.behaviour("sweep")


def test_bumping_a_version_invalidates_that_components_cached_evaluations(tmp_path, monkeypatch):
    """A cached evaluation is reused until the code that decided its episodes changes its behaviour version."""
    from omcrl.eval.stage import evaluate_methods

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}", "eval.workers=1"])

    def run() -> dict[str, int]:
        stats: dict[str, int] = {}
        evaluate_methods(cfg, {"blind": "blind"}, scenes=["box-v2"], episodes=1, stats=stats)
        return stats

    assert run() == {"evaluated": 1}
    assert run() == {"cached": 1}
    monkeypatch.setitem(R.BEHAVIOUR, "rl", R.BEHAVIOUR["rl"] + 1)  # not a planner's component
    assert run() == {"cached": 1}
    for component in ("planners", "eval", "env"):
        monkeypatch.setitem(R.BEHAVIOUR, component, R.BEHAVIOUR[component] + 1)
        assert run() == {"evaluated": 1}, component
        assert run() == {"cached": 1}
    # Execution-only settings never do.
    cfg.eval.workers = 2
    assert run() == {"cached": 1}


def test_an_evaluation_key_holds_what_decides_its_episodes():
    from omcrl.eval.stage import evaluation_identity

    cfg = load_config("smoke")
    env = dataclasses.replace(cfg.env, scene="tree-v2")
    base = evaluation_identity(cfg, "abc", env, 5, planner=False, lanes=8)
    assert base["versions"] == R.behaviour("eval-policy") and base["env"]["scene"] == "tree-v2"
    variants = [
        evaluation_identity(cfg, "abd", env, 5, planner=False, lanes=8),
        evaluation_identity(cfg, "abc", dataclasses.replace(env, max_speed=1.0), 5, planner=False, lanes=8),
        evaluation_identity(cfg, "abc", env, 6, planner=False, lanes=8),
        evaluation_identity(cfg, "abc", env, 5, planner=False, lanes=1),
        evaluation_identity(cfg, "abc", env, 5, planner=False, lanes=8, seed_offset=7),
        evaluation_identity(cfg, "abc", env, 5, planner=False, lanes=8, disturbance={"appearance": "box"}),
        evaluation_identity(cfg, "abc", env, 5, planner=True, lanes=8),
    ]
    hashes = {config_hash(v) for v in variants}
    assert config_hash(base) not in hashes and len(hashes) == len(variants)
