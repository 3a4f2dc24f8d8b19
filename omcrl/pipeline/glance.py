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
import textwrap
from pathlib import Path
from typing import Any

import pandas as pd

from omcrl import planners
from omcrl.config import load_config, project_root
from omcrl.eval.ablation import ablation_findings, findings_summary
from omcrl.eval.metrics import glossary_markdown
from omcrl.eval.stage import scene_cells, to_markdown
from omcrl.eval.stats import aggregate, cell_rng, contrast, term
from omcrl.eval.table1 import Table1Result, ci_text, paper_table1, read_table1_csv, table1_frames
from omcrl.eval.verdicts import changes_from_v1, compare_readings, readings_markdown, verdict_counts
from omcrl.pipeline.griddata import GridData, grid_data_dir, tables_from_reference
from omcrl.pipeline.grids import ABLATION_GRIDS, GRIDS
from omcrl.pipeline.ladder import ladder_markdown, ladder_stage
from omcrl.pipeline.records import Table1Record
from omcrl.pipeline.reference import reference_table_dir
from omcrl.pipeline.sweep import rest_hours
from omcrl.pipeline.why import (
    WHY_DETOUR_END,
    WHY_DETOUR_START,
    WHY_LOOK_END,
    WHY_LOOK_START,
    attribution_block,
    detour_block,
)
from omcrl.rl.methods import METHODS, TABLE1_METHODS
from omcrl.scenes import scene_label, scene_spec
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
# The issue's seeds for the v2 ablations (notebook 06's six findings over three training seeds).
ABLATION_SEEDS = (0, 1, 2)
# A claim's verdict over its hypotheses (omcrl.eval.verdicts.verdict_counts), in the README's order.
CLAIM_VERDICTS = ("holds", "reversed", "mixed", "undecided", "one seed", "not run")
# The commit that fixed the claim ledger before any v2 Table I evaluation (omcrl.eval.ledger; docs/results.md).
LEDGER_COMMIT = "2cdf7b5"
# What the v1 suite's table measures (docs/scenes.md, "The v2 suite").
V1_CAVEAT = (
    "**v1 suite, superseded**: a pilot that flies straight at the goal and senses nothing succeeds in 37–78 % of "
    "these layouts and box-v0 never asks for a detour, so this table measures goal-seeking under a change of look "
    "more than navigation from pixels; its runs were lost, so its cells cannot be recomputed."
)


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


def _signed(x: float) -> str:
    """A difference in whole points with its sign (``+5``, ``−3``; ``0`` without one)."""
    text = f"{x:+.0f}"
    return "0" if text in ("+0", "-0") else text.replace("-", "−")


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
        lines.append(f"| {METHODS[m].label if m in METHODS else planners.LABELS.get(m, m)} | " + " | ".join(out) + " |")
    return lines


def render_glance(table_dir: str | Path, figure: str = "docs/figures/quick/v1/fig5_training_curves.png") -> str:
    """The markdown block (without the markers) for the reference Table I in ``table_dir``."""
    sr, record = _read(Path(table_dir))
    seeds, n = int(sr["seeds"].max()), int(sr["episodes"].min())
    # Planners are code, not trained: a row of one run flies the same episodes once.
    once = " (the planners, which are not trained: one run of the same episodes)" if (sr["seeds"] < seeds).any() else ""
    lines = [
        V1_CAVEAT,
        "",
        f"Success rate % over {seeds} training seeds × {n} episodes per scene{once}, mean [95 % CI] (two-stage "
        "bootstrap); the paper's value (200 episodes, Unity scenes) in *italics*. Trained in box only; every other "
        "scene unseen.",
        "",
        *wide_table(sr),
    ]
    claims = pd.DataFrame(record.claims)
    if len(claims):
        lines += ["", "The paper's orderings (SR difference in points [95 % CI]; a verdict where the CI excludes 0):"]
        lines.append("")
        for claim, g in claims.groupby("claim", sort=False):
            parts = []
            for verdict in ("holds", "reversed", "undecided"):
                sc = g[g.verdict == verdict]
                if len(sc):
                    where = ", ".join(
                        f"{r.scene} {_signed(r.diff)} [{_signed(r.lo)}, {_signed(r.hi)}]" if verdict != "undecided"
                        else r.scene
                        for r in sc.itertuples()
                    )  # fmt: skip
                    parts.append(f"**{verdict}** in {where}")
            lines.append(f"- `{claim}`: " + "; ".join(parts) + ".")
    lines += ["", f"![Fig. 5: training curves]({figure})"]
    return "\n".join(_wrap(x) for x in lines)


