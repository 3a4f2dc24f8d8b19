"""The README's "Results at a glance": Table I on the v2 suite with the claim ledger's verdicts, rebuilt from the
grid data in ``reference/<preset>/table1-v2/`` (:func:`render_v2`), and the v1 suite's Table I (success rate with its
CI over seeds, the paper's value beside) with one line per ordering of the paper, rendered from the committed
reference tables (:func:`render_glance`).

The reference tables live in ``reference/<preset>/table1/`` (``table1.csv``, long rows as the ``tables`` stage
writes them, and ``table1_summary.json``, notebook 07's :class:`~omcrl.pipeline.records.Table1Record` with the
claims). ``python -m omcrl summary --preset quick --readme`` rewrites the block between the README's markers;
``tests/test_summary.py`` fails when the README differs from what these files give, so the two cannot drift apart.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from omcrl import planners
from omcrl.config import load_config, project_root
from omcrl.eval.ablation import PAPER_TABLES, SUMMARY_COLUMNS, paper_ablations
from omcrl.eval.metrics import glossary_markdown
from omcrl.eval.stage import scene_cells, to_markdown
from omcrl.eval.stats import aggregate, cell_rng, contrast, term
from omcrl.eval.table1 import Table1Result, ci_text, paper_table1, read_table1_csv, signed_points, table1_frames
from omcrl.eval.verdicts import changes_from_v1, compare_readings, readings_markdown, verdict_counts
from omcrl.pipeline.ablations import ABLATION_SEEDS, AblationResult, ablations_from_reference, account_markdown
from omcrl.pipeline.answer import ANSWER_END, ANSWER_START, answer_block, answer_facts
from omcrl.pipeline.griddata import GridData, grid_data_dir, tables_from_reference
from omcrl.pipeline.grids import ABLATION_GRIDS, GRIDS
from omcrl.pipeline.ladder import ladder_markdown, ladder_stage
from omcrl.pipeline.pages import render
from omcrl.pipeline.records import Table1Record
from omcrl.pipeline.reference import reference_table_dir
from omcrl.pipeline.sweep import rest_hours
from omcrl.pipeline.why import (
    WHY_DETOUR_END,
    WHY_DETOUR_START,
    WHY_LOOK_END,
    WHY_LOOK_START,
    attribution_block,
    attribution_table,
    detour_block,
    detour_table,
    method_label,
)
from omcrl.rl.methods import METHODS, TABLE1_METHODS
from omcrl.rl.train import rollout_geometry
from omcrl.scenes import scene_id, scene_label, scene_spec
from omcrl.utils.io import atomic_write_text

START = "<!-- results-at-a-glance: start (python -m omcrl summary --preset quick --readme writes this block) -->"
END = "<!-- results-at-a-glance: end -->"
V2_START = "<!-- results-v2: start (python -m omcrl summary --preset quick --readme writes this block) -->"
V2_END = "<!-- results-v2: end -->"
FULL_START = "<!-- results-v2-full: start (python -m omcrl summary --preset quick --readme writes this block) -->"
FULL_END = "<!-- results-v2-full: end -->"
CONFIRM_START = "<!-- results-v2-confirm: start (python -m omcrl summary --preset quick --readme writes this block) -->"
CONFIRM_END = "<!-- results-v2-confirm: end -->"
# The training seeds of Table I's confirmation on fresh layouts (declared in docs/results.md before it was flown).
CONFIRM_SEEDS = (2, 3, 4)
CONFIRM_ANCHOR = "a-confirmation-on-fresh-layouts-declared-before-it-was-flown"
V2_FIGURE = "docs/figures/quick/v2/fig5_training_curves.png"
V1_START = "<!-- results-v1: start (python -m omcrl summary --preset quick --readme writes this block) -->"
V1_END = "<!-- results-v1: end -->"
GLOSSARY_START = "<!-- metrics: start (python -m omcrl summary --preset quick --readme writes this block) -->"
GLOSSARY_END = "<!-- metrics: end -->"
TRANSFER_START = "<!-- transfer-v2: start (python -m omcrl summary --preset quick --readme writes this block) -->"
TRANSFER_END = "<!-- transfer-v2: end -->"
LADDER_START = "<!-- results-ladder: start (python -m omcrl summary --preset quick --readme writes this block) -->"
LADDER_END = "<!-- results-ladder: end -->"
# Where the ladder's per-scene figures live, relative to the project root and to docs/results.md.
LADDER_FIGURES = "docs/figures/quick/v2"
ABLATION_START = (
    "<!-- results-ablations-v2: start (python -m omcrl summary --preset quick --readme writes this block) -->"
)
ABLATION_END = "<!-- results-ablations-v2: end -->"
# A claim's verdict over its hypotheses (omcrl.eval.verdicts.verdict_counts), in the README's order.
CLAIM_VERDICTS = ("holds", "reversed", "mixed", "undecided", "one seed", "not run")
TALLIED = ("holds", "reversed", "undecided", "one seed", "not run")  # a hypothesis's verdicts (a claim's add mixed)
# The commit that fixed the claim ledger before any v2 Table I evaluation (omcrl.eval.ledger; docs/results.md).
LEDGER_COMMIT = "2cdf7b5"


# What the v1 suite's table measures (docs/scenes.md, "The v2 suite").
class GlanceError(RuntimeError):
    """The reference tables or the README's markers are missing or malformed; the message names the file."""


