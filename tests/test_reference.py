"""Reference bundles: verified before use, never replacing different data, refusing what is not one.

The round trip on real trained runs (pack a smoke chain's runs, unpack them into a fresh results folder, Table I
from the bundle alone) is part of ``test_notebooks.py::test_chain_smoke``, which trains them.
"""

from __future__ import annotations

import hashlib
import io
import itertools
import json
import tarfile
from pathlib import Path

import pytest

from omcrl.config import load_config
from omcrl.pipeline.reference import ARCHIVE, MANIFEST, ReferenceError, unpack_reference, verify_reference
from omcrl.pipeline.storage import sha256


def _bundle(path: Path, files: dict[str, bytes], fields: dict | None = None, archive: dict | None = None) -> Path:
    """A bundle as pack_reference writes one; ``archive`` puts other bytes in the archive than the manifest lists."""
    path.mkdir(parents=True, exist_ok=True)
    with tarfile.open(path / ARCHIVE, "w:xz") as tar:
        for rel, data in (archive or files).items():
            info = tarfile.TarInfo(rel)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    manifest = {
        "format": 1,
        "preset": "smoke",
        "seeds": [0],
        "methods": [],
        "commit": "0" * 40,
        "made": "2026-12-02 00:00 UTC",
        "archive": {"name": ARCHIVE, "sha256": sha256(path / ARCHIVE), "bytes": (path / ARCHIVE).stat().st_size},
        "files": {rel: {"sha256": hashlib.sha256(d).hexdigest(), "bytes": len(d)} for rel, d in files.items()},
    }
    manifest.update(fields or {})
    (path / MANIFEST).write_text(json.dumps(manifest))
    return path


FILES = {
    "runs/rl/ppo-abc/seed0/metrics.csv": b"step,metric,value\n1,x,2\n",
    "eval/ppo/seed0/box-v0-k/episodes.csv": b"a\n1\n",
}


def test_unpack_copies_verified_files_and_a_second_unpack_finds_them_there(tmp_path):
    b = _bundle(tmp_path / "bundle", FILES)
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path / 'results'}"])
    res = unpack_reference(cfg, b)
    assert sorted(res.copied) == sorted(FILES) and not res.present
    for rel, data in FILES.items():
        assert (cfg.run_root / rel).read_bytes() == data
    again = unpack_reference(cfg, b)
    assert not again.copied and sorted(again.present) == sorted(FILES)


def test_a_damaged_file_is_named_and_nothing_is_copied(tmp_path):
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path / 'results'}"])
    # Same size, other content: only the digest can tell.
    damaged = {**FILES, "eval/ppo/seed0/box-v0-k/episodes.csv": b"a\n2\n"}
    b = _bundle(tmp_path / "one", FILES, archive=damaged)
    member = "eval/ppo/seed0/box-v0-k/episodes.csv"
    with pytest.raises(ReferenceError, match=f"member '{member}' does not match its SHA-256"):
        unpack_reference(cfg, b)
    assert not cfg.run_root.exists() or not any(p.is_file() for p in cfg.run_root.rglob("*"))
    # The archive itself changed after the manifest was written.
    b = _bundle(tmp_path / "two", FILES)
    raw = bytearray((b / ARCHIVE).read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    (b / ARCHIVE).write_bytes(bytes(raw))
    with pytest.raises(ReferenceError, match="runs.tar.xz: does not match its SHA-256"):
        verify_reference(b)
    # A file the manifest lists is not in the archive; one in the archive is not listed.
    b = _bundle(
        tmp_path / "three",
        FILES,
        archive={"runs/rl/ppo-abc/seed0/metrics.csv": FILES["runs/rl/ppo-abc/seed0/metrics.csv"]},
    )
    with pytest.raises(ReferenceError, match="box-v0-k/episodes.csv is listed in .* but not in the archive"):
        verify_reference(b)
    b = _bundle(tmp_path / "four", FILES, archive={**FILES, "../../outside.txt": b"x"})
    with pytest.raises(ReferenceError, match="member '../../outside.txt' is not in the manifest"):
        verify_reference(b)
    (b / ARCHIVE).unlink()
    with pytest.raises(ReferenceError, match="runs.tar.xz: listed in .* but missing"):
        verify_reference(b)


def test_different_data_already_there_is_never_replaced(tmp_path):
    b = _bundle(tmp_path / "bundle", FILES)
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path / 'results'}"])
    mine = cfg.run_root / "runs/rl/ppo-abc/seed0/metrics.csv"
    mine.parent.mkdir(parents=True)
    mine.write_bytes(b"my own run\n")
    with pytest.raises(ReferenceError, match="metrics.csv: exists with other content .* not replacing it"):
        unpack_reference(cfg, b)
    assert mine.read_bytes() == b"my own run\n"
    assert not (cfg.run_root / "eval").exists()  # checked before anything was copied


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"preset": "quick"}, "field 'preset' is 'quick', expected 'smoke'"),
        ({"format": 7}, "field 'format' is 7, expected 1"),
        ({"files": {"../outside.txt": {"sha256": "0", "bytes": 1}}}, "leaves the bundle"),
        ({"archive": None}, "field 'archive' is None"),
    ],
)
def test_a_manifest_of_another_preset_format_or_with_escaping_paths_is_refused(tmp_path, fields, match):
    b = _bundle(tmp_path / "bundle", FILES, fields)
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path / 'results'}"])
    with pytest.raises(ReferenceError, match=match):
        unpack_reference(cfg, b)