def render_v1_results(table_dir: str | Path) -> str:
    """docs/results.md's block for the v1 suite's Table I in ``table_dir``: SR per method and scene, and every
    ordering the v1 check judged in every scene (the README's block lists the decided ones)."""
    sr, record = _read(Path(table_dir))
    seeds, n = int(sr["seeds"].max()), int(sr["episodes"].min())
    lines = [
        _wrap(
            f"SR %, mean [95 % CI] over {seeds} training seeds × {n} episodes (two-stage bootstrap; the planners, "
            "which are not trained: one run of the same episodes):"
        ),
        "",
        *wide_table(sr, with_paper=False),
    ]
    claims = pd.DataFrame(record.claims)
    if len(claims):
        scenes = list(dict.fromkeys(claims["scene"]))
        lines += [
            "",
            _wrap(
                "The paper's orderings (the v1 check, since replaced by the claim ledger): SR difference in points "
                "[95 % CI], *holds* / *reversed* where the CI excludes 0:"
            ),
            "",
            "| claim | " + " | ".join(scenes) + " |",
            "|---|" + "---|" * len(scenes),
        ]
        for claim, g in claims.groupby("claim", sort=False):
            cells = {r.scene: r for r in g.itertuples()}
            out = []
            for sc in scenes:
                r = cells.get(sc)
                if r is None:
                    out.append("")
                    continue
                text = f"{_signed(r.diff)} [{_signed(r.lo)}, {_signed(r.hi)}]"
                out.append(f"**{r.verdict}** {text}" if r.verdict in ("holds", "reversed") else text)
            lines.append(f"| {claim} | " + " | ".join(out) + " |")
    return "\n".join(lines)


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
    body, layouts, done = _sr_table(result)
    lines = [
        f"**Scenes v2** (navigation that needs sight; trained in box-v2 only, every other scene unseen). Success rate "
        f"% over {layouts} layouts per scene and {done} of the grid's {grid_seeds} training seeds per learned "
        "method (the column `seeds`), mean [95 % CI] with training seeds and layouts as crossed factors (a row of "
        "one seed: layouts only); planners fly once. The paper's value (Unity scenes) in *italics* where its scene "
        "matches. Rebuilt by `python -m omcrl tables --preset quick --from-reference` from "
        "`reference/quick/table1-v2/`; all six metrics and every hypothesis: [docs/results.md](docs/results.md).",
        "",
    ]
    lines += body
    v = result.verdicts
    if v is not None and len(v):
        c = verdict_counts(v)
        n = v["verdict"].value_counts()
        tally = ", ".join(f"{int(n.get(k, 0))} {k}" for k in ("holds", "reversed", "undecided", "one seed", "not run"))
        bound = int(((v["verdict"] == "undecided") & (v["seeds_to_decide"] == math.inf)).sum())
        lines += [
            "",
            f"The paper's claims as a ledger fixed before any v2 evaluation (commit {LEDGER_COMMIT}; "
            f"`omcrl.eval.ledger`; the kit's controls C1–C2 declared before they flew), {len(v)} hypotheses, "
            f"Holm–Bonferroni within each family (primary, secondary, controls): {tally}. A row of one training "
            f"seed is shown, not judged. Of the undecided, {bound} are bound by the {layouts} layouts: at the "
            "measured effect no number of training seeds would decide them, more "
            "layouts would (each row's power line, in docs/results.md).",
            "",
        ]
        if confirmation:
            lines += [confirmation, ""]
        by = {v: list(g["claim"]) for v, g in c.groupby("verdict", sort=False)}
        lines += [
            "| claims' verdict | claims |",
            "|---|---|",
            *(f"| {v} | {', '.join(by[v])} |" for v in CLAIM_VERDICTS if v in by),
            "",
            "Each claim's words, its hypotheses and their estimates: [docs/results.md](docs/results.md#claim-ledger-"
            "declared-before-the-v2-grid).",
        ]
    if "fig5" in result.paths:
        lines += ["", f"![Fig. 5 on v2: training curves in box-v2, every recorded seed]({V2_FIGURE})"]
    return "\n".join(_wrap(x) for x in lines)


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


