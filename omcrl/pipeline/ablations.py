"""The paper's ablations (VI-C) from the grids' data in the checkout: Tables II–III, Figs. 7–10, the six findings.

``python -m omcrl tables --preset quick --from-reference --grid ablations`` reads what the six ablation grids
(:data:`omcrl.pipeline.grids.ABLATION_GRIDS`) recorded under ``reference/<preset>/<grid>-<suite>/`` at the training
seeds :data:`ABLATION_SEEDS` and writes, nothing trained or flown::

    tables/ablation_<grid>.{csv,md,tex}     every variant × scene × metric, mean ± half-width of the 95 % CI
    tables/table2.*, table3.*               the sequential and decay grids as the paper's Tables II and III
    tables/table{2,3}_vs_paper.{csv,md}     the paper's value beside the kit's mean [95 % CI], cell by cell
    tables/ablation_findings.{csv,md}       the six findings judged (paired, Holm over the unseen-scene checks)
    tables/ablation_findings_table1.{csv,md}  the same orderings judged on Table I's runs where both variants are
                                            Table I methods as they are (:func:`table1_counterparts`)
    tables/ablation_account.{csv,md}        jobs and machine-hours per grid and kind, measured against the plan,
                                            and what the grids left to run would cost
    figures/fig7_mask_prob.png ...          Figs. 7–10 (and the other grids' bars) from the same aggregate tables

The variants train at the sweep budgets (``cfg.sweep``: at quick 50,000 env steps and 750 pretraining iterations,
docs/DEVIATIONS.md), so they compare with each other, not with Table I's runs. Where two variants of a finding are
Table I methods with no override (today ours / ours w/o OT, NPE / NPE w/ OT, CURL / CURL w/ phi: derived from
``GRIDS`` by :func:`table1_counterparts`), Table I's runs (its full budget, five seeds) judge the same ordering
again, apart: does a finding's verdict move with the budget?
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

from omcrl.config import Config
from omcrl.eval.ablation import ablation_table, write_ablation, write_findings
from omcrl.eval.stats import DEFAULT_REPS
from omcrl.pipeline.griddata import GridData, grid_data_dir
from omcrl.pipeline.grids import ABLATION_GRIDS, GRIDS
from omcrl.pipeline.ladder import PLAN_RATES, cost_table, estimate_rest, timed_jobs
from omcrl.pipeline.sweep import rest_plan
from omcrl.rl.methods import TABLE1_METHODS
from omcrl.utils.io import atomic_write_text
from omcrl.viz import save_figure
from omcrl.viz.ablation import plot_ablation

# The training seeds for every ablation grid (the paper averages three).
ABLATION_SEEDS = (0, 1, 2)


def ablation_records(cfg: Config, seeds: Sequence[int] = ABLATION_SEEDS) -> dict[str, pd.DataFrame]:
    """``{grid: episodes}``: each ablation grid's recorded episodes at the training ``seeds`` (grids with none left
    out), as :meth:`GridData.episodes` gives them (one row per episode, ``label`` the variant)."""
    out = {}
    for g in ABLATION_GRIDS:
        ep = GridData(grid_data_dir(cfg, g)).episodes()
        if len(ep):
            ep = ep[ep["train_seed"].isin(list(seeds))]
        if len(ep):
            out[g] = ep.reset_index(drop=True)
    return out


def account(cfg: Config, seeds: Sequence[int] = ABLATION_SEEDS) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The grids' cost: what ran, against the plan, and what is left.

    Returns
    -------
    ran : :func:`omcrl.pipeline.ladder.cost_table` over the ablation grids (``grid, rate_key, jobs, work,
        planned_h, measured_h, resumed``): the jobs each grid's sweeps ran (jobs found finished, a run another grid
        of the same worktree had trained, are not counted), hours at the rates its plan kept (``plan_rates.json``)
        and as measured, and how many of them resumed from a checkpoint (:func:`_resumed`).
    rest : ``rate_key, jobs, work, planned_h, ratio, estimate_h``: the jobs of all six grids at ``seeds`` that no
        record holds yet, counted once where grids share them (Table I's runs left out), at the plan's rates, and
        those hours × the measured / planned ratio of that kind (of every job that ran where none of that kind has).
    """
    ran = cost_table(cfg, {g: g for g in ABLATION_GRIDS}, column="grid")
    resumed = {g: _resumed(grid_data_dir(cfg, g)) for g in ran["grid"].unique()}
    ran["resumed"] = [resumed[g].get(k, 0) for g, k in zip(ran["grid"], ran["rate_key"])]
    rates = {}
    for g in ABLATION_GRIDS:
        path = grid_data_dir(cfg, g) / PLAN_RATES
        if path.is_file():
            rates = json.loads(path.read_text(encoding="utf-8"))
            break
    rows = estimate_rest(rest_plan(cfg, ABLATION_GRIDS, seeds), rates, ran)
    rest = pd.DataFrame(rows, columns=["rate_key", "jobs", "work", "planned_h", "ratio", "estimate_h"])
    return ran, rest


