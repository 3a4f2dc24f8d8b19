"""The summary (``python -m omcrl summary``, results/<preset>/summary.md): what it lists from the stages' files,
and what it says when a stage has not run."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from omcrl.config import load_config
from omcrl.pipeline.records import RECORDS, DataRecord, OracleRecord, PretrainRecord, Table1Record


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
    # Two stages' records, built with the library's types as the notebooks build them.
    DataRecord(file="data/quick/box.h5", episodes=80, steps=12345, pilot_success_rate=0.75, file_mb=27.0).write(
        root / "tables"
    )
    OracleRecord(steps=150000.0, steps_per_s=212.0, final_success_rate=0.93,
                 eval_box={"SR": 96.0, "SPL": 0.81, "CR": 2.0, "episodes": 50}).write(root / "tables")  # fmt: skip


@pytest.mark.parametrize("preset", ["smoke", "quick"])
def test_summary_lists_every_figure_and_the_table(tmp_path, preset):
    from omcrl.pipeline.pages import render
    from omcrl.pipeline.summary import write_summary

    SMOKE_NOTE = render("summary/smoke_note.md.j2", layout=False).strip()

    cfg = load_config(preset, overrides=[f"results_dir={tmp_path}"])
    _fake_results(cfg.run_root)
    path = write_summary(cfg)
    assert path == cfg.run_root / "summary.md"
    text = path.read_text()
    for f in (cfg.run_root / "figures").glob("*.png"):
        assert f"(figures/{f.name})" in text
    # Table I compact: a row per method, a column per scene, the paper's value in italics where it has one.
    assert "| method | box-v2 (training) | tree-v2 (hard) |" in text  # families: their latest version
    assert "| CURL | 90 [81, 99] | 90 [81, 99] *0* |" in text and "| Ours | 5 [4, 6] | 5 [4, 6] *8* |" in text
    assert "19m02s" in text and "19m08s" in text  # notebook 02 and the total
    assert "| 412 MB |" in text and text.count("| 1,830 MB |") == 2  # notebook 02 and the total's peak
    assert "not run yet (notebook 04_train_student)" in text  # a missing stage is named, not skipped silently
    assert "80 episodes, 12,345 steps in `data/quick/box.h5` (27.0 MB)" in text
    assert "training SR (last updates) 93" in text and "evaluation in box: SR 96" in text
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


def test_records_round_trip_and_read_the_files_of_older_versions(tmp_path):
    """Each stage record writes the JSON its notebook wrote before the types existed and reads it back; a file
    from an older version (a missing field, an extra key) still reads; a damaged one is one line naming it."""
    from omcrl.runs import CorruptFile

    for cls in RECORDS:
        rec = cls()
        assert cls.read(tmp_path) is None
        rec.write(tmp_path)
        assert cls.read(tmp_path) == rec, cls.__name__
    flat = {"OMC": {"iterations": 1500, "final_loss": 2.1}, "probe_r2": {"OMC": {"mean_r2": 0.31}}}
    (tmp_path / PretrainRecord.FILE).write_text(json.dumps(flat))
    pre = PretrainRecord.read(tmp_path)
    assert pre.encoders == {"OMC": flat["OMC"]} and pre.probe_r2["OMC"]["mean_r2"] == 0.31
    assert json.loads(pre.write(tmp_path).read_text()) == flat  # the same layout as before
    (tmp_path / OracleRecord.FILE).write_text(json.dumps({"steps": 10.0, "a_key_from_the_future": 1}))
    assert OracleRecord.read(tmp_path).steps == 10.0
    (tmp_path / DataRecord.FILE).write_text("[1, 2]")
    with pytest.raises(CorruptFile, match=r"data_summary.json is not a readable DataRecord"):
        DataRecord.read(tmp_path)


def test_readme_results_at_a_glance_match_the_reference_table(repo_root):
    """The README's table and verdicts are what reference/quick/table1 gives: re-run
    `python -m omcrl summary --preset quick --readme` after the reference Table I changes."""
    from omcrl.pipeline.glance import current_block, reference_table_dir, render_glance

    readme = (repo_root / "README.md").read_text(encoding="utf-8")
    assert current_block(readme) == render_glance(reference_table_dir("quick"))


def test_results_pages_v1_table_and_orderings_are_what_the_reference_table_gives(repo_root):
    """docs/results.md's v1 Table I and its orderings are rendered from reference/quick/table1 (a hand-edited cell
    fails here): re-run `python -m omcrl summary --preset quick --readme` after that table changes."""
    from omcrl.pipeline.glance import V1_END, V1_START, current_block, reference_table_dir, render_v1_results

    page = (repo_root / "docs" / "results.md").read_text(encoding="utf-8")
    block = current_block(page, "docs/results.md", V1_START, V1_END)
    assert "| Ours | 95 [91, 98] |" in block and "| curl > npe | **reversed**" in block
    assert block == render_v1_results(reference_table_dir("quick"))


def test_readme_v2_table_and_verdicts_are_what_the_grid_data_gives(repo_root, pages):
    """The README's v2 block is rebuilt from reference/quick/table1-v2/ alone (Table I, the ledger's verdicts): re-run
    `python -m omcrl summary --preset quick --readme` after grid data is committed. A hand-edited cell fails here."""
    from omcrl.pipeline.glance import FULL_END, FULL_START, V2_END, V2_START, current_block

    short, full = pages["README.md"][V2_START], pages["docs/results.md"][FULL_START]
    readme = (repo_root / "README.md").read_text(encoding="utf-8")
    block = current_block(readme, start=V2_START, end=V2_END)
    assert "| Blind pilot (senses nothing) |" in block and "ledger fixed before any v2 evaluation" in block
    assert block == short
    results = (repo_root / "docs" / "results.md").read_text(encoding="utf-8")
    assert current_block(results, "docs/results.md", FULL_START, FULL_END) == full
    assert "**tree-v2 (hard)**" in full and "| E1 | ours > npe on SR in tree-v2 |" in full


def test_the_confirmations_block_is_what_its_data_gives(repo_root, pages):
    """docs/results.md's block on Table I's confirmation on fresh layouts is rebuilt from
    reference/quick/table1-confirm-v2/ and the grid's verdicts (summary --readme): a hand-edited cell fails here."""
    from omcrl.pipeline.glance import CONFIRM_END, CONFIRM_START, current_block

    block = pages["docs/results.md"][CONFIRM_START]
    page = (repo_root / "docs" / "results.md").read_text(encoding="utf-8")
    assert current_block(page, "docs/results.md", CONFIRM_START, CONFIRM_END) == block
    assert block.startswith(("**Flown**", "Not flown yet"))
    if block.startswith("**Flown**"):  # its tables stay tables (a table row is never wrapped into prose)
        assert "\n| claim | hypothesis | grid | grid verdict |" in block and "\n| Oracle |" in block
    assert max(len(line) for line in block.splitlines() if not line.startswith("|")) <= 120