def _wrap(line: str, width: int = 120) -> str:
    """A prose line or list item wrapped at ``width`` (Markdown renders it the same); table rows as they are."""
    if line.startswith("|") or len(line) <= width:
        return line
    indent = "  " if line.startswith("- ") else ""
    return textwrap.fill(line, width, subsequent_indent=indent, break_long_words=False, break_on_hyphens=False)


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
    head = f"| method | SR in {train} | " + " | ".join(f"{scene_label(s)}" for s in others) + " | seeds |"
    lines = [
        _wrap(
            f"**What transfers** (v2; generated from `reference/quick/table1-v2/`): SR % in {train}, and the change "
            "in SR points from it in each other scene, mean [95 % CI] with the runs' training seeds resampled "
            "together in both scenes and each scene's layouts apart. 0 is no loss; a change near minus the training "
            "SR is no transfer."
        ),
        "",
        head,
        "|---|" + "---|" * (len(others) + 2),
    ]
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
            cells.append(f"{_signed(est.estimate)} [{_signed(est.lo)}, {_signed(est.hi)}]")
        lines.append(
            f"| {METHODS[m].label} | {sr0.mean():.0f} | " + " | ".join(cells) + f" | {base['train_seed'].nunique()} |"
        )
    return "\n".join(lines)


def v2_blocks(preset: str = "quick", figure_to: str | Path | None = None) -> tuple[str, str]:
    """The README's block (:func:`render_v2`) and docs/results.md's (Table I's six metrics per scene, then every
    hypothesis of the ledger) from a rebuild of ``reference/<preset>/table1-v2/`` under a temporary folder; with
    ``figure_to``, Fig. 5 of the rebuild is copied there."""
    short, full, _ = _v2(preset, figure_to)
    return short, full


def confirm_block(preset: str = "quick") -> str:
    """docs/results.md's block on Table I's confirmation (:func:`_confirm`)."""
    return _v2(preset)[2]


def _confirm(preset: str, grid_verdicts: pd.DataFrame) -> tuple[str, str | None]:
    """docs/results.md's block on Table I's confirmation (grid ``table1-confirm``: the grid's runs in 200 layouts it
    never flew), rebuilt from ``reference/<preset>/table1-confirm-<suite>/``: which policies are flown, SR per method
    and scene, its ledger tally, and each hypothesis beside the grid's reading ``grid_verdicts``
    (:func:`omcrl.eval.verdicts.compare_readings`); and the README's line on it (None while nothing is flown)."""
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(preset, overrides=[f"results_dir={tmp}"])
        data = GridData(grid_data_dir(cfg, "table1-confirm"))
        if data.episodes().empty:
            return f"Not flown yet (no episodes under `reference/{preset}/{data.root.name}/`).", None
        res = tables_from_reference(cfg, "table1-confirm")
    learned = list(dict.fromkeys(v.method for v in GRIDS["table1-confirm"]))  # the controls came after it
    flown = data.progress(learned, CONFIRM_SEEDS)
    body, layouts, done = _sr_table(res)
    v = res.verdicts
    judged = v[v["verdict"].isin(("holds", "reversed", "undecided"))]
    n = judged["verdict"].value_counts()
    tally = ", ".join(f"{int(n.get(k, 0))} {k}" for k in ("holds", "reversed", "undecided"))
    sizes = judged.groupby("family", sort=False).size()
    families = " and ".join(f"{k} {int(x)}" for k, x in sizes.items())
    both = compare_readings(grid_verdicts, v)
    lines = [
        f"**Flown**: {int(flown.to_numpy().sum())} of {flown.size} policies (training seeds "
        f"{', '.join(map(str, CONFIRM_SEEDS))} of the {len(learned)} learned methods); the planners once.",
        "",
        f"Success rate % over {layouts} layouts per scene that Table I never flew, {done} training seeds per "
        "learned method (the column `seeds`), mean [95 % CI], seeds × layouts crossed; the paper's value in "
        "*italics*.",
        "",
        *body,
        "",
        f"Its ledger: {len(judged)} evaluation hypotheses judged, Holm–Bonferroni within the families ({families}): "
        f"{tally}. Beside the grid's reading above (50 layouts):",
        "",
        *readings_markdown(both, "grid", "confirmation").strip().splitlines(),
    ]
    k = both["agreement"].value_counts()
    line = (
        f"A confirmation declared before it was flown, the same runs in {layouts} layouts per scene Table I never "
        f"flew ({int(flown.to_numpy().sum())} of {flown.size} policies flown so far: training seeds "
        f"{', '.join(map(str, CONFIRM_SEEDS))}): of {len(both)} hypotheses judged in both readings, "
        f"{int(k.get('alike', 0))} decided alike, {int(k.get('opposite', 0))} in opposite directions, "
        f"{int(k.get('second only', 0))} by the confirmation only, {int(k.get('first only', 0))} by the grid only "
        f"([docs/results.md](docs/results.md#{CONFIRM_ANCHOR}))."
    )
    if flown.to_numpy().all():
        line = line.replace(" so far", "")
    return "\n".join(_wrap(x) for x in lines), line