def _read(table_dir: Path) -> tuple[pd.DataFrame, Table1Record]:
    csv, js = table_dir / "table1.csv", table_dir / Table1Record.FILE
    for f in (csv, js):
        if not f.is_file():
            raise GlanceError(f"{f}: missing; the reference Table I is made by python -m omcrl reference --pack")
    try:
        table, record = read_table1_csv(csv), Table1Record.read(table_dir)
    except ValueError as e:  # CorruptFile included
        raise GlanceError(str(e)) from None
    return table[table.metric == "SR"], record


def wide_table(rows: pd.DataFrame, with_paper: bool = True, digits: int = 0) -> list[str]:
    """Markdown lines of one metric of Table I, one row per method, one column per scene: ``mean [lo, hi]`` (the
    CI left out where it collapses), with the paper's value in *italics* where it has one (``with_paper``).

    Parameters
    ----------
    rows : Table I's long rows of one metric (columns method, scene, metric, mean, lo, hi), e.g. SR in %.
    """
    methods = list(dict.fromkeys(rows["method"]))
    scenes = list(dict.fromkeys(rows["scene"]))
    metric = str(rows["metric"].iloc[0]) if len(rows) else "SR"
    paper = paper_table1().set_index(["method", "scene"])[metric]
    cell = {(r.method, r.scene): r for r in rows.itertuples()}
    lines = ["| method | " + " | ".join(scene_label(s) for s in scenes) + " |", "|---|" + "---|" * len(scenes)]
    for m in methods:
        out = []
        for s in scenes:
            r = cell.get((m, s))
            if r is None:
                out.append("")
                continue
            text = ci_text(r.mean, r.lo, r.hi, digits)
            psc = scene_spec(s).paper_scene
            if with_paper and psc is not None and (m, psc) in paper.index and pd.notna(paper[(m, psc)]):
                text += f" *{paper[(m, psc)]:g}*"
            out.append(text)
        lines.append(f"| {method_label(m)} | " + " | ".join(out) + " |")
    return lines


def render_glance(table_dir: str | Path, figure: str = "docs/figures/quick/v1/fig5_training_curves.png") -> str:
    """The markdown block (without the markers) for the reference Table I in ``table_dir``."""
    sr, record = _read(Path(table_dir))
    seeds, n = int(sr["seeds"].max()), int(sr["episodes"].min())
    claims = []
    for claim, g in pd.DataFrame(record.claims).groupby("claim", sort=False) if record.claims else ():
        parts = []
        for verdict in ("holds", "reversed", "undecided"):
            sc = g[g.verdict == verdict]
            if len(sc):
                pts = signed_points
                where = ", ".join(
                    f"{r.scene} {pts(r.diff)} [{pts(r.lo)}, {pts(r.hi)}]" if verdict != "undecided" else r.scene
                    for r in sc.itertuples()
                )  # fmt: skip
                parts.append(f"**{verdict}** in {where}")
        claims.append((claim, parts))
    # Planners are code, not trained: a row of one run flies the same episodes once.
    return render("table1_v1.md.j2", seeds=seeds, episodes=n, planners_once=bool((sr["seeds"] < seeds).any()),
                  table=wide_table(sr), claims=claims, figure=figure)  # fmt: skip


def render_v1_results(table_dir: str | Path) -> str:
    """docs/results.md's block for the v1 suite's Table I in ``table_dir``: SR per method and scene, and every
    ordering the v1 check judged in every scene (the README's block lists the decided ones)."""
    sr, record = _read(Path(table_dir))
    seeds, n = int(sr["seeds"].max()), int(sr["episodes"].min())
    claims = pd.DataFrame(record.claims)
    scenes = list(dict.fromkeys(claims["scene"])) if len(claims) else []
    rows = []
    for claim, g in claims.groupby("claim", sort=False) if len(claims) else ():
        cells = {r.scene: r for r in g.itertuples()}
        out = []
        for sc in scenes:
            r = cells.get(sc)
            if r is None:
                out.append("")
                continue
            text = f"{signed_points(r.diff)} [{signed_points(r.lo)}, {signed_points(r.hi)}]"
            out.append(f"**{r.verdict}** {text}" if r.verdict in ("holds", "reversed") else text)
        rows.append((claim, out))
    return render("table1_v1_full.md.j2", seeds=seeds, episodes=n, table=wide_table(sr, with_paper=False),
                  scenes=scenes, claims=rows)  # fmt: skip