def test_the_ladders_block_is_what_its_data_gives(repo_root, pages):
    """docs/results.md's budget-ladder block is rebuilt from the grids table1, ladder-pretrain and ladder-rl under
    reference/quick/ (summary --readme): a hand-edited cell fails here, and every figure it shows is in the checkout."""
    from omcrl.pipeline.glance import LADDER_END, LADDER_START, current_block

    block = pages["docs/results.md"][LADDER_START]
    page = (repo_root / "docs" / "results.md").read_text(encoding="utf-8")
    assert current_block(page, "docs/results.md", LADDER_START, LADDER_END) == block
    assert "| pretrain ladder | ×1 | ×4 | ×16 |" in block and "| rl | ours | ×1 | 3 |" in block
    for image in re.findall(r"\]\((figures/[^)]+\.png)\)", block):
        assert (repo_root / "docs" / image).is_file(), image
    assert max(len(line) for line in block.splitlines() if not line.startswith("|")) <= 120


def test_the_v2_ablations_block_is_what_its_data_gives(repo_root, pages):
    """docs/results.md's v2 ablations block is rebuilt from reference/quick/<grid>-v2/ for the six ablation grids
    (summary --readme): a hand-edited cell fails here."""
    from omcrl.pipeline.glance import ABLATION_END, ABLATION_START, current_block

    block = pages["docs/results.md"][ABLATION_START]
    page = (repo_root / "docs" / "results.md").read_text(encoding="utf-8")
    assert current_block(page, "docs/results.md", ABLATION_START, ABLATION_END) == block
    assert block.startswith(("**Recorded**", "Not run yet"))
    assert max(len(line) for line in block.splitlines() if not line.startswith("|")) <= 120