def test_a_folder_without_a_manifest_is_named(tmp_path):
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path / 'results'}"])
    with pytest.raises(ReferenceError, match="no reference manifest there"):
        unpack_reference(cfg, tmp_path)


def test_cli_names_the_problem_in_one_line(tmp_path, capsys):
    from omcrl.__main__ import main

    rc = main(["reference", "--preset", "smoke", "--from", str(tmp_path), "--set", f"results_dir={tmp_path / 'r'}"])
    err = capsys.readouterr().err
    assert rc == 1 and err.startswith("error: ") and "no reference manifest there" in err


def test_a_bundle_names_its_scene_suite_and_one_from_before_v2_holds_v1_runs(tmp_path):
    """The runs of a bundle are found under its suite's scenes: the shipped quick bundle holds v2 runs (seed 2 of the
    v2 grid, at quick's budget: no overrides); the retired v1 bundle beside it holds v1 runs (re-keyed at 2b7073b by
    scripts/rekey_reference.py, since retired to git history), so `--from-reference` with it passes v1's overrides;
    a manifest from before v2 (no `suite` field) holds v1 runs; a bundle of another suite says so."""
    from omcrl.pipeline.reference import bundle_overrides, bundle_suite, config_suite
    from omcrl.scenes import suite_overrides

    quick = Path(__file__).parents[1] / "reference" / "quick"
    shipped = json.loads((quick / "bundle" / MANIFEST).read_text())
    assert shipped["suite"] == "v2" and bundle_suite(shipped) == "v2" and shipped["seeds"] == [2]
    assert bundle_overrides("quick") == [*suite_overrides("v2"), "seed=2", "seeds=[2]"]
    v1 = json.loads((quick / "bundle-v1" / MANIFEST).read_text())
    assert v1["suite"] == "v1" and v1["rekeyed"]["runs"] and bundle_suite(v1) == "v1"
    assert bundle_suite({k: v for k, v in v1.items() if k != "suite"}) == "v1"
    # It was trained at quick's budget before the v2 budget check tripled it: the manifest says so (the oracle's decay
    # too, since the oracle has its own guidance section: scripts/migrate_runs.py).
    budget = ["rl.total_steps=150000", "rl.alpha_decay_steps=75000", "oracle.alpha_decay_steps=75000"]
    assert bundle_overrides("quick", quick / "bundle-v1") == [*suite_overrides("v1"), *budget, "seed=0", "seeds=[0]"]
    b = _bundle(tmp_path / "b", FILES, {"suite": "v2"})
    assert bundle_overrides("smoke", b) == [*suite_overrides("v2"), "seed=0", "seeds=[0]"]
    # The notebooks fly the bundle's seeds, not the preset's: a bundle of seeds 2 and 4 sets both fields.
    two = _bundle(tmp_path / "two", FILES, {"suite": "v2", "seeds": [2, 4]})
    assert bundle_overrides("smoke", two)[-2:] == ["seed=2", "seeds=[2, 4]"]
    cfg = load_config("smoke", overrides=bundle_overrides("smoke", two))
    assert (cfg.seed, cfg.seeds) == (2, [2, 4])
    with pytest.raises(ReferenceError, match="field 'seeds' is \\[\\]"):
        bundle_overrides("smoke", _bundle(tmp_path / "none", FILES, {"seeds": []}))
    with pytest.raises(ReferenceError, match="'suite' is 'v9'"):
        bundle_suite({"suite": "v9"})
    cfg = load_config("smoke")
    assert config_suite(cfg) == "v2" and config_suite(cfg.with_suite("v1")) == "v1"
    with pytest.raises(ReferenceError, match="training scene of no suite"):
        config_suite(load_config("smoke", overrides=["env.scene=tree-v2"]))


