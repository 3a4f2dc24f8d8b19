"""The ablations rebuilt from the grids' records (omcrl.pipeline.ablations): Tables II–III beside the paper's values,
Figs. 7–10, the findings with Holm-adjusted p, and the grids' account."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from omcrl.config import ConfigError, load_config
from omcrl.eval.ablation import paper_ablations
from omcrl.eval.table1 import paper_table1
from omcrl.pipeline.griddata import GridData, grid_data_dir
from omcrl.pipeline.grids import GRIDS

SCENES = ("box-v2", "furniture-v2", "barrier-v2", "tree-v2", "furniture-v0")


def _episodes(label: str, p: float, seed: int, rng: np.random.Generator, n: int = 40) -> pd.DataFrame:
    """``n`` layouts per scene of SCENES, each a success with probability ``p``."""
    ok = (rng.random((len(SCENES), n)) < p).ravel()
    return pd.DataFrame({
        "method": "ours", "label": label, "scene": np.repeat(SCENES, n), "train_seed": seed,
        "seed": np.tile(np.arange(n), len(SCENES)), "success": ok, "collision": ~ok,
        "final_distance": np.where(ok, 0.1, 3.0), "min_distance": np.where(ok, 0.1, 2.0), "path_length": 8.0,
        "optimal_path_length": 7.0, "steps": 80,
    })  # fmt: skip


def test_the_papers_ablation_tables_are_transcribed_whole():
    """Tables II and III: every variant in every evaluation scene once, labels the grids' own, TTS empty exactly
    where SR is 0 (the paper's "--"); Table III's Ours row is the paper's Table I row of Ours, as printed there."""
    df = paper_ablations()
    assert len(df) == 15 and not df.duplicated(["grid", "label", "scene"]).any()
    for grid, g in df.groupby("grid"):
        assert set(g["label"]) <= {v.label for v in GRIDS[grid]}
        assert set(g["scene"]) == {"furniture", "barrier", "tree"}
    assert (df["TTS"].isna() == (df["SR"] == 0)).all()
    assert ((df["SR"] <= df["OS"]) & df[["SR", "OS", "CR"]].apply(lambda c: c.between(0, 100)).all(axis=1)).all()
    linear = df[(df["grid"] == "decay") & (df["label"] == "linear")].drop(columns=["grid", "label"])
    ours = paper_table1().query("method == 'ours'").drop(columns="method")
    pd.testing.assert_frame_equal(linear.set_index("scene").sort_index(), ours.set_index("scene").sort_index())


def test_tables_from_reference_writes_the_ablations_from_the_grid_records(tmp_path, monkeypatch):
    """From records alone: the per-grid tables, Table III beside the paper's values, the findings judged with
    Holm-adjusted p, the figures, and an account whose hours are the grid's jobs.csv against its plan's rates."""
    from omcrl.pipeline.tables import tables_stage

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("quick", overrides=[f"results_dir={tmp_path / 'results'}"])
    rng = np.random.default_rng(3)
    decay = GridData(grid_data_dir(cfg, "decay"))
    for s in (0, 1, 2):
        decay.save_episodes("linear", s, _episodes("linear", 0.9, s, rng))
        decay.save_episodes("exp", s, _episodes("exp", 0.1, s, rng))
        decay.save_episodes("fixed", s, _episodes("fixed", 0.9, s, rng))
    decay.save_episodes("linear", 4, _episodes("linear", 0.0, 4, rng))  # not an ablation seed: left out
    pd.DataFrame([
        {"id": "pretrain:a", "kind": "pretrain", "method": "ours", "seed": 0, "status": "done", "seconds": 720.0,
         "rate_key": "pretrain", "work": 750},
        {"id": "pretrain:c", "kind": "pretrain", "method": "ours", "seed": 1, "status": "done", "seconds": 240.0,
         "rate_key": "pretrain", "work": 250},  # resumed at 500 of 750 iterations: the part after its checkpoint
        {"id": "train:b", "kind": "train", "method": "ours", "seed": 0, "status": "skipped", "seconds": 0.1,
         "rate_key": "train:frozen", "work": 50000},
    ]).to_csv(decay.root / "jobs.csv", index=False)  # fmt: skip
    (decay.root / "plan_rates.json").write_text(json.dumps({"pretrain": 1.25, "train:frozen": 250.0}))

    res = tables_stage(cfg, from_reference=True, grid="ablations")
    tables = cfg.run_root / "tables"
    for name in ("ablation_decay.md", "table3.tex", "table3_vs_paper.md", "ablation_findings.csv",
                 "ablation_account.md"):  # fmt: skip
        assert (tables / name).is_file(), name
    assert (cfg.run_root / "figures" / "ablation_decay.png").is_file()
    assert set(res.episodes) == {"decay"} and set(res.episodes["decay"]["train_seed"]) == {0, 1, 2}

    # Rows in the paper's order of the variants (the grid's), not the alphabet's.
    assert list(res.tables["decay"].index.get_level_values(0).unique()) == ["linear", "exp", "fixed"]
    assert list(pd.read_csv(tables / "table3.csv")["method"].unique()) == ["linear", "exp", "fixed"]
    vp = pd.read_csv(tables / "table3_vs_paper.csv")
    sr = vp[(vp["metric"] == "SR") & (vp["scene"] == "tree-v2")].set_index("method")
    assert sr.loc["linear", "paper"] == 78.5 and sr.loc["exp", "paper"] == 72.5
    assert sr.loc["linear", "kit"] > 80 > 20 > sr.loc["exp", "kit"]

    f = res.findings.set_index(["claim", "scene"])
    assert f.loc[("linear > exp", "tree-v2"), "verdict"] == "holds"
    assert f.loc[("linear > exp", "tree-v2"), "p_holm"] < 0.05 <= f.loc[("linear > fixed", "tree-v2"), "p_holm"]
    # The stress room is its own Holm family: its check does not enter the unseen scenes' verdict.
    assert res.summary.set_index("finding").loc["6 linear decay beats exponential and fixed", "checks"] == 6

    ran = res.ran.set_index("rate_key")
    # Only what ran: the skipped training is not counted; 960 s of 1,000 iterations planned at 1.25/s = 800 s.
    assert list(ran.index) == ["pretrain"] and ran.loc["pretrain", "measured_h"] == pytest.approx(960 / 3600)
    assert ran.loc["pretrain", "planned_h"] == pytest.approx(800 / 3600)
    assert ran.loc["pretrain", "resumed"] == 1
    # The other five grids are left whole (Table I's runs aside): their variants' trainings are in the rest.
    assert res.rest["jobs"].sum() > 0 and "train:frozen" in set(res.rest["rate_key"])
    assert "| decay | pretrain | 2 | 1 | 0.22 | 0.27 | 1.20 |" in (tables / "ablation_account.md").read_text()


def test_tables_names_the_grids_it_takes(tmp_path, monkeypatch):
    from omcrl.pipeline.tables import tables_stage

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("quick", overrides=[f"results_dir={tmp_path / 'results'}"])
    with pytest.raises(ConfigError, match="add --from-reference"):
        tables_stage(cfg, grid="ablations")
    with pytest.raises(FileNotFoundError, match="no ablation grid has recorded episodes"):
        tables_stage(cfg, from_reference=True, grid="ablations")
    out = subprocess.run([sys.executable, "-m", "omcrl", "tables", "--preset", "quick", "--from-reference", "--grid",
                          "decay"], capture_output=True, text=True, env=dict(os.environ))  # fmt: skip
    assert out.returncode != 0 and "'ablations'" in out.stderr


def test_findings_are_judged_again_on_table_i_runs_where_both_variants_are_table_i_methods(tmp_path, monkeypatch):
    """An ordering whose two variants are Table I methods with no override (ours and ours w/o OT) is judged again on
    Table I's runs (all their training seeds), in its own file and Holm family; one whose variant is not a Table I
    method (ours w/o phi) or has overrides (decay's schedules) is not."""
    from omcrl.pipeline.tables import tables_stage

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("quick", overrides=[f"results_dir={tmp_path / 'results'}"])
    rng = np.random.default_rng(5)
    grid = GridData(grid_data_dir(cfg, "oracle-teacher"))
    for s in (0, 1, 2):  # the sweep budget: no difference between the two
        grid.save_episodes("Ours", s, _episodes("Ours", 0.5, s, rng))
        grid.save_episodes("Ours w/o OT", s, _episodes("Ours w/o OT", 0.5, s, rng))
    table1 = GridData(grid_data_dir(cfg, "table1"))
    for s in range(5):  # Table I's budget: ours far above ours w/o OT
        for method, p in (("ours", 0.9), ("ours-noOT", 0.1), ("ours-noPhi", 0.0)):
            table1.save_episodes(method, s, _episodes(method, p, s, rng).assign(method=method))

    res = tables_stage(cfg, from_reference=True, grid="ablations")
    again = res.at_table1.set_index(["claim", "scene"])
    assert set(again.index.get_level_values("claim")) == {"Ours > Ours w/o OT"}
    assert again.loc[("Ours > Ours w/o OT", "tree-v2"), "verdict"] == "holds"
    assert (again["seeds"] == 5).all()
    assert res.findings.set_index(["claim", "scene"]).loc[("Ours > Ours w/o OT", "tree-v2"), "verdict"] == "undecided"
    text = (cfg.run_root / "tables" / "ablation_findings_table1.md").read_text(encoding="utf-8")
    assert text.startswith("The same orderings judged on Table I's runs")
    from omcrl.pipeline.glance import ablation_block

    block = " ".join(ablation_block("quick", reps=200).split())  # the page names the orderings the checks judged
    assert "Table I methods as they are (Ours > Ours w/o OT), Table I's runs judge it again" in block


def test_a_resumed_job_is_the_one_whose_record_says_it_began_after_zero(tmp_path):
    """The account's "of them resumed" reads ``start`` where jobs.csv keeps it: a job that ran from 0 at a smaller
    budget is not a resume, one that began at its checkpoint is, whatever its work. A row written before ``start``
    was kept (empty) is judged by its work below the largest of its kind, as before."""
    from omcrl.pipeline.ablations import _resumed

    pd.DataFrame([
        {"id": "a", "status": "done", "seconds": 9.0, "rate_key": "pretrain", "work": 750, "start": 0},
        {"id": "b", "status": "done", "seconds": 3.0, "rate_key": "pretrain", "work": 250, "start": 0},  # smaller
        {"id": "c", "status": "done", "seconds": 8.0, "rate_key": "pretrain", "work": 750, "start": 100},
        {"id": "g", "status": "done", "seconds": 6.0, "rate_key": "pretrain", "work": 500, "start": 0},  # smaller
        {"id": "d", "status": "done", "seconds": 2.0, "rate_key": "pretrain", "work": 250, "start": None},  # old row
        {"id": "e", "status": "done", "seconds": 5.0, "rate_key": "train:frozen", "work": 900, "start": 0},
        {"id": "f", "status": "skipped", "seconds": 0.1, "rate_key": "train:frozen", "work": 10, "start": 500},
    ]).to_csv(tmp_path / "jobs.csv", index=False)  # fmt: skip
    assert _resumed(tmp_path) == {"pretrain": 2}  # c by its start, d by its work; f ran nothing
    pd.read_csv(tmp_path / "jobs.csv").drop(columns="start").to_csv(tmp_path / "jobs.csv", index=False)
    assert _resumed(tmp_path) == {"pretrain": 3}  # no start column at all: b, d and g by their work