def render_v2(result: Table1Result, confirmation: str | None = None, grid_seeds: int = 5) -> str:
    """The markdown block (without the markers) of Table I on the v2 suite from a rebuild of the grid data
    (:func:`omcrl.pipeline.griddata.tables_from_reference`): SR per method and scene with the paper's value, every
    recorded method's training seeds, and one line per claim of the ledger with its verdict.

    Parameters
    ----------
    result : the rebuild's Table I (``table``: every metric's aggregates) and ledger verdicts (``verdicts``).
    confirmation : a line on Table I's confirmation on fresh layouts (:func:`_confirm`), after the ledger's.
    grid_seeds : the training seeds the grid is to have (the issue's five), to say how far it has come.
    """
    table, layouts, done = _sr_table(result)
    v, ledger = result.verdicts, None
    if v is not None and len(v):
        n = v["verdict"].value_counts()
        by = {k: list(g["claim"]) for k, g in verdict_counts(v).groupby("verdict", sort=False)}
        ledger = {
            "hypotheses": len(v),
            "tally": ", ".join(f"{int(n.get(k, 0))} {k}" for k in TALLIED),
            **_power(v),
            "claims": [(k, by[k]) for k in CLAIM_VERDICTS if k in by],
        }
    return render(
        "table1_v2.md.j2",
        layouts=layouts,
        done=done,
        grid_seeds=grid_seeds,
        table=table,
        ledger=ledger,
        ledger_commit=LEDGER_COMMIT,
        confirmation=confirmation,
        figure=V2_FIGURE if "fig5" in result.paths else None,
    )


def _power(v: pd.DataFrame) -> dict[str, Any]:
    """What the undecided hypotheses' power lines say (:func:`omcrl.eval.verdicts.holm_verdicts`): ``bound``, those no
    number of training seeds decides at the grid's layouts, and the layouts their lines ask for (``layouts``: min,
    median, max of the finite ones; ``no_layouts``: those with none); ``by_seeds``, the others, and the training seeds
    theirs ask for (``seeds``: min, median, max); ``seed_heavy``, those whose spread between training seeds is larger
    than their layouts' (``var_seed`` > ``var_layout``)."""
    und = v[v["verdict"] == "undecided"]
    bound = und[und["seeds_to_decide"] == math.inf]
    need = bound["layouts_to_decide"]
    finite = need[need.map(math.isfinite)]
    by_seeds = und["seeds_to_decide"][und["seeds_to_decide"].map(math.isfinite)]

    def spread(x: pd.Series) -> tuple[str, str, str] | None:
        return None if x.empty else (f"{x.min():,.0f}", f"{x.median():,.0f}", f"{x.max():,.0f}")

    return {
        "undecided": len(und),
        "bound": len(bound),
        "layouts_needed": spread(finite),
        "no_layouts": int(len(need) - len(finite)),
        "by_seeds": len(by_seeds),
        "seeds_needed": spread(by_seeds),
        "seed_heavy": int((und["var_seed"] > und["var_layout"]).sum()),
    }


def _sr_table(result: Table1Result) -> tuple[list[str], int, str]:
    """Markdown rows of SR per method and scene (:func:`wide_table`, the paper beside it) with a column of each
    row's training seeds, in Table I's order; the layouts per scene and seed, and the seeds a learned row has
    (``"4"``, or ``"3–4"`` while some rows have fewer)."""
    table = table1_frames(result.table)[0]
    # Table I's order: the learned methods, its planners, then the local APF and the blind pilot.
    order = {m: i for i, m in enumerate((*TABLE1_METHODS, *planners.LABELS))}
    sr = table[table.metric == "SR"].sort_values("method", key=lambda m: m.map(order).fillna(len(order)), kind="stable")
    seeds = sr.groupby("method", sort=False)["seeds"].max()
    learned = [m for m in seeds.index if m in METHODS and METHODS[m].learned]
    counts = sorted({int(seeds[m]) for m in learned}) or [0]
    layouts = int((sr["episodes"] / sr["seeds"].clip(lower=1)).min())
    done = f"{counts[0]}" if counts[0] == counts[-1] else f"{counts[0]}–{counts[-1]}"
    body = wide_table(sr)
    body[0] = body[0] + " seeds |"
    body[1] = body[1] + "---|"
    for i, m in enumerate(dict.fromkeys(sr["method"]), start=2):
        body[i] = body[i] + f" {int(seeds[m]) if m in learned else 'planner'} |"
    return body, layouts, done


