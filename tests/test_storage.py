"""Sweep storage (``sweep.storage``): files travel between project roots by content, checked on the way in."""

from __future__ import annotations

import json

import pytest

from omcrl.pipeline.storage import Storage, StorageError, job_key, sha256


def _tree(root):
    run = root / "results" / "smoke" / "runs" / "rl" / "ppo-abc" / "seed0"
    run.mkdir(parents=True)
    (run / "final.pt").write_bytes(b"weights" * 100)
    (run / "metrics.csv").write_text("step,sr\n0,0.1\n")
    (run / ".final.pt.x1.tmp").write_bytes(b"half a file")  # an atomic write in progress: never shared
    (run.parent / "seed0.lock").write_text("pid 1")
    return run


def test_a_pushed_run_arrives_under_another_root_byte_for_byte(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    run = _tree(a)
    store = Storage(str(tmp_path / "store"))
    m = store.push("k1", [run, run.parent / "seed0.lock"], base=a)
    assert sorted(m["files"]) == [
        "results/smoke/runs/rl/ppo-abc/seed0/final.pt",
        "results/smoke/runs/rl/ppo-abc/seed0/metrics.csv",
    ]
    assert store.pull(["k1", "never-pushed"], base=b) == {"fetched": 2, "kept": 0, "missing_manifests": 1}
    got = b / "results/smoke/runs/rl/ppo-abc/seed0"
    assert (got / "final.pt").read_bytes() == (run / "final.pt").read_bytes()
    assert not list(got.glob(".*")) and not (got.parent / "seed0.lock").exists()
    # Again: what is already there with the right digest is kept, not copied.
    assert store.pull(["k1"], base=b)["kept"] == 2
    # A stale local copy is replaced by the stored one.
    (got / "metrics.csv").write_text("stale")
    assert store.pull(["k1"], base=b)["fetched"] == 1 and (got / "metrics.csv").read_text().startswith("step")


def test_a_damaged_blob_is_refused_naming_it_and_nothing_is_replaced(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    run = _tree(a)
    store = Storage(str(tmp_path / "store"))
    store.push("k1", [run], base=a)
    digest = sha256(run / "final.pt")
    (tmp_path / "store" / "blobs" / digest[:2] / digest).write_bytes(b"garbled")
    with pytest.raises(StorageError, match=rf"blob .*{digest}.* has sha256 .*damaged in storage"):
        store.pull(["k1"], base=b)
    dest = b / "results/smoke/runs/rl/ppo-abc/seed0"
    assert not (dest / "final.pt").exists() and not list(dest.glob(".*.tmp"))


def test_a_damaged_or_escaping_manifest_is_one_clear_error(tmp_path):
    store = Storage(str(tmp_path / "store"))
    (tmp_path / "store" / "manifests").mkdir(parents=True)
    (tmp_path / "store" / "manifests" / "bad.json").write_text("{not json")
    with pytest.raises(StorageError, match=r"manifests/bad.json is damaged"):
        store.pull(["bad"], base=tmp_path / "b")
    escape = {"format": 1, "files": {"../../etc/x": {"sha256": "0" * 64, "bytes": 1}}}
    (tmp_path / "store" / "manifests" / "up.json").write_text(json.dumps(escape))
    with pytest.raises(StorageError, match=r"leaves the project root"):
        store.pull(["up"], base=tmp_path / "b")
    with pytest.raises(StorageError, match=r"sweep.storage: got ''"):
        Storage(" ")


def test_job_keys_do_not_depend_on_the_machine_project_root():
    assert job_key("pretrain:/home/a/kit/results/x", "/home/a/kit") == job_key("pretrain:/srv/b/results/x", "/srv/b")
    assert job_key("train:x", "/r") != job_key("train:y", "/r")