def _v2(preset: str = "quick", figure_to: str | Path | None = None) -> tuple[str, str, str]:
    """The README's v2 block, docs/results.md's and the confirmation's (:func:`v2_blocks`, :func:`_confirm`)."""
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(preset, overrides=[f"results_dir={tmp}"])
        res = tables_from_reference(cfg)
        confirm, line = _confirm(preset, res.verdicts)
        full = "\n".join(
            [
                *_progress_md(cfg),
                *_account_md(cfg),
                "",
                Path(res.paths["md"]).read_text(encoding="utf-8").strip(),
                "",
                "**Claim ledger, every hypothesis** (estimates signed so that the paper's direction is positive)",
                "",
                Path(res.paths["verdicts_md"]).read_text(encoding="utf-8").strip(),
                "",
                *_changes_md(res.verdicts, preset),
            ]
        )
        if figure_to is not None and "fig5" in res.paths:
            Path(figure_to).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(res.paths["fig5"], figure_to)
        return render_v2(res, line), full, confirm


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
        return "\n".join(_wrap(x) for x in ladder_markdown(res, rel))


def _hours_text(cost: dict[str, float]) -> str:
    """:func:`omcrl.pipeline.sweep.rest_hours` in words."""
    if math.isnan(cost["hours"]):
        return f"{cost['jobs']} jobs, some of a kind no record has measured (so no hours)"
    return (
        f"{cost['jobs']} jobs, {cost['hours']:.1f} machine-hours at the median of the rates this checkout's records "
        f"measured ({cost['hours_fast']:.1f} at their upper quartile, a machine to itself)"
    )