def _resumed(folder: Path) -> dict[str, int]:
    """``{rate_key: jobs}`` of a grid's timed jobs (:func:`omcrl.pipeline.ladder.timed_jobs`, under ``folder``)
    that resumed from a checkpoint: ``start`` > 0 in ``jobs.csv``. A row written before ``start`` was kept has none;
    its work is the part after its checkpoint, so it resumed when that is below the largest work of its kind, which
    holds in the ablation grids, whose variants all train at the sweep budgets (not in the ladders, whose variants
    differ in budget). The time a stopped attempt spent before its checkpoint is in no record."""
    if (jobs := timed_jobs(folder)) is None:
        return {}
    below = jobs["work"] < jobs.groupby("rate_key")["work"].transform("max")
    start = jobs["start"] if "start" in jobs else pd.Series(float("nan"), index=jobs.index)
    resumed = (start > 0) | (start.isna() & below)
    return {str(k): int(n) for k, n in jobs[resumed].groupby("rate_key").size().items()}


def account_markdown(ran: pd.DataFrame, rest: pd.DataFrame) -> str:
    """:func:`account`'s two tables in Markdown, each with a total row (hours ``–`` where a kind has none)."""

    def h(x: float) -> str:
        return "–" if not math.isfinite(x) else f"{x:.2f}"

    lines = [
        "Ran: the jobs each grid's sweeps ran (a run found finished, trained by another grid in the same worktree, is "
        "not counted again), how many resumed from a checkpoint (their hours count the part after it), hours at the "
        "rates the grid's plan kept and as measured.",
        "",
        "| grid | kind | jobs | of them resumed | planned h | measured h | measured / planned |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in ran.itertuples():
        lines.append(f"| {r.grid} | {r.rate_key} | {r.jobs} | {r.resumed} | {h(r.planned_h)} | {h(r.measured_h)} | "
                     f"{h(r.measured_h / r.planned_h if r.planned_h else math.nan)} |")  # fmt: skip
    if ran.empty:
        lines.append("| – | none timed yet | 0 | 0 | | | |")
    else:
        p, m = ran["planned_h"].sum(min_count=len(ran)), ran["measured_h"].sum()
        lines.append(f"| all | all | {int(ran['jobs'].sum())} | {int(ran['resumed'].sum())} | {h(p)} | {h(m)} | "
                     f"{h(m / p if p else math.nan)} |")  # fmt: skip
    lines += [
        "",
        "Left: the jobs of the six grids that no record holds yet (shared runs once, Table I's runs left out), at the "
        "plan's rates and × the measured / planned ratio of their kind: the estimate for this machine.",
        "",
        "| kind | jobs | planned h | measured / planned | estimated h |",
        "|---|---|---|---|---|",
    ]
    for r in rest.itertuples():
        lines.append(f"| {r.rate_key} | {r.jobs} | {h(r.planned_h)} | {h(r.ratio)} | {h(r.estimate_h)} |")
    if len(rest):
        lines.append(f"| all | {int(rest['jobs'].sum())} | {h(rest['planned_h'].sum(min_count=len(rest)))} | | "
                     f"{h(rest['estimate_h'].sum(min_count=len(rest)))} |")  # fmt: skip
    return "\n".join(lines) + "\n"


# What the Table I check is, at the head of its file.
TABLE1_INTRO = (
    "The same orderings judged on Table I's runs (its full RL budget and training seeds, its layouts), where both "
    "variants are Table I methods with no override; chosen after Table I's runs were recorded, so a second look, not "
    "a declared family."
)


def table1_counterparts(cfg: Config) -> dict[str, pd.DataFrame]:
    """``{grid: episodes}`` of Table I's recorded runs for each ablation grid's variants that are Table I methods as
    they are (no override), labelled with the variant's label, so :func:`omcrl.eval.ablation.ablation_findings`
    judges the paper's orderings between them at Table I's budget and training seeds. Grids with fewer than two such
    variants, or no Table I record, are left out."""
    table1 = GridData(grid_data_dir(cfg, "table1")).episodes()
    if table1.empty:
        return {}
    out = {}
    for g in ABLATION_GRIDS:
        same = {v.label: v.method for v in GRIDS[g] if not v.overrides and v.method in TABLE1_METHODS}
        frames = [f for label, m in same.items() if len(f := table1[table1["method"] == m].assign(label=label))]
        if len(frames) >= 2:
            out[g] = pd.concat(frames, ignore_index=True)
    return out


@dataclass
class AblationResult:
    """What :func:`ablations_from_reference` read and wrote.

    ``episodes``: ``{grid: episodes}`` (:func:`ablation_records`); ``tables``: ``{grid: aggregate table}``
    (:func:`omcrl.eval.ablation.ablation_table`, index (variant, scene)); ``findings`` / ``summary``: every check and
    one line per finding (:func:`omcrl.eval.ablation.write_findings`); ``ran`` / ``rest``: :func:`account`;
    ``paths``: every file written; ``seconds``: wall time; ``at_table1`` / ``at_table1_summary``: the same
    checks and summary on Table I's runs (:func:`table1_counterparts`; empty without them).
    """

    episodes: dict[str, pd.DataFrame]
    tables: dict[str, pd.DataFrame]
    findings: pd.DataFrame
    summary: pd.DataFrame
    ran: pd.DataFrame = field(default_factory=pd.DataFrame)
    rest: pd.DataFrame = field(default_factory=pd.DataFrame)
    paths: dict[str, Path] = field(default_factory=dict)
    seconds: float = 0.0
    at_table1: pd.DataFrame = field(default_factory=pd.DataFrame)
    at_table1_summary: pd.DataFrame = field(default_factory=pd.DataFrame)

    def __repr__(self) -> str:
        grids = ", ".join(f"{g} ({len(t.index.get_level_values(0).unique())} variants)" for g, t in self.tables.items())
        return f"AblationResult({grids}; {len(self.findings)} checks, {len(self.paths)} files, {self.seconds:.1f} s)"


def ablations_from_reference(
    cfg: Config, seeds: Sequence[int] = ABLATION_SEEDS, reps: int = DEFAULT_REPS
) -> AblationResult:
    """The module's tables and figures from the grids' records in the checkout alone, under ``cfg.run_root``
    (``tables/``, ``figures/``). FileNotFoundError when no ablation grid has episodes at ``seeds``."""
    t0 = time.perf_counter()
    episodes = ablation_records(cfg, seeds)
    if not episodes:
        folders = ", ".join(grid_data_dir(cfg, g).name for g in ABLATION_GRIDS)
        raise FileNotFoundError(
            f"no ablation grid has recorded episodes of training seeds {list(seeds)} under "
            f"{grid_data_dir(cfg, ABLATION_GRIDS[0]).parent} ({folders}); run scripts/grid_session.sh --grid <grid> "
            f"--seeds {','.join(map(str, seeds))} (or python -m omcrl sweep <grid> --preset {cfg.preset} "
            "--to-reference) first"
        )
    out, figs = cfg.run_root / "tables", cfg.run_root / "figures"
    tables, paths = {}, {}
    for g, ep in episodes.items():
        order = [v.label for v in GRIDS[g]]  # the paper's order of the variants, in tables and figures alike
        tables[g] = ablation_table(ep, reps, order)
        paths.update(write_ablation(ep, out, g, reps, order))
        name, fig = plot_ablation(g, tables[g])
        paths[name] = save_figure(fig, figs, name)
        plt.close(fig)
    findings, summary, fpaths = write_findings(episodes, out, reps)
    paths.update({f"ablation_findings.{k}": v for k, v in fpaths.items()})
    at_table1, at_table1_summary = pd.DataFrame(), pd.DataFrame()
    if counterparts := table1_counterparts(cfg):
        at_table1, at_table1_summary, tpaths = write_findings(
            counterparts, out, reps, "ablation_findings_table1", intro=TABLE1_INTRO
        )
        paths.update({f"ablation_findings_table1.{k}": v for k, v in tpaths.items()})
    ran, rest = account(cfg, seeds)
    for suffix, text in (("csv", None), ("md", account_markdown(ran, rest))):
        path = out / f"ablation_account.{suffix}"
        if text is None:
            both = pd.concat([ran.assign(part="ran"), rest.assign(part="left")], ignore_index=True)
            text = both.to_csv(index=False)
        atomic_write_text(path, text)
        paths[path.name] = path
    seconds = time.perf_counter() - t0
    return AblationResult(episodes, tables, findings, summary, ran, rest, paths, seconds, at_table1, at_table1_summary)