def _span(text: str, start: str, end: str, where: str) -> tuple[int, int]:
    i, j = text.find(start), text.find(end)
    if i < 0 or j < i:
        raise GlanceError(f"{where}: the markers {start!r} and {end!r} are missing or out of order")
    return i + len(start), j


def replace_block(text: str, block: str, where: str = "README.md", start: str = START, end: str = END) -> str:
    """``text`` with the part between ``start`` and ``end`` (default :data:`START`, :data:`END`) replaced by
    ``block``."""
    i, j = _span(text, start, end, where)
    return text[:i] + "\n" + block + "\n" + text[j:]


def current_block(text: str, where: str = "README.md", start: str = START, end: str = END) -> str:
    """The block between the markers ``start`` and ``end`` of ``text``."""
    i, j = _span(text, start, end, where)
    return text[i:j].strip("\n")


def render_transfer(episodes: pd.DataFrame, reps: int = 2000) -> str:
    """docs/generalization.md's table of what transfers: for each learned method, its success rate in the training
    scene and, in every other scene, the change from it in points, mean [95 % CI].

    ``episodes``: Table I's episode rows (``method``, ``scene``, ``train_seed``, ``seed``, ``success``). A change is
    the contrast SR(scene) − SR(training scene) of the same runs: training seeds are resampled together in both
    terms (a seed's two SRs come from one policy), the layouts of each scene apart (:func:`omcrl.eval.stats.contrast`).
    """
    order = ("training", "easy", "medium", "hard", "stress")
    scenes = sorted(dict.fromkeys(episodes["scene"]), key=lambda s: order.index(scene_spec(s).difficulty))
    train, others = scenes[0], scenes[1:]
    learned = [m for m in TABLE1_METHODS if METHODS[m].learned and m in set(episodes["method"])]
    rows = []
    for m in learned:
        e = episodes[episodes["method"] == m]
        base = e[e["scene"] == train]
        sr0 = 100.0 * base["success"].astype(float).to_numpy()
        cells = []
        for s in others:
            g = e[e["scene"] == s]
            est = contrast(
                [term(g, 100.0 * g["success"].astype(float).to_numpy(), s), term(base, sr0, train, -1.0)],
                reps,
                rng=cell_rng(0, "transfer", m, s),
                bounded=100.0,
            )
            cells.append(f"{signed_points(est.estimate)} [{signed_points(est.lo)}, {signed_points(est.hi)}]")
        rows.append((METHODS[m].label, f"{sr0.mean():.0f}", cells, base["train_seed"].nunique()))
    return render("transfer_v2.md.j2", train=train, others=[scene_label(s) for s in others], rows=rows)


def _confirm(preset: str, grid_verdicts: pd.DataFrame) -> tuple[str, str | None]:
    """docs/results.md's block on Table I's confirmation (grid ``table1-confirm``: the grid's runs in 200 layouts it
    never flew), rebuilt from ``reference/<preset>/table1-confirm-<suite>/``: which policies are flown, SR per method
    and scene, its ledger tally, and each hypothesis beside the grid's reading ``grid_verdicts``
    (:func:`omcrl.eval.verdicts.compare_readings`); and the README's line on it (None while nothing is flown)."""
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(preset, overrides=[f"results_dir={tmp}"])
        data = GridData(grid_data_dir(cfg, "table1-confirm"))
        if data.episodes().empty:
            return render("confirm_v2.md.j2", flown_any=False, preset=preset, folder=data.root.name), None
        res = tables_from_reference(cfg, "table1-confirm")
    learned = list(dict.fromkeys(v.method for v in GRIDS["table1-confirm"]))  # the controls came after it
    flown = data.progress(learned, CONFIRM_SEEDS)
    table, layouts, done = _sr_table(res)
    v = res.verdicts
    judged = v[v["verdict"].isin(("holds", "reversed", "undecided"))]
    n = judged["verdict"].value_counts()
    both = compare_readings(grid_verdicts, v)
    k = both["agreement"].value_counts()
    counts = {"flown": int(flown.to_numpy().sum()), "policies": flown.size, "seeds": CONFIRM_SEEDS, "layouts": layouts}
    block = render(
        "confirm_v2.md.j2",
        flown_any=True,
        learned=len(learned),
        done=done,
        table=table,
        judged=len(judged),
        families=" and ".join(f"{f} {int(x)}" for f, x in judged.groupby("family", sort=False).size().items()),
        tally=", ".join(f"{int(n.get(x, 0))} {x}" for x in ("holds", "reversed", "undecided")),
        readings=readings_markdown(both, "grid", "confirmation").strip(),
        **counts,
    )
    line = render(
        "confirm_line.md.j2",
        complete=bool(flown.to_numpy().all()),
        both=len(both),
        alike=int(k.get("alike", 0)),
        opposite=int(k.get("opposite", 0)),
        second=int(k.get("second only", 0)),
        first=int(k.get("first only", 0)),
        anchor=CONFIRM_ANCHOR,
        **counts,
    )
    return block, line