def ablation_block(preset: str = "quick", seeds: tuple[int, ...] = ABLATION_SEEDS, reps: int = 2000) -> str:
    """docs/results.md's block on the paper's six ablation findings (VI-C) on the preset's scene suite, rebuilt from
    the grids of :data:`omcrl.pipeline.grids.ABLATION_GRIDS` under ``reference/<preset>/<grid>-<suite>/`` at the
    training ``seeds``: which variants are recorded, each finding's verdict (:func:`omcrl.eval.ablation.
    findings_summary`), each check's SR difference with its 95 % CI and verdict (paired, Holm over the unseen-scene
    checks; the stress room a family apart), and SR per variant and scene (Table I's intervals)."""
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(preset, overrides=[f"results_dir={tmp}"])
        episodes = {}
        for g in ABLATION_GRIDS:
            ep = GridData(grid_data_dir(cfg, g)).episodes()
            if len(ep):
                episodes[g] = ep[ep["train_seed"].isin(list(seeds))]
    which = ", ".join(map(str, seeds))
    if not any(len(e) for e in episodes.values()):
        seed_arg = ",".join(map(str, seeds))
        return _wrap(
            f"Not run yet (no ablation grid has episodes of training seeds {which} under `reference/{preset}/`). "
            f"`scripts/grid_session.sh --grid <grid> --seeds {seed_arg} --by variant` runs a grid and commits each "
            "variant's rows as it finishes, for each of "
            + ", ".join(f"`{g}`" for g in ABLATION_GRIDS)
            + f"; `python -m omcrl sweep all --preset {preset} --seeds {seed_arg} --to-reference --plan` prints their "
            f"cost: {_hours_text(rest_hours(cfg, ABLATION_GRIDS, seeds))}."
        )
    lines = [f"**Recorded** (training seeds of {which} with episodes, per variant of each grid):", ""]
    lines += ["| grid | variant | seeds |", "|---|---|---|"]
    for g in ABLATION_GRIDS:
        ep = episodes.get(g, pd.DataFrame(columns=["label", "train_seed"]))
        for v in GRIDS[g]:
            n = ep.loc[ep["label"] == v.label, "train_seed"].nunique()
            lines.append(f"| {g} | {v.label} | {n}/{len(seeds)} |")
    findings = ablation_findings(episodes, reps=reps)
    summary = findings_summary(findings)
    lines += [
        "",
        "Each finding as SR orderings between variants in the unseen scenes (paired layout by layout and seed by "
        "seed, Holm–Bonferroni over every unseen-scene check; the stress room furniture-v0 counted apart as held / "
        "reversed / undecided). A verdict holds when every check holds, does not hold when any is reversed and none "
        "holds:",
        "",
        *to_markdown(summary.set_index("finding"), "finding").strip().splitlines(),
    ]
    if len(findings):
        scenes = list(dict.fromkeys(findings["scene"]))
        lines += _captioned_head(
            "Every check: SR of the first variant minus the second, percentage points, mean [95 % CI] and verdict "
            "(`one seed`: shown, not judged):",
            ["finding", "claim", *scenes],
        )

        def check(r: pd.Series) -> str:
            ok = math.isfinite(r["diff"])
            return f"{_signed(r['diff'])} [{_signed(r['lo'])}, {_signed(r['hi'])}] {r['verdict']}" if ok else ""

        for (finding, claim), g in findings.groupby(["finding", "claim"], sort=False):
            lines.append(f"| {finding} | {claim} | {scene_cells(g, scenes, check)} |")
    frames = [e.assign(grid=g) for g, e in episodes.items() if len(e)]
    table = aggregate(pd.concat(frames, ignore_index=True), ("grid", "label", "scene"), reps=reps).reset_index()
    order = {(g, v.label): i for i, (g, v) in enumerate((g, v) for g in ABLATION_GRIDS for v in GRIDS[g])}
    rank = [order.get(k, len(order)) for k in zip(table["grid"], table["label"])]  # the grids' own order
    table = table.assign(_rank=rank).sort_values("_rank", kind="stable").drop(columns="_rank")
    scenes = list(dict.fromkeys(table["scene"]))
    lines += _captioned_head(
        "Success rate % per variant, mean [95 % CI] over its seeds × the layouts (the ablation budgets: a variant is "
        "not its Table I run):",
        ["grid", "variant", "seeds", *scenes],
    )
    for (g, label), t in table.groupby(["grid", "label"], sort=False):
        sr = scene_cells(t, scenes, lambda r: ci_text(r["SR"], r["SR_lo"], r["SR_hi"]))
        lines.append(f"| {g} | {label} | {int(t['seeds'].max())} | {sr} |")
    return "\n".join(_wrap(x) for x in lines)