def test_the_shipped_bundle_is_found_by_this_codes_registry(tmp_path, monkeypatch):
    """Every run of reference/quick/bundle is where the run registry of this code looks for it: a change of run
    identity that would orphan the shipped runs fails here (re-key them once with a migration script, as
    scripts/rekey_reference.py did at 2b7073b)."""
    from omcrl.pipeline.reference import bundle_overrides, default_bundle
    from omcrl.pretrain.train import pretrain_encoder
    from omcrl.rl.methods import METHODS, encoder_config

    cfg = load_config("quick", overrides=[f"results_dir={tmp_path}", *bundle_overrides("quick")])
    res = unpack_reference(cfg, default_bundle("quick"))
    assert not res.not_found and len(res.found) == len(res.manifest["methods"]) * len(res.manifest["seeds"])
    # Its encoders are finished runs to this code (their end recorded in run.json, by a migration of 00dfa04): found
    # and skipped without their dataset, which a fresh clone does not have.
    no_data = cfg.with_overrides([f"data.file={tmp_path / 'absent.h5'}"])
    frozen = [m for m in res.manifest["methods"] if METHODS[m].features == "frozen"]
    for s, m in itertools.product(res.manifest["seeds"], frozen):  # the bundle's seeds, not the preset's seed 0
        enc = pretrain_encoder(encoder_config(no_data.with_seed(int(s)), METHODS[m]), progress=False)
        assert enc.skipped and enc.iterations == 1500, (s, m)
    # Its evaluations are finished cache runs of this code (migrated at bf1e40c): read back, none flown again.
    import omcrl.eval.stage as stage

    def fly(*args, **kwargs):
        raise AssertionError(f"a shipped evaluation was flown again: {args[:2]}")

    monkeypatch.setattr(stage, "evaluate", fly)
    from omcrl.pipeline.reference import manifest_overrides

    for s in res.manifest["seeds"]:
        c = cfg.with_overrides(manifest_overrides(res.manifest)).with_seed(int(s))
        stats: dict[str, int] = {}
        policies = {m: res.found[f"{m}/seed{s}"] / "final.pt" for m in res.manifest["methods"]}
        episodes = stage.evaluate_methods(c, policies, stats=stats)
        assert stats == {"cached": len(policies) * len(c.eval.scenes)} and len(episodes) > 0


def test_a_bundle_records_the_overrides_its_runs_were_trained_under():
    from omcrl.pipeline.reference import config_overrides, manifest_overrides

    cfg = load_config("quick", overrides=["rl.total_steps=1234", "env.goal_distance=[4, 12]"]).with_suite("v1")
    got = config_overrides(cfg)
    assert got == ["env.goal_distance=[4.0, 12.0]", "rl.total_steps=1234"]
    again = load_config("quick").with_suite("v1").with_overrides(got)
    assert config_overrides(again) == got and again.rl.total_steps == 1234
    assert config_overrides(load_config("quick")) == []
    with pytest.raises(ReferenceError, match="'overrides'"):
        manifest_overrides({"overrides": "rl.total_steps=1"})