def _v2(preset: str = "quick", figure_to: str | Path | None = None) -> tuple[str, str, str, Table1Result]:
    """The README's v2 block (:func:`render_v2`), docs/results.md's (Table I's six metrics per scene, then every
    hypothesis of the ledger) and the confirmation's (:func:`_confirm`), from a rebuild of
    ``reference/<preset>/table1-v2/`` under a temporary folder, and that rebuild; with ``figure_to``, Fig. 5 of the
    rebuild is copied there."""
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(preset, overrides=[f"results_dir={tmp}"])
        res = tables_from_reference(cfg)
        confirm, line = _confirm(preset, res.verdicts)
        full = render(
            "table1_v2_full.md.j2",
            layout=False,
            progress="\n".join(_progress_md(cfg)),
            account="\n".join(_account_md(cfg)),
            table=Path(res.paths["md"]).read_text(encoding="utf-8").strip(),
            verdicts=Path(res.paths["verdicts_md"]).read_text(encoding="utf-8").strip(),
            changes="\n".join(_changes_md(res.verdicts, preset)),
        )
        if figure_to is not None and "fig5" in res.paths:
            Path(figure_to).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(res.paths["fig5"], figure_to)
        return render_v2(res, line), full, confirm, res


def transfer_block(preset: str = "quick") -> str:
    """docs/generalization.md's block (:func:`render_transfer`) from the grid data under ``reference/<preset>/``."""
    cfg = load_config(preset)
    return render_transfer(GridData(grid_data_dir(cfg, "table1")).episodes())


def ladder_block(preset: str = "quick", figures_to: str | Path | None = None) -> str:
    """docs/results.md's block on the budget ladder (:func:`omcrl.pipeline.ladder.ladder_markdown`), rebuilt from
    the grids ``table1``, ``ladder-pretrain`` and ``ladder-rl`` under ``reference/<preset>/``; with ``figures_to``
    (a folder), the per-scene figures are copied there."""
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(preset, overrides=[f"results_dir={tmp}"])
        try:
            res = ladder_stage(cfg)
        except FileNotFoundError:
            return f"Not run yet (no ladder point has episodes under `reference/{preset}/`)."
        if figures_to is not None:
            Path(figures_to).mkdir(parents=True, exist_ok=True)
            for name, path in res.paths.items():
                if name.startswith("ladder_") and path.suffix == ".png":
                    shutil.copyfile(path, Path(figures_to) / path.name)
        rel = LADDER_FIGURES.removeprefix("docs/")
        return ladder_markdown(res, rel)


def _hours_text(cost: dict[str, float]) -> str:
    """:func:`omcrl.pipeline.sweep.rest_hours` in words."""
    if math.isnan(cost["hours"]):
        return f"{cost['jobs']} jobs, some of a kind no record has measured (so no hours)"
    return (
        f"{cost['jobs']} jobs, {cost['hours']:.1f} machine-hours at the median of the rates this checkout's records "
        f"measured ({cost['hours_fast']:.1f} at their upper quartile, a machine to itself)"
    )


# The paper's numbering of the ablation tables the kit writes (omcrl.eval.ablation.PAPER_TABLES).
PAPER_NAMES = {"table2": "Table II", "table3": "Table III"}


def _paper_rows(res: AblationResult, grid: str) -> list[str]:
    """Markdown rows of one of the paper's ablation tables (II, III): per variant and scene, SR and CR as the kit
    measured them (mean [95 % CI]) beside the paper's values."""
    table = res.tables.get(grid)
    paper = paper_ablations(grid)
    rows = []
    for r in paper.itertuples():
        sc = next((s for s in table.index.get_level_values("scene").unique() if scene_spec(s).paper_scene == r.scene),
                  None) if table is not None else None  # fmt: skip
        k = table.loc[(r.label, sc)] if sc is not None and (r.label, sc) in table.index else None
        cells = [ci_text(k[m], k[f"{m}_lo"], k[f"{m}_hi"]) if k is not None else "not recorded" for m in ("SR", "CR")]
        rows.append(f"| {r.label} | {sc or scene_id(r.scene)} | {cells[0]} | {r.SR:g} | {cells[1]} | {r.CR:g} |")
    return rows


