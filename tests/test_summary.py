"""The summary (``python -m omcrl summary``, results/<preset>/summary.md): what it lists from the stages' files,
and what it says when a stage has not run."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from omcrl.config import load_config


def _fake_results(root: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (root / "figures").mkdir(parents=True)
    (root / "tables").mkdir()
    for name in ("scenes", "fig5_training_curves"):
        fig, ax = plt.subplots()
        ax.plot([0, 1])
        fig.savefig(root / "figures" / f"{name}.png")
        plt.close(fig)
    rows = ["method,scene,metric,mean,lo,hi,seeds,episodes"]
    for m in ("ours", "curl"):
        for sc in ("box", "tree"):
            for met, v in (("SR", 90.0), ("SPL", 0.8), ("CR", 5.0), ("NE", 0.4)):
                rows.append(f"{m},{sc},{met},{v},{v * 0.9},{v * 1.1},3,50")
    (root / "tables" / "table1.csv").write_text("\n".join(rows) + "\n")
    (root / "executed").mkdir()
    (root / "executed" / "wall_times.json").write_text(json.dumps({"00_scenes": 6.2, "02_pretrain_encoder": 1142.0}))
    (root / "executed" / "peak_rss_mb.json").write_text(json.dumps({"00_scenes": 412, "02_pretrain_encoder": 1830}))


@pytest.mark.parametrize("preset", ["smoke", "quick"])
def test_summary_lists_every_figure_and_the_table(tmp_path, preset):
    from omcrl.pipeline.summary import SMOKE_NOTE, write_summary

    cfg = load_config(preset, overrides=[f"results_dir={tmp_path}"])
    _fake_results(cfg.run_root)
    path = write_summary(cfg)
    assert path == cfg.run_root / "summary.md"
    text = path.read_text()
    for f in (cfg.run_root / "figures").glob("*.png"):
        assert f"(figures/{f.name})" in text
    assert "| tree | curl | 90.0 [81.0, 99.0] |" in text
    assert "19m02s" in text and "19m08s" in text  # notebook 02 and the total
    assert "| 412 MB |" in text and text.count("| 1,830 MB |") == 2  # notebook 02 and the total's peak
    assert "not run yet (notebook 03_train_oracle)" in text  # a missing stage is named, not skipped silently
    assert "| SPL | success weighted by path length |" in text  # the glossary
    assert (SMOKE_NOTE in text) == (preset == "smoke")


def test_summary_cli(tmp_path, repo_root):
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    _fake_results(cfg.run_root)
    r = subprocess.run(
        [sys.executable, "-m", "omcrl", "summary", "--preset", "smoke", "--set", f"results_dir={tmp_path}"],
        cwd=repo_root,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    assert "results summary, preset `smoke`" in r.stdout and (cfg.run_root / "summary.md").exists()


def test_an_empty_results_folder_gives_a_short_summary_that_names_what_to_run(tmp_path):
    from omcrl.pipeline.summary import write_summary

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    text = write_summary(cfg).read_text()
    assert "not run yet (notebook 03_train_oracle)" in text and "not run yet (notebook 07_tables)" in text
    assert "| SR | success rate |" in text  # the glossary is there even before any number is