def test_the_checkouts_reference_folder_stays_under_the_60_mb_it_may_hold():
    """reference/ travels with every clone: the bundle, the grids' records and the teachers' weights still needed
    (released ones are read back from git history, omcrl.pipeline.griddata) must fit 60 MB together."""
    from omcrl.config import project_root
    from omcrl.pipeline.reference import LIMIT_MB

    files = [p for p in (project_root() / "reference").rglob("*") if p.is_file()]
    total = sum(p.stat().st_size for p in files)
    biggest = sorted(files, key=lambda p: p.stat().st_size)[-3:]
    assert total <= LIMIT_MB * 1e6, f"reference/ holds {total / 1e6:.1f} MB; the largest files: {biggest}"


def test_a_retired_bundle_is_read_from_git_history_and_a_copy_without_it_is_told(tmp_path):
    """retire_bundle: the archive leaves the checkout for a pointer to its git blob (only once committed); the bundle
    still verifies and unpacks from a full clone; a copy without the repository's objects is refused by name; a
    pointer to other bytes is caught by the manifest's SHA-256."""
    import shutil
    import subprocess

    from omcrl.pipeline.reference import retire_bundle

    def git(*args):
        return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True).stdout

    repo = tmp_path / "repo"
    repo.mkdir()
    git("init", "-q")
    git("config", "user.email", "t@example.org")
    git("config", "user.name", "t")
    b = _bundle(repo / "bundle", FILES)
    with pytest.raises(ReferenceError, match="commit the bundle before retiring it"):
        retire_bundle(b)
    assert (b / ARCHIVE).is_file()
    git("add", "-A")
    git("commit", "-qm", "bundle")
    before = verify_reference(b)
    pointer = retire_bundle(b)
    assert pointer == b / f"{ARCHIVE}.git.json" and not (b / ARCHIVE).exists()
    assert verify_reference(b) == before
    res = unpack_reference(load_config("smoke", overrides=[f"results_dir={tmp_path / 'results'}"]), b)
    assert sorted(res.copied) == sorted(FILES)

    copy = shutil.copytree(b, tmp_path / "copy")  # outside the repository: no objects to read the blob from
    with pytest.warns(UserWarning, match="git blob .* is not in this repository"):
        with pytest.raises(ReferenceError, match="its git blob is not in this repository"):
            verify_reference(copy)

    other = repo / "other.bin"
    other.write_bytes(b"not the archive")
    rec = json.loads(pointer.read_text())
    pointer.write_text(json.dumps({**rec, "git_blob": git("hash-object", "-w", str(other)).strip()}))
    with pytest.raises(ReferenceError, match="does not match its SHA-256"):
        verify_reference(b)
    pointer.write_text("{not json")
    with pytest.raises(ReferenceError, match="not a readable git pointer"):
        verify_reference(b)