def ablation_block(
    preset: str = "quick",
    seeds: tuple[int, ...] = ABLATION_SEEDS,
    reps: int = 2000,
    figures_to: str | Path | None = None,
) -> str:
    """docs/results.md's block on the paper's ablations (VI-C) on the preset's scene suite, rebuilt from the grids of
    :data:`omcrl.pipeline.grids.ABLATION_GRIDS` under ``reference/<preset>/<grid>-<suite>/`` at the training
    ``seeds`` (:func:`omcrl.pipeline.ablations.ablations_from_reference`): which variants are recorded, each
    finding's verdict (:func:`omcrl.eval.ablation.findings_summary`), each check's SR difference with its 95 % CI,
    Holm-adjusted p and verdict (paired; Holm over the unseen-scene checks, the stress room a family apart), Tables
    II and III beside the paper's values, SR per variant and scene, Figs. 7–10, and the grids' account. With
    ``figures_to`` (a folder), the figures are copied there (linked from docs/ as :data:`LADDER_FIGURES`)."""
    return _ablation(preset, seeds, reps, figures_to)[0]


def _ablation(
    preset: str, seeds: tuple[int, ...], reps: int, figures_to: str | Path | None
) -> tuple[str, AblationResult | None]:
    """:func:`ablation_block` and the rebuild it comes from (None when no grid has episodes)."""
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(preset, overrides=[f"results_dir={tmp}"])
        common = {"seeds": list(seeds), "preset": preset}
        try:
            res = ablations_from_reference(cfg, seeds, reps)
        except FileNotFoundError:
            cost = _hours_text(rest_hours(cfg, ABLATION_GRIDS, seeds))
            return render("ablations_v2.md.j2", recorded=[], grids=ABLATION_GRIDS, cost=cost, **common), None
        figures = [path.name for name, path in res.paths.items() if path.suffix == ".png"]
        if figures_to is not None:
            Path(figures_to).mkdir(parents=True, exist_ok=True)
            for name in figures:
                shutil.copyfile(cfg.run_root / "figures" / name, Path(figures_to) / name)
    recorded = []
    for g in ABLATION_GRIDS:
        ep = res.episodes.get(g, pd.DataFrame(columns=["label", "train_seed"]))
        recorded += [(g, v.label, ep.loc[ep["label"] == v.label, "train_seed"].nunique()) for v in GRIDS[g]]
    check_scenes, checks = _check_rows(res.findings)
    table1_scenes, table1_checks = _check_rows(res.at_table1)
    t1 = res.at_table1
    table1 = {
        "table1_scenes": table1_scenes,
        "table1_checks": table1_checks,
        "table1_summary": [(r["finding"], r["verdict"], int(r["checks"])) for _, r in res.at_table1_summary.iterrows()],
        "table1_steps": f"{rollout_geometry(cfg.rl)[3]:,}",
        "table1_seeds": int(t1["seeds"].max()) if len(t1) else 0,
        # The orderings named from the checks themselves, so the words follow GRIDS if it gains a pair.
        "table1_claims": list(dict.fromkeys(t1["claim"])) if len(t1) else [],
    }
    frames = [e.assign(grid=g) for g, e in res.episodes.items()]
    table = aggregate(pd.concat(frames, ignore_index=True), ("grid", "label", "scene"), reps=reps).reset_index()
    order = {(g, v.label): i for i, (g, v) in enumerate((g, v) for g in ABLATION_GRIDS for v in GRIDS[g])}
    rank = [order.get(k, len(order)) for k in zip(table["grid"], table["label"])]  # the grids' own order
    table = table.assign(_rank=rank).sort_values("_rank", kind="stable").drop(columns="_rank")
    sr_scenes = list(dict.fromkeys(table["scene"]))
    sr = [
        f"| {g} | {label} | {int(t['seeds'].max())} | "
        + scene_cells(t, sr_scenes, lambda r: ci_text(r["SR"], r["SR_lo"], r["SR_hi"]))
        + " |"
        for (g, label), t in table.groupby(["grid", "label"], sort=False)
    ]
    paper = [(PAPER_NAMES[PAPER_TABLES[g]], PAPER_TABLES[g], g, _paper_rows(res, g)) for g in PAPER_TABLES]
    rel = LADDER_FIGURES.removeprefix("docs/")
    text = render(
        "ablations_v2.md.j2",
        recorded=recorded,
        findings=to_markdown(res.summary[SUMMARY_COLUMNS].set_index("finding"), "finding").strip(),
        checks=checks,
        check_scenes=check_scenes,
        sr=sr,
        sr_scenes=sr_scenes,
        paper=paper,
        figures=[f"{rel}/{name}" for name in figures],
        account=account_markdown(res.ran, res.rest).strip(),
        **table1,
        **common,
    )
    return text, res


