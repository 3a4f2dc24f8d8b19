"""Benchmarks (``python -m omcrl.bench``): the dispatcher, and one benchmark end to end with its JSON's content.
Speeds are never asserted here (they are what the benchmarks measure); only that the numbers are there."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from omcrl.bench.__main__ import available, main


def test_the_dispatcher_lists_the_benchmarks_and_refuses_an_unknown_one(capsys):
    names = available()
    assert {"env", "pretrain", "rl", "eval", "deploy", "sweep", "cost", "precision"} <= set(names)
    assert main([]) == 2 and main(["--help"]) == 0
    assert f"benchmarks: {', '.join(names)}" in capsys.readouterr().out
    assert main(["warp-drive"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: benchmark 'warp-drive' does not exist; available: {', '.join(names)}"]


@pytest.mark.timeout(600)
def test_deploy_benchmark_writes_both_runtimes_side_by_side(tmp_path, repo_root):
    out = tmp_path / "deploy.json"
    r = subprocess.run(
        [sys.executable, "-m", "omcrl.bench", "deploy", "--quick", "--image-size", "32", "--out", str(out)],
        cwd=repo_root, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert doc["name"] == "deploy" and doc["machine"]["cpu_count"] >= 1
    rows = {row["runtime"]: row for row in doc["rows"]}
    assert set(rows) == {"onnxruntime", "torch"}
    for row in rows.values():
        assert row["image_size"] == 32 and row["calls"] > 0
        assert 0 < row["median_ms"] <= row["p99_ms"] <= row["max_ms"]
        assert row["max_vs_period"] == pytest.approx(row["max_ms"] / row["period_ms"])
    assert rows["onnxruntime"]["speedup_vs_torch"] == pytest.approx(
        rows["torch"]["median_ms"] / rows["onnxruntime"]["median_ms"], rel=1e-3
    )