def test_bundle_parts_merge_into_one_that_verifies_and_unpacks_and_disagreements_are_named(tmp_path):
    """merge_bundles: parts packed a few methods at a time make one bundle (a file two parts carry alike is stored
    once, the methods and rounding effects add up); parts that disagree on a field, hold one method twice or
    different bytes under one name are refused by name before anything is written."""
    from omcrl.pipeline.reference import merge_bundles

    shared = {"runs/rl/oracle-o/seed0/metrics.csv": b"step,metric,value\n1,x,1\n"}
    a_files = {**shared, "eval/oracle/seed0/box-v2-k/episodes.csv": b"a\n1\n"}
    b_files = {
        **shared,
        "runs/rl/ours-u/seed0/metrics.csv": b"step\n2\n",
        "eval/ours/seed0/box-v2-k/episodes.csv": b"b\n",
    }
    effect = {"episodes": 50, "changed_success": 1, "changed_collision": 0, "max_abs_sr_diff_points": 2.0}
    a = _bundle(tmp_path / "parts" / "oracle", a_files, {"methods": ["oracle"], "rounding": effect})
    b = _bundle(
        tmp_path / "parts" / "ours",
        b_files,
        {"methods": ["ours"], "rounding": {**effect, "changed_success": 0, "max_abs_sr_diff_points": 0.0}},
    )
    res = merge_bundles([b, a], tmp_path / "bundle")
    manifest, contents = verify_reference(tmp_path / "bundle")
    assert contents == {**a_files, **b_files} and len(contents) == 4
    assert manifest["methods"] == ["oracle", "ours"] and [p["name"] for p in manifest["parts"]] == ["oracle", "ours"]
    assert manifest["rounding"]["episodes"] == 100 and manifest["rounding"]["changed_success"] == 1
    assert manifest["rounding"]["max_abs_sr_diff_points"] == 2.0 and res.manifest == manifest
    got = unpack_reference(load_config("smoke", overrides=[f"results_dir={tmp_path / 'results'}"]), res.bundle)
    assert sorted(got.copied) == sorted(contents)

    before = (tmp_path / "bundle" / MANIFEST).read_bytes()
    cases = [
        (_bundle(tmp_path / "v1" / "x", {}, {"methods": ["npe"], "suite": "v1"}), "field 'suite' is 'v1'"),
        (_bundle(tmp_path / "twice" / "x", {}, {"methods": ["ours"]}), "method 'ours' is in two parts"),
        (
            _bundle(tmp_path / "other" / "x", {"runs/rl/oracle-o/seed0/metrics.csv": b"other\n"}, {"methods": []}),
            "oracle-o/seed0/metrics.csv: differs between",
        ),
    ]
    for extra, match in cases:
        with pytest.raises(ReferenceError, match=match):
            merge_bundles([a, b, extra], tmp_path / "bundle")
    assert (tmp_path / "bundle" / MANIFEST).read_bytes() == before  # the merged bundle there was left alone
    with pytest.raises(ReferenceError, match="no bundle parts"):
        merge_bundles([], tmp_path / "bundle")


def test_cli_merges_a_folder_of_parts_and_names_an_empty_one(tmp_path, capsys):
    from omcrl.__main__ import main

    _bundle(tmp_path / "parts" / "oracle", FILES, {"methods": ["oracle"]})
    out = tmp_path / "merged"
    assert main(["reference", "--preset", "smoke", "--merge", str(tmp_path / "parts"), "--from", str(out)]) == 0
    assert verify_reference(out)[1] == FILES
    (tmp_path / "empty").mkdir()
    assert main(["reference", "--preset", "smoke", "--merge", str(tmp_path / "empty"), "--from", str(out)]) != 0
    assert "no bundle folders" in capsys.readouterr().err
    assert main(["reference", "--preset", "smoke", "--pack", "--methods", "hybrid-apf", "--from", str(out)]) != 0
    assert "not learned methods" in capsys.readouterr().err


def test_pages_that_quote_the_bundles_rounding_agree_with_its_manifest(repo_root):
    """DEVIATIONS, reproducibility and usage each give the rounding's effect on Table I: the counts must be the ones
    the v2 bundle's manifest recorded when it was packed (they once said 2 of 2,000, the v1 bundle's)."""
    import json
    import re

    r = json.loads((repo_root / "reference" / "quick" / "bundle" / "MANIFEST.json").read_text())["rounding"]
    want = (r["changed_success"], r["changed_collision"], r["episodes"])
    for page in ("docs/DEVIATIONS.md", "docs/reproducibility.md", "docs/usage.md"):
        text = " ".join((repo_root / page).read_text(encoding="utf-8").split())
        got = re.findall(r"(\d+) success and (\d+) collision outcomes of (?:Table I's )?([\d,]+)", text)
        assert got, f"{page} does not quote the rounding's effect"
        assert {(int(s), int(c), int(n.replace(",", ""))) for s, c, n in got} == {want}, (page, got, want)