def _check_rows(findings: pd.DataFrame) -> tuple[list[str], list[str]]:
    """The scenes and the Markdown rows of :func:`omcrl.eval.ablation.ablation_findings`' checks: per claim, each
    scene's SR difference with its 95 % CI, verdict and Holm-adjusted p."""
    if not len(findings):
        return [], []
    scenes = list(dict.fromkeys(findings["scene"]))

    def check(r: pd.Series) -> str:
        if not math.isfinite(r["diff"]):
            return ""
        p = f", p {r['p_holm']:.2g}" if math.isfinite(r["p_holm"]) else ""
        return f"{signed_points(r['diff'])} [{signed_points(r['lo'])}, {signed_points(r['hi'])}] {r['verdict']}{p}"

    by_claim = findings.groupby(["finding", "claim"], sort=False)
    return scenes, [f"| {finding} | {claim} | {scene_cells(g, scenes, check)} |" for (finding, claim), g in by_claim]


def _complete_grids(res: AblationResult | None, seeds: Sequence[int]) -> list[str]:
    """The ablation grids that have every variant recorded at every one of ``seeds``."""
    if res is None:
        return []
    return [g for g, ep in res.episodes.items()
            if all(set(seeds) <= set(ep.loc[ep["label"] == v.label, "train_seed"]) for v in GRIDS[g])]  # fmt: skip


def answer_blocks(
    preset: str,
    table1: Table1Result,
    ablation: AblationResult | None,
    attribution: pd.DataFrame,
    detour: pd.DataFrame,
    seeds: tuple[int, ...] = ABLATION_SEEDS,
) -> tuple[str, str]:
    """The answer first (:mod:`omcrl.pipeline.answer`) as the README's block and as docs/results.md's, from Table I's
    rebuild (:func:`_v2`), the ablations' (:func:`_ablation`; None when no grid has episodes), the attribution and
    the teacher's ceiling (:func:`omcrl.pipeline.why.attribution_table`, :func:`~omcrl.pipeline.why.detour_table`)."""
    cfg = load_config(preset)
    facts = answer_facts(
        table1.verdicts,
        table1.table,
        attribution,
        detour,
        None if ablation is None else ablation.summary,
        (_complete_grids(ablation, seeds), len(ABLATION_GRIDS)),
        # the env steps runs train (rollouts round up), as run.json and Table I's text give them
        tuple(rollout_geometry(replace(cfg.rl, total_steps=n))[3] for n in (cfg.sweep.rl_steps, cfg.rl.total_steps)),
        None if ablation is None else ablation.at_table1_summary,
    )
    return answer_block(facts, "docs/results.md"), answer_block(facts, "")


def _progress_md(cfg: Any, seeds: int = 5) -> list[str]:
    """Markdown lines: which learned methods' training seeds the grid has recorded (✓) and which are to come."""
    record = GridData(grid_data_dir(cfg, "table1"))
    learned = [m for m in TABLE1_METHODS if METHODS[m].learned]
    p = record.progress(learned, range(seeds))
    rows = [(METHODS[m].label, ["✓" if x else "" for x in p.loc[m]]) for m in p.index]
    text = render("progress_v2.md.j2", recorded=int(p.to_numpy().sum()), runs=p.size, seeds=list(p.columns), rows=rows)
    return text.splitlines()


def _account_md(cfg: Any) -> list[str]:
    """Markdown lines: how the grid's recorded runs were trained (:meth:`GridData.account`), what they reused, and
    the pretraining and evaluation time its ``jobs.csv`` measured."""
    record = GridData(grid_data_dir(cfg, "table1"))
    a = record.account()
    if a.empty:
        return []
    rl = a[a["stage"] == "rl"]
    kind = rl["method"].map(lambda m: METHODS[m].features if m in METHODS else "other")
    hours = (rl.groupby(kind)["train_s"].sum() / 3600).round(1)
    timed = []
    jobs_csv = record.root / "jobs.csv"
    if jobs_csv.is_file():
        jobs = pd.read_csv(jobs_csv)
        done = jobs[jobs["status"] == "done"].groupby("kind")["seconds"].agg(["sum", "size"])
        names = {"pretrain": "pretraining", "evaluate": "evaluation"}
        timed = [f"{name} {done.loc[k, 'sum'] / 3600:.1f} h ({int(done.loc[k, 'size'])} jobs)"
                 for k, name in names.items() if k in done.index]  # fmt: skip
    students = rl.dropna(subset=["encoder"])
    sharing = students.groupby("encoder")["label"].agg(lambda x: ", ".join(sorted(set(x)))).value_counts()
    # Encoders that serve several students first.
    sharing = [
        _sharing_words(labels.split(", "), n) for labels, n in sorted(sharing.items(), key=lambda kv: "," not in kv[0])
    ]
    seg = rl["segments"].dropna()
    cpu = rl["cpu"].replace("", "not recorded").value_counts()
    text = render(
        "account_v2.md.j2",
        runs=len(rl),
        hours=rl["train_s"].sum() / 3600,
        hours_by_kind=[f"{k} {v:.1f}" for k, v in hours.items()],
        timed=timed,
        encoders=students["encoder"].nunique(),
        students=len(students),
        sharing=sharing if len(students) else [],
        oracles=int((rl["method"] == "oracle").sum()),
        taught=len(rl.dropna(subset=["oracle"])),
        resumed=int((seg > 1).sum()),
        segments=len(seg),
        machines=[f"{k} {n}" for k, n in cpu.items()],
    )
    return text.splitlines()


