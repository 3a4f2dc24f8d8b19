"""The budget ladder (omcrl.pipeline.ladder): its points from the grids, its tables, verdicts by budget and figures
rebuilt from grid records alone, and the encoder reports (omcrl.interpret.encoder_report) its encoder table reads."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from omcrl.config import load_config
from omcrl.pipeline.griddata import GridData, grid_data_dir
from omcrl.pipeline.ladder import (
    ladder_episodes,
    ladder_markdown,
    ladder_points,
    ladder_stage,
    record_encoder_reports,
    scale_effects,
)

SCENES = ("box-v2", "furniture-v2", "barrier-v2", "tree-v2")


def _episodes(
    method: str, label: str, p: float, seed: int, rng: np.random.Generator, layouts: int = 40
) -> pd.DataFrame:
    ok = rng.random((len(SCENES), layouts)) < p
    rows = [{"method": method, "label": label, "scene": sc, "train_seed": seed, "seed": j, "success": bool(ok[i, j]),
             "collision": not ok[i, j], "final_distance": 0.1 if ok[i, j] else 3.0,
             "min_distance": 0.1 if ok[i, j] else 2.0, "path_length": 8.0, "optimal_path_length": 7.0, "steps": 80}
            for i, sc in enumerate(SCENES) for j in range(layouts)]  # fmt: skip
    return pd.DataFrame(rows)


def test_the_ladders_points_come_from_the_grids():
    pts = ladder_points()
    pre = pts[pts.axis == "pretrain"]
    assert {(m, s) for m, s in zip(pre.method, pre.scale)} == {(m, s) for m in ("ours", "curl") for s in (1, 4, 16)}
    assert set(pre.loc[pre.scale == 1, "grid"]) == {"table1"} and set(pre.loc[pre.scale > 1, "grid"]) == {
        "ladder-pretrain"
    }
    rl = pts[pts.axis == "rl"]
    assert {(m, s) for m, s in zip(rl.method, rl.scale)} == {
        (m, s) for m in ("ours", "npe", "curl", "ppo") for s in (1, 3)
    }


def test_the_ladder_is_rebuilt_from_the_records_alone(tmp_path, monkeypatch):
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("smoke", overrides=["eval.scenes=[box-v2,furniture-v2,barrier-v2,tree-v2]"])
    with pytest.raises(FileNotFoundError, match="no ladder point has recorded episodes"):
        ladder_stage(cfg, reps=100)
    rng = np.random.default_rng(0)
    base, pre = GridData(grid_data_dir(cfg, "table1")), GridData(grid_data_dir(cfg, "ladder-pretrain"))
    # x1: ours and curl alike (the ledger's "ours > curl" undecided); x4: ours far ahead of curl (it holds).
    for s in (0, 1, 2):
        for m in ("ours", "curl"):
            base.save_episodes(m, s, _episodes(m, m, 0.5, s, rng))
        pre.save_episodes("ours pretrain x4", s, _episodes("ours", "ours pretrain x4", 0.9, s, rng))
        pre.save_episodes("curl pretrain x4", s, _episodes("curl", "curl pretrain x4", 0.1, s, rng))
    base.save_episodes("ours", 3, _episodes("ours", "ours", 0.0, 3, rng))  # Table I's seed 3: not a ladder seed
    base.save_episodes("hybrid-apf", 0, _episodes("hybrid-apf", "hybrid-apf", 0.3, 0, rng))
    rec = pre.folder("ours pretrain x4", 0) / "pretrain"
    rec.mkdir(parents=True)
    settings = ["box-v2", "box-v2, other layouts", "furniture-v2"]
    (rec / "report.json").write_text(json.dumps({"top1": 0.4, "probe_r2": dict(zip(settings, (0.3, 0.25, 0.1))),
                                                 "mmd": dict(zip(settings, (0.0, 0.01, 0.2)))}))  # fmt: skip

    res = ladder_stage(cfg, reps=300)
    t = res.table.set_index(["axis", "method", "scale", "scene"])
    assert (
        t.loc[("pretrain", "ours", 4.0, "tree-v2"), "SR"] > 75
        and t.loc[("pretrain", "curl", 4.0, "tree-v2"), "SR"] < 25
    )
    assert t.loc[("pretrain", "ours", 1.0, "tree-v2"), "seeds"] == 3  # the x1 points at the ladder's seeds only
    assert ("rl", "ours", 1.0, "box-v2") in t.index and ("pretrain", "ours", 16.0, "box-v2") not in t.index
    for col in ("SR", "SR_lo", "SR_hi"):  # Table I's runs are both ladders' x1: one interval, printed twice
        assert t.loc[("rl", "ours", 1.0, "tree-v2"), col] == t.loc[("pretrain", "ours", 1.0, "tree-v2"), col]
    enc = res.encoders.set_index(["method", "scale"])
    assert enc.loc[("ours", 4.0), "top1"] == 0.4 and enc.loc[("ours", 4.0), "R2 furniture-v2"] == 0.1
    assert "MMD box-v2" not in enc and enc.loc[("ours", 4.0), "MMD furniture-v2"] == 0.2
    v = res.verdicts.set_index(["axis", "scale", "hypothesis"])
    row = "ours > curl on SR in tree-v2"
    assert v.loc[("pretrain", 4.0, row), "verdict"] == "holds"
    assert v.loc[("pretrain", 1.0, row), "verdict"] == "undecided"
    assert not res.verdicts["a"].eq("hybrid-apf").all()  # planner-only rows are left out
    wide = pd.read_csv(res.paths["ladder_verdicts.csv"])
    assert len(wide) == len(res.verdicts)
    md = res.paths["ladder_verdicts.md"].read_text()
    line = next(x for x in md.splitlines() if f"| {row} |" in x)
    assert "holds" in line and "undecided" in line and line.rstrip("| ").endswith("no")  # stable pretrain: no
    for scene in SCENES:
        assert res.paths[f"ladder_{scene}"].stat().st_size > 5_000
    # docs/results.md's block: points and their seeds, a decided row beside its budgets, the figures it shows.
    md = ladder_markdown(res, "figures/x")
    assert "| ours | 3/3 | 3/3 | 0/3 |" in md and "| npe | 0/3 | 0/3 |" in md
    assert "| pretrain | ours | ×4 | 3 |" in md and "| pretrain | ours | ×16 |" not in md
    line = next(x for x in md.splitlines() if f"| {row} |" in x)
    assert "undecided" in line and "holds" in line and line.rstrip("| ").endswith("no")
    assert "- pretrain ×4: " in md and "![ladder, tree-v2](figures/x/ladder_tree-v2.png)" in md
    assert "| ours | ×4 | 1 | 0.4 |" in md  # the encoder report of seed 0 at x4
    # Probe and shift in two tables headed by scene alone (one of thirteen columns ran off a page's width).
    heads = [x for x in md.splitlines() if x.startswith("| method | budget | seeds | ")]
    assert heads[0].startswith("| method | budget | seeds | top1 | box-v2 |") and "furniture-v2" in heads[0]
    assert heads[1].startswith("| method | budget | seeds | box-v2, other layouts |") and "top1" not in heads[1]
    assert not any("R2 " in h or "MMD " in h for h in heads)
    # The direct test of a change with budget: ours rose from 50 % to 90 %, curl fell to 10 %, paired with x1.
    eff = res.effects.set_index(["axis", "method", "scale", "scene"])
    for scene in ("barrier-v2", "tree-v2"):  # (with three seeds a 40-point move is not resolved in every scene)
        assert eff.loc[("pretrain", "ours", 4.0, scene), "verdict"] == "up"
        assert eff.loc[("pretrain", "curl", 4.0, scene), "verdict"] == "down"
    assert eff.loc[("pretrain", "ours", 4.0, "box-v2"), "seeds"] == 3 and ("rl", "ours", 3.0, "box-v2") not in eff.index
    d = eff.loc[("pretrain", "ours", 4.0, "tree-v2")]
    assert d["lo"] < d["diff"] < d["hi"] and 25 < d["diff"] < 55
    assert "SR change from ×1" in md and "| pretrain | ours | ×4 | 3 | +" in md and "↑" in md and "↓" in md
    assert "of 1 hypotheses judged at two or more budgets" not in md and "pretrain ladder: of " in md
    assert res.paths["ladder_scale.md"].read_text().count("| pretrain |") == 2
    # Cost: the jobs the ladder's grid ran against the rates its plan kept (skipped jobs ran nothing).
    assert res.cost.empty and "Cost: the plan's prediction" not in md
    assert res.rest.empty and "What the rest would cost" not in md  # no plan's rates kept, no hours
    folder = grid_data_dir(cfg, "ladder-pretrain")
    (folder / "plan_rates.json").write_text(json.dumps({"pretrain": 2.0, "train:frozen": 100.0}))
    pd.DataFrame(
        [
            ("p0", "pretrain", "done", 1800.0, "pretrain", 6000),
            ("t0", "train", "done", 3600.0, "train:frozen", 450000),
            ("o0", "train", "skipped", 0.4, "train:oracle", 450000),
            ("c0", "collect", "done", 120.0, "collect", 320),
        ],
        columns=["id", "kind", "status", "seconds", "rate_key", "work"],
    ).assign(method="ours", seed=0).to_csv(folder / "jobs.csv", index=False)
    res = ladder_stage(cfg, reps=100)
    cost = res.cost.set_index("rate_key")
    assert list(cost.index) == ["pretrain", "train:frozen", "collect"]
    assert (
        cost.at["pretrain", "planned_h"] == pytest.approx(6000 / 2.0 / 3600)
        and cost.at["pretrain", "measured_h"] == 0.5
    )
    assert cost.at["train:frozen", "planned_h"] == pytest.approx(1.25) and np.isnan(cost.at["collect", "planned_h"])
    md = ladder_markdown(res)
    assert "| pretrain | pretrain | 1 | 6,000 | 0.83 | 0.50 | 0.60 |" in md
    assert "| pretrain | collect | 1 | 320 | – | 0.03 | – |" in md and "| pretrain | all | 3 | – | – | 1.53 | – |" in md
    # What the rest costs: the x16 points, recorded nowhere, at the plan's rates and the ratio measured for the kind.
    rest = res.rest.set_index("rate_key")
    assert set(res.rest["ladder"]) == {"pretrain"}  # the rl ladder kept no plan rates
    n_iter = 16 * cfg.pretrain.iterations
    assert rest.at["pretrain", "jobs"] == 6 and rest.at["pretrain", "work"] == 6 * n_iter  # ours, curl x seeds 0-2
    assert rest.at["pretrain", "planned_h"] == pytest.approx(6 * n_iter / 2.0 / 3600)
    assert rest.at["pretrain", "ratio"] == pytest.approx(0.6)  # 0.50 h measured / 0.83 h planned
    assert rest.at["pretrain", "estimate_h"] == pytest.approx(0.6 * 6 * n_iter / 2.0 / 3600)
    assert np.isnan(rest.at["evaluate", "planned_h"])  # no plan rate: no hours, said as "–"
    assert "What the rest would cost" in md and "| pretrain | pretrain | 6 | " in md
    # A point of one training seed is compared with x1's same seed and shown, not judged.
    ep = ladder_episodes(cfg)
    one = scale_effects(ep[(ep["scale"] == 1.0) | (ep["train_seed"] == 0)], reps=100)
    assert set(one["verdict"]) == {"one seed"} and set(one["seeds"]) == {1}


def test_an_encoder_report_is_written_once_per_encoder_and_travels_with_the_record(tmp_path, monkeypatch):
    from omcrl.interpret.encoder_report import read_report, write_encoder_report
    from omcrl.pipeline import pretrain_method
    from omcrl.pipeline.stages import collect_stage

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("smoke", overrides=["eval.scenes=[box-v2,tree-v2]", "eval.episodes=8"])
    collect_stage(cfg, progress=False)
    run = pretrain_method(cfg, "ours", progress=False)
    # The grid's record of that run (as a sweep keeps it) and one whose encoder this machine does not have.
    data = GridData(grid_data_dir(cfg, "ladder-pretrain"))
    data.save_run("ours pretrain x4", 0, "pretrain", run.run_dir)
    other = data.folder("curl pretrain x4", 0) / "pretrain"
    other.mkdir(parents=True)
    (other / "run.json").write_text(json.dumps({"method": "curl", "key": "0123456789", "seed": 0}))
    # ... and one whose run folder is here, but holds another encoder than the one its record names.
    (data.folder("ours pretrain x16", 0) / "pretrain").mkdir(parents=True)
    foreign = json.loads((run.run_dir / "run.json").read_text()) | {"artifact_digest": "of the recorded encoder"}
    (data.folder("ours pretrain x16", 0) / "pretrain" / "run.json").write_text(json.dumps(foreign))
    written, missing = record_encoder_reports(cfg, ["ladder-pretrain"])
    assert written == [data.folder("ours pretrain x4", 0) / "pretrain"]
    assert [m[0] for m in missing] == [other, data.folder("ours pretrain x16", 0) / "pretrain"]
    assert "curl-0123456789" in str(missing[0][1]) and not (missing[1][0] / "report.json").exists()
    rep = read_report(written[0])
    assert rep == read_report(run.run_dir) and rep["reference"] == "box-v2"
    assert list(rep["probe_r2"]) == ["box-v2", "box-v2, other layouts", "tree-v2"] and rep["episodes"] == 2
    assert rep["mmd"]["box-v2"] == 0.0 and rep["mmd"]["tree-v2"] > rep["mmd"]["box-v2, other layouts"]
    assert 0.0 <= rep["top1"] <= 1.0 and all(np.isfinite(list(rep["probe_r2"].values())))
    # Once per encoder: a second call keeps the file; a report of another encoder file (digest) is made again.
    path = run.run_dir / "report.json"
    before = path.stat().st_mtime_ns
    write_encoder_report(cfg, run.run_dir)
    assert path.stat().st_mtime_ns == before
    path.write_text(json.dumps({**rep, "encoder_digest": "of another encoder"}))
    write_encoder_report(cfg, run.run_dir)
    assert read_report(run.run_dir) == rep


def test_a_point_of_fewer_seeds_is_drawn_hollow_and_labelled():
    from omcrl.viz.ladder import plot_ladder

    points = ((1.0, 3, 40.0), (4.0, 1, 5.0), (16.0, 3, 50.0))  # (budget, seeds, SR)
    rows = [{"axis": "pretrain", "method": "ours", "scale": k, "scene": "tree-v2", "seeds": n, "SR": sr,
             "SR_lo": sr - 10, "SR_hi": sr + 10} for k, n, sr in points]  # fmt: skip
    fig = plot_ladder(pd.DataFrame(rows), "tree-v2", {"pretrain": "1,500 iterations"})
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.texts] == ["1 seed"]
    hollow = [ln for ln in ax.lines if ln.get_markerfacecolor() in ("white", "w", (1.0, 1.0, 1.0, 1.0))]
    assert len(hollow) == 1 and list(hollow[0].get_ydata()) == [5.0]
    assert "ours (1-3 seeds)" in [t.get_text() for t in ax.get_legend().get_texts()]
    # Each seed's own SR beside its point: the spread an interval of three seeds summarises.
    per_seed = pd.DataFrame([{"axis": "pretrain", "method": "ours", "scale": k, "scene": "tree-v2", "train_seed": s,
                              "SR": sr + 10 * (s - 1)} for k, n, sr in points for s in range(n)])  # fmt: skip
    fig = plot_ladder(pd.DataFrame(rows), "tree-v2", {"pretrain": "1,500 iterations"}, per_seed=per_seed)
    dots = [ln for ln in fig.axes[0].lines if ln.get_marker() == "."]
    assert len(dots) == 1 and sorted(dots[0].get_ydata()) == sorted(per_seed["SR"])