def test_the_ablations_block_judges_the_findings_from_the_grid_records(tmp_path, monkeypatch):
    """The block from grid records alone: a variant far below its partner makes the finding hold in every unseen
    scene, one recorded at a single seed is shown and not judged, and grids with nothing recorded say 0/3."""
    import numpy as np
    import pandas as pd

    from omcrl.pipeline.glance import ablation_block
    from omcrl.pipeline.griddata import GridData, grid_data_dir

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    scenes = ("box-v2", "furniture-v2", "barrier-v2", "tree-v2")
    rng = np.random.default_rng(1)

    def episodes(method: str, label: str, p: float, seed: int) -> pd.DataFrame:
        ok = rng.random((len(scenes), 50)) < p
        return pd.DataFrame([{"method": method, "label": label, "scene": sc, "train_seed": seed, "seed": j,
                              "success": bool(ok[i, j]), "collision": not ok[i, j],
                              "final_distance": 0.1 if ok[i, j] else 3.0, "min_distance": 0.1 if ok[i, j] else 2.0,
                              "path_length": 8.0, "optimal_path_length": 7.0, "steps": 80}
                             for i, sc in enumerate(scenes) for j in range(50)])  # fmt: skip

    cfg = load_config("quick")
    ot = GridData(grid_data_dir(cfg, "oracle-teacher"))
    for s in (0, 1, 2):
        ot.save_episodes("Ours", s, episodes("ours", "Ours", 0.9, s))
        ot.save_episodes("Ours w/o OT", s, episodes("ours-noOT", "Ours w/o OT", 0.1, s))
    ot.save_episodes("NPE", 0, episodes("npe", "NPE", 0.5, 0))
    ot.save_episodes("NPE w/ OT", 0, episodes("npe-ot", "NPE w/ OT", 0.5, 0))
    ot.save_episodes("Ours", 3, episodes("ours", "Ours", 0.0, 3))  # not one of the block's seeds
    block = ablation_block("quick", reps=200)
    lines = block.splitlines()
    assert "| oracle-teacher | Ours | 3/3 |" in lines and "| oracle-teacher | NPE | 1/3 |" in lines
    assert "| decay | linear | 0/3 |" in lines
    # 9 checks (3 orderings x 3 unseen scenes): Ours > Ours w/o OT holds in each; the 6 of one seed are not judged.
    assert "| 5 the oracle teacher helps ours and NPE | 9 | 3 | 0 | 0 | holds |" in block
    check = next(x for x in lines if "| Ours > Ours w/o OT |" in x)
    assert check.count(" holds") == 3 and "box-v2" not in check
    assert next(x for x in lines if "| NPE w/ OT > NPE |" in x).count("one seed") == 3
    sr = next(x for x in lines if x.startswith("| oracle-teacher | Ours | 3 |"))
    assert len(sr.split("|")) == 2 + 3 + len(scenes) and "[" in sr


def test_generalizations_transfer_table_is_what_the_grid_data_gives(repo_root):
    """docs/generalization.md's "what transfers" table is rebuilt from reference/quick/table1-v2/ (summary --readme):
    a hand-edited cell fails here. Each change is SR(scene) − SR(box-v2) of the same runs."""
    from omcrl.pipeline.glance import TRANSFER_END, TRANSFER_START, current_block, transfer_block

    block = transfer_block("quick")
    page = (repo_root / "docs" / "generalization.md").read_text(encoding="utf-8")
    assert current_block(page, "docs/generalization.md", TRANSFER_START, TRANSFER_END) == block
    assert "| Ours |" in block and "| Oracle |" in block and "furniture-v2" in block
    assert max(len(line) for line in block.splitlines() if not line.startswith("|")) <= 120