def _sharing_words(labels: list[str], seeds: int) -> str:
    """'at each of 4 seeds one encoder serves a, b and c' or 'curl has its own at 4 seeds'."""
    at = f"{seeds} seed{'s' * (seeds > 1)}"
    if len(labels) == 1:
        return f"{labels[0]} has its own at {at}"
    return f"at each of {at} one encoder serves {', '.join(labels[:-1])} and {labels[-1]}"


def _changes_md(verdicts: pd.DataFrame, preset: str) -> list[str]:
    """Markdown lines: the v1 reference's orderings beside the v2 ledger's verdicts on the same ones
    (:func:`omcrl.eval.verdicts.changes_from_v1`)."""
    record = Table1Record.read(reference_table_dir(preset))
    ch = changes_from_v1(pd.DataFrame(record.claims if record else []), verdicts)
    if ch.empty:
        return []
    n = ch["changed"].dropna()
    rows = [
        {**r._asdict(), "mark": "–" if r.changed is None else ("**yes**" if r.changed else "no")}
        for r in ch.itertuples()
    ]
    text = render("changes_v2.md.j2", changed=int(n.sum()), judged=len(n), not_judged=int(ch["changed"].isna().sum()),
                  rows=rows)  # fmt: skip
    return text.splitlines()


def _rewrite(path: Path, blocks: list[tuple[str, str, str]]) -> bool:
    text = path.read_text(encoding="utf-8")
    new = text
    for block, start, end in blocks:
        new = replace_block(new, block, str(path), start, end)
    if new != text:
        atomic_write_text(path, new)
    return new != text


def page_blocks(preset: str = "quick", root: Path | None = None) -> dict[str, list[tuple[str, str, str]]]:
    """Every generated block of the pages, each input rebuilt once from ``reference/<preset>/``: ``{page: [(block,
    start marker, end marker), ...]}``, pages relative to the project root (``README.md``, ``docs/results.md``,
    ``docs/glossary.md``, ``docs/generalization.md``). With ``root``, the figures the blocks show (Fig. 5 on v2, the
    ladder's and the ablations' figures) are copied under it (:data:`V2_FIGURE`, :data:`LADDER_FIGURES`)."""
    short, full, confirm, table1 = _v2(preset, figure_to=None if root is None else root / V2_FIGURE)
    figures = None if root is None else root / LADDER_FIGURES
    ablations, ablation = _ablation(preset, ABLATION_SEEDS, 2000, figures)
    detour, attribution = detour_table(preset), attribution_table(preset)
    answer_readme, answer_results = answer_blocks(preset, table1, ablation, attribution, detour)
    return {
        "README.md": [(answer_readme, ANSWER_START, ANSWER_END),
                      (render_glance(reference_table_dir(preset)), START, END), (short, V2_START, V2_END)],
        "docs/results.md": [(answer_results, ANSWER_START, ANSWER_END), (full, FULL_START, FULL_END),
                            (confirm, CONFIRM_START, CONFIRM_END),
                            (render_v1_results(reference_table_dir(preset)), V1_START, V1_END),
                            (ladder_block(preset, figures_to=figures), LADDER_START, LADDER_END),
                            (ablations, ABLATION_START, ABLATION_END),
                            (detour_block(preset, detour), WHY_DETOUR_START, WHY_DETOUR_END),
                            (attribution_block(preset, attribution), WHY_LOOK_START, WHY_LOOK_END)],
        "docs/glossary.md": [(glossary_markdown(), GLOSSARY_START, GLOSSARY_END)],
        "docs/generalization.md": [(transfer_block(preset), TRANSFER_START, TRANSFER_END)],
    }  # fmt: skip


def update_readme(preset: str = "quick", readme: str | Path | None = None) -> bool:
    """Rewrite every generated block of the pages (:func:`page_blocks`: the README's answer, v2 and v1 blocks;
    docs/results.md's answer, Table I, confirmation, v1, ladder, ablations, teacher's ceiling and attribution blocks;
    docs/glossary.md's metrics table; docs/generalization.md's transfer table) and the figures beside them; True when
    the README (``readme``, default the project's) changed."""
    root = project_root()
    blocks = page_blocks(preset, root)
    for page in ("docs/results.md", "docs/glossary.md", "docs/generalization.md"):
        _rewrite(root / page, blocks[page])
    return _rewrite(Path(readme) if readme is not None else root / "README.md", blocks["README.md"])