def _captioned_head(caption: str, columns: list[str]) -> list[str]:
    """Markdown lines opening a table: a blank line, ``caption``, a blank line, the header and its rule."""
    return ["", caption, "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]


def _progress_md(cfg: Any, seeds: int = 5) -> list[str]:
    """Markdown lines: which learned methods' training seeds the grid has recorded (✓) and which are to come."""
    record = GridData(grid_data_dir(cfg, "table1"))
    learned = [m for m in TABLE1_METHODS if METHODS[m].learned]
    p = record.progress(learned, range(seeds))
    lines = [
        f"**Grid progress**: {int(p.to_numpy().sum())} of {p.size} training runs recorded (✓; the planners fly "
        "once and are all recorded).",
        "",
        "| method | " + " | ".join(p.columns) + " |",
        "|---|" + "---|" * len(p.columns),
    ]
    lines += [f"| {METHODS[m].label} | " + " | ".join("✓" if x else "" for x in p.loc[m]) + " |" for m in p.index]
    return lines


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
    text = (
        f"**How the grid ran** (from its run records): {len(rl)} training runs recorded, "
        f"{rl['train_s'].sum() / 3600:.1f} machine-hours of RL training (each run's logged rollout and update time: "
        + ", ".join(f"{k} {v:.1f}" for k, v in hours.items())
        + ")"
    )
    jobs_csv = record.root / "jobs.csv"
    if jobs_csv.is_file():
        jobs = pd.read_csv(jobs_csv)
        done = jobs[jobs["status"] == "done"].groupby("kind")["seconds"].agg(["sum", "size"])
        names = {"pretrain": "pretraining", "evaluate": "evaluation"}
        parts = [f"{name} {done.loc[k, 'sum'] / 3600:.1f} h ({int(done.loc[k, 'size'])} jobs)"
                 for k, name in names.items() if k in done.index]  # fmt: skip
        if parts:
            text += "; as the grid's jobs.csv timed them, " + " and ".join(parts)
    students = rl.dropna(subset=["encoder"])
    if len(students):
        sharing = students.groupby("encoder")["label"].agg(lambda x: ", ".join(sorted(set(x)))).value_counts()
        text += (
            f". Reused: {students['encoder'].nunique()} encoders serve {len(students)} frozen-encoder students ("
            # Encoders that serve several students first.
            + "; ".join(
                _sharing_words(labels.split(", "), n)
                for labels, n in sorted(sharing.items(), key=lambda kv: "," not in kv[0])
            )
            + ")"
        )
    taught = rl.dropna(subset=["oracle"])
    if len(taught):
        text += f", {int((rl['method'] == 'oracle').sum())} oracles teach {len(taught)} students"
    text += ", and the planners fly once"
    seg = rl["segments"].dropna()
    if len(seg):
        text += (
            f". Resumed after a stop: {int((seg > 1).sum())} of the {len(seg)} runs that record their stretches of "
            "training (kept since 2026-12-05)"
        )
    cpu = rl["cpu"].replace("", "not recorded").value_counts()
    text += ". Machines per run (torch's CPU capability): " + ", ".join(f"{k} {n}" for k, n in cpu.items()) + "."
    return ["", _wrap(text)]


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
    lines = [
        "**Which verdicts changed from v1**: the v1 reference's orderings (SR points, 95 % CI per cell, no "
        "multiplicity correction, a two-stage bootstrap) beside the ledger's hypothesis on the same ordering and "
        f"scene family on v2 (Holm-adjusted). {int(n.sum())} of {len(n)} judged on both changed; "
        f"{int(ch['changed'].isna().sum())} not judged on v2 yet.",
        "",
        "| ordering | family | v1 scene | v1 | v1 verdict | v2 scene | v2 | v2 verdict | changed |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in ch.itertuples():
        changed = "–" if r.changed is None else ("**yes**" if r.changed else "no")
        lines.append(f"| {r.ordering} | {r.family} | {r.v1_scene} | {r.v1} | {r.v1_verdict} | {r.v2_scene} | {r.v2} | "
                     f"{r.v2_verdict} | {changed} |")  # fmt: skip
    return [_wrap(x) for x in lines]


def _rewrite(path: Path, blocks: list[tuple[str, str, str]]) -> bool:
    text = path.read_text(encoding="utf-8")
    new = text
    for block, start, end in blocks:
        new = replace_block(new, block, str(path), start, end)
    if new != text:
        atomic_write_text(path, new)
    return new != text


def update_readme(preset: str = "quick", readme: str | Path | None = None) -> bool:
    """Rewrite the README's blocks (v2 from ``reference/<preset>/table1-v2/``, v1 from ``reference/<preset>/table1``),
    docs/results.md's v2 block and the v2 Fig. 5 beside them (:data:`V2_FIGURE`), its ladder block and figures
    (:func:`ladder_block`, :data:`LADDER_FIGURES`), its v2 ablations block (:func:`ablation_block`), and
    docs/glossary.md's metrics
    table (:func:`omcrl.eval.metrics.glossary_markdown`); True when the README changed."""
    root = project_root()
    path = Path(readme) if readme is not None else root / "README.md"
    short, full, confirm = _v2(preset, figure_to=root / V2_FIGURE)
    v1 = render_v1_results(reference_table_dir(preset))
    ladder = ladder_block(preset, figures_to=root / LADDER_FIGURES)
    blocks = [(full, FULL_START, FULL_END), (confirm, CONFIRM_START, CONFIRM_END), (v1, V1_START, V1_END),
              (ladder, LADDER_START, LADDER_END), (ablation_block(preset), ABLATION_START, ABLATION_END),
              (detour_block(preset), WHY_DETOUR_START, WHY_DETOUR_END),
              (attribution_block(preset), WHY_LOOK_START, WHY_LOOK_END)]  # fmt: skip
    _rewrite(root / "docs" / "results.md", blocks)
    _rewrite(root / "docs" / "glossary.md", [(glossary_markdown(), GLOSSARY_START, GLOSSARY_END)])
    _rewrite(root / "docs" / "generalization.md", [(transfer_block(preset), TRANSFER_START, TRANSFER_END)])
    return _rewrite(path, [(render_glance(reference_table_dir(preset)), START, END), (short, V2_START, V2_END)])