def test_a_transfer_change_is_paired_by_training_seed():
    """The change from the training scene pairs each run with itself: a method whose every seed loses exactly the
    same episodes shows that loss with no seed spread, and one that flies every scene alike shows 0 [0, 0]."""
    import pandas as pd

    from omcrl.pipeline.glance import render_transfer

    rows = []
    for seed in range(3):
        for scene, ok in (("box-v2", [1, 1, 1, 1]), ("furniture-v2", [1, 1, 0, 0]), ("tree-v2", [1, 1, 1, 1])):
            for i, s in enumerate(ok):
                rows.append({"method": "ours", "scene": scene, "train_seed": seed, "seed": 100 * i + len(scene),
                             "success": bool(s)})  # fmt: skip
    md = render_transfer(pd.DataFrame(rows), reps=200)
    line = next(x for x in md.splitlines() if x.startswith("| Ours |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1] == "100" and cells[-1] == "3"
    assert cells[3] == "0 [0, 0]"  # tree-v2: nothing lost
    assert cells[2].startswith("−50 [")  # furniture-v2: half the layouts lost, by every seed alike


def test_the_glossarys_metrics_table_is_the_one_the_tables_print(repo_root):
    """docs/glossary.md's metrics table is omcrl.eval.metrics.GLOSSARY rendered (what Table I, the summary and
    notebook 07 print): a definition edited by hand on the page fails here."""
    from omcrl.eval.metrics import glossary_markdown
    from omcrl.pipeline.glance import GLOSSARY_END, GLOSSARY_START, current_block

    page = (repo_root / "docs" / "glossary.md").read_text(encoding="utf-8")
    assert current_block(page, "docs/glossary.md", GLOSSARY_START, GLOSSARY_END) == glossary_markdown()
    assert max(len(line) for line in glossary_markdown().splitlines()) <= 120


def test_readme_block_is_replaced_between_its_markers_only(tmp_path):
    from omcrl.pipeline.glance import END, START, GlanceError, current_block, replace_block

    text = f"head\n{START}\nold\n{END}\ntail\n"
    new = replace_block(text, "new table")
    assert new.startswith("head\n") and new.endswith("tail\n") and current_block(new) == "new table"
    with pytest.raises(GlanceError, match="README.md: the markers"):
        replace_block("no markers here", "x")


def test_the_teachers_ceiling_block_is_what_the_grid_data_gives(repo_root):
    """Issue 75: docs/results.md's SR / CR / timeout by detour is rebuilt from reference/quick/table1-v2/ and the
    layouts' geometry (summary --readme); each cell's shares add up to its episodes, each scene's bins to its
    layouts."""
    from omcrl.pipeline.glance import current_block
    from omcrl.pipeline.why import WHY_DETOUR_END, WHY_DETOUR_START, detour_block, detour_table

    table = detour_table("quick")
    shares = table[["SR", "CR", "OUT", "TO"]].sum(axis=1)
    assert ((shares - 100.0).abs() < 1e-9).all()
    assert ((table.groupby(["method", "scene"])["layouts"].sum() - 100.0).abs() < 1e-9).all()
    assert set(table.scene) == {"box-v2", "furniture-v2", "barrier-v2", "tree-v2"}
    page = (repo_root / "docs" / "results.md").read_text(encoding="utf-8")
    assert current_block(page, "docs/results.md", WHY_DETOUR_START, WHY_DETOUR_END) == detour_block("quick", table)
    assert "| Oracle |" in page and "**barrier-v2**" in page


def test_the_attribution_splits_a_loss_into_geometry_and_look_with_the_right_pairing():
    """Issue 75: on episodes made up so that SR is 80 % in box-v2, 60 % on tree-v2's layouts in box's look and 30 % in
    tree-v2's own look (every seed alike), the attribution reads geometry −20 and look −30, each inside its interval;
    a scene not flown in box's look gives no number."""
    import numpy as np
    import pandas as pd

    from omcrl.pipeline.why import attribution, attribution_block

    def eps(scene, rate, seeds=(0, 1, 2), layouts=20, shift=0):
        rows = []
        for s in seeds:
            for k in range(layouts):
                rows.append({"method": "ours", "scene": scene, "train_seed": s, "seed": 1_000_000 + k,
                             "episode": k, "success": (k + shift) % 10 < rate // 10})  # fmt: skip
        return rows

    own = pd.DataFrame(eps("box-v2", 80) + eps("tree-v2", 30))
    look = pd.DataFrame(eps("tree-v2", 60))
    t = attribution(own, look, reps=200)
    r = t[t.scene == "tree-v2"].iloc[0]
    assert r.seeds == 3 and (r.box, r.box_look, r.own) == (80.0, 60.0, 30.0)
    assert r.geometry == -20.0 and r.look == -30.0
    assert r.look_lo <= -30.0 <= r.look_hi and r.geometry_lo < -20.0 < r.geometry_hi
    assert np.isnan(t[t.scene == "barrier-v2"].iloc[0].look)  # not flown there: no number
    assert "| Ours | 3 | 80 [" in attribution_block(table=t) and "**tree-v2**" in attribution_block(table=t)
    rows = [line for line in attribution_block(table=t).splitlines() if line.startswith("| Ours |")]
    assert "| −20 [−" in rows[-1] and "-" not in "".join(rows)  # a minus sign, not a hyphen
    bounds = t[["geometry_lo", "look_lo", "geometry_hi", "look_hi"]].dropna()
    assert len(bounds) and bounds.abs().le(100).all().all()  # a difference of two SRs stays in [-100, 100]
    # Two seeds that disagree completely in tree's own look (0 % and 100 %): the look's interval is cut at ±100.
    split = pd.DataFrame(
        eps("box-v2", 80, seeds=(0, 1)) + eps("tree-v2", 0, seeds=(0,)) + eps("tree-v2", 100, seeds=(1,))
    )
    wide = attribution(split, pd.DataFrame(eps("tree-v2", 60, seeds=(0, 1))), reps=200)
    r = wide[wide.scene == "tree-v2"].iloc[0]
    assert r.look_lo == -100.0 and r.look_hi == 100.0
    assert attribution(own, look.iloc[0:0]).empty


def test_a_retrained_seed_replaces_table1s_run_of_it_in_all_three_settings():
    """Issue 75: a seed the retrain grid flew in both its variants is taken whole from there (box-v2, box's look and
    the own look all its own), Table I's run of that seed left out, even where the box-look grid also flew it; a
    seed retrained in one variant only changes nothing; the block says how many seeds were retrained."""
    import pandas as pd

    from omcrl.pipeline.why import attribution, attribution_block

    def eps(scene, rate, seeds, label="ours"):
        return [{"method": "ours", "label": label, "scene": scene, "train_seed": s, "seed": 1_000_000 + k,
                 "episode": k, "success": k % 10 < rate // 10} for s in seeds for k in range(20)]  # fmt: skip

    own = pd.DataFrame(eps("box-v2", 80, (0, 1, 2)) + eps("tree-v2", 30, (0, 1, 2)))
    look = pd.DataFrame(eps("tree-v2", 60, (1, 2)) + eps("tree-v2", 0, (0,)))  # a Table I seed 0 that must go
    retrain = pd.DataFrame(
        eps("box-v2", 50, (0,)) + eps("tree-v2", 50, (0,)) + eps("tree-v2", 50, (0,), "ours box-look")
    )
    r = attribution(own, look, reps=200, retrain=retrain).set_index("scene").loc["tree-v2"]
    assert (r.seeds, r.retrained) == (3, 1)
    # Seeds 1-2 from Table I (80 / 60 / 30) and seed 0 retrained (50 / 50 / 50), every step a mean over three seeds.
    assert (round(r.box, 6), round(r.box_look, 6), round(r.own, 6)) == (70.0, round(170 / 3, 6), round(110 / 3, 6))
    assert "| Ours | 3 (1 retrained) | 70 [" in attribution_block(table=attribution(own, look, 200, retrain))
    half = retrain[retrain["label"] == "ours"]  # its box-look flights not recorded: Table I's seed 0 stays
    r = attribution(own, look, reps=200, retrain=half).set_index("scene").loc["tree-v2"]
    assert (r.retrained, r.box, r.box_look) == (0, 80.0, 40.0)


def test_a_templates_paragraphs_are_joined_and_a_value_it_lacks_is_an_error():
    """The generated pages' words live in templates (omcrl/pipeline/templates): a paragraph written over several lines
    is one line before wrapping, table rows and list items keep their lines, a trailing backslash breaks a line, and
    a name the code does not pass stops the page instead of printing nothing."""
    import jinja2

    from omcrl.pipeline.pages import reflow, render

    text = "a b\nc d\n\n| t | u |\n- item\n  more\n- next\n\nhard\\\nbreak"
    assert reflow(text) == ["a b c d", "", "| t | u |", "- item more", "- next", "", "hard", "break"]
    assert render("summary/missing.md.j2", layout=False, what="data", notebook="01") == (
        "_data: not run yet (notebook 01)._"
    )
    with pytest.raises(jinja2.UndefinedError, match="notebook"):
        render("summary/missing.md.j2", what="data")


def test_a_table_of_one_seed_points_to_the_grids_verdicts(tmp_path):
    """A chain on the reference bundle (one training seed) ends with every claim `one seed`; its summary then says
    where the five-seed verdicts are (tables --from-reference), and says nothing of it when a claim was judged."""
    from omcrl.pipeline.summary import _section_table1

    cfg = load_config("quick", overrides=[f"results_dir={tmp_path}"])
    _fake_results(cfg.run_root)
    tables = cfg.run_root / "tables"
    for verdicts, pointed in ((["one seed", "not run"], True), (["one seed", "holds"], False)):
        ledger = [{"claim": f"E{i}", "family": "primary", "verdict": v} for i, v in enumerate(verdicts)]
        Table1Record(ledger=ledger).write(tables)
        text = _section_table1({}, tables)
        assert ("python -m omcrl tables --preset quick --from-reference" in text) == pointed, verdicts


def test_the_readmes_power_sentence_counts_what_the_power_lines_say():
    """The README's sentence on the undecided rows is computed from their power lines: which no number of seeds
    decides (and the layouts they would need), which more seeds would, and where the seeds' spread is the larger
    part."""
    import math

    import pandas as pd

    from omcrl.pipeline.glance import _power

    inf = math.inf
    v = pd.DataFrame({
        "verdict": ["undecided", "undecided", "undecided", "undecided", "holds"],
        "seeds_to_decide": [inf, inf, 12.0, 30.0, math.nan],
        "layouts_to_decide": [100.0, inf, math.nan, math.nan, math.nan],
        "var_seed": [1.0, 0.1, 2.0, 3.0, 9.0],
        "var_layout": [0.5, 0.2, 1.0, 1.0, 1.0],
    })  # fmt: skip
    p = _power(v)
    assert (p["undecided"], p["bound"], p["no_layouts"], p["by_seeds"], p["seed_heavy"]) == (4, 2, 1, 2, 3)
    assert p["layouts_needed"] == ("100", "100", "100") and p["seeds_needed"] == ("12", "21", "30")


def test_every_generated_block_of_the_pages_is_what_the_data_gives(repo_root, pages):
    """Each block between markers in the README and docs/ equals its rebuild from reference/quick/ (the one
    `summary --readme` writes: omcrl.pipeline.glance.page_blocks); a hand edit, or data committed without the pages
    rebuilt, fails here and names the page and the block."""
    from omcrl.pipeline.glance import current_block

    for page, blocks in pages.items():
        text = (repo_root / page).read_text(encoding="utf-8")
        for start, block in blocks.items():
            end = start.split(":")[0] + ": end -->"  # "<!-- name: start (...) -->" ends at "<!-- name: end -->"
            assert current_block(text, page, start, end) == block, f"{page}: {start}"


def test_tables_from_reference_writes_the_why_tables_as_the_page_shows_them(tmp_path, monkeypatch):
    """`tables --from-reference` writes the attribution and the teacher's ceiling beside Table I: the CSV is the
    table, the .md the block docs/results.md shows; a table with no data is not written."""
    import pandas as pd

    from omcrl.pipeline import why

    row = {"method": "ours", "scene": "tree-v2", "seeds": 3, "retrained": 1}
    for i, name in enumerate(("box", "box_look", "own", "geometry", "look")):
        row |= {name: 80.0 - 10 * i, f"{name}_lo": 70.0 - 10 * i, f"{name}_hi": 90.0 - 10 * i}
    att = pd.DataFrame([row])
    monkeypatch.setattr(why, "attribution_table", lambda preset: att)
    monkeypatch.setattr(why, "detour_table", lambda preset: pd.DataFrame())
    paths = why.write_why_tables("quick", tmp_path)
    assert sorted(paths) == ["why_attribution.csv", "why_attribution.md"]
    assert (tmp_path / "why_attribution.md").read_text(encoding="utf-8") == why.attribution_block("quick", att) + "\n"
    assert "3 (1 retrained)" in (tmp_path / "why_attribution.md").read_text(encoding="utf-8")
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "why_attribution.csv"), att, check_dtype=False)
    assert not (tmp_path / "why_detour.csv").exists()
