"""The budget ladder from the grids' data in the checkout: does a verdict move with scale?

``python -m omcrl ladder --preset quick`` reads what the grids ``table1`` (the ×1 points), ``ladder-pretrain`` and
``ladder-rl`` recorded under ``reference/<preset>/`` (:mod:`omcrl.pipeline.griddata`) and writes, nothing trained or
flown::

    tables/ladder_table.{csv,md}      per ladder (pretrain, rl), method, budget multiplier and scene: SR, CR and SPL
                                      with 95 % CIs over seeds × layouts (Table I's intervals, omcrl.eval.stats)
    tables/ladder_encoders.{csv,md}   per pretraining point: the objective's top-1 at the end of pretraining, the
                                      linear probe's R² in the training scene and each unseen scene, and the
                                      features' shift (MMD²) from the training scene (omcrl.interpret.encoder_report),
                                      mean over the seeds whose report is recorded
    tables/ladder_verdicts.{csv,md}   the claim ledger (omcrl.eval.ledger) judged at each point of each ladder, on the
                                      rows whose methods that ladder trains (planners are budget-free and join every
                                      point); Holm over the rows judged at that point; ``stable`` says whether a
                                      row's verdict is the same at every budget of the ladder
    figures/ladder_<scene>.png        SR against budget (log axis), one panel per ladder

A point is a method at a multiplier of the preset's budget: pretraining (dataset episodes, iterations and the
Transformer's warm-up scaled together) or RL (env steps, with the guidance decay scaled). The ×1 points are Table I's
runs at the ladder's seeds (:data:`LADDER_SEEDS`), so every point is compared over the same seeds and layouts.
"""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

from omcrl.config import Config
from omcrl.eval.metrics import episode_values
from omcrl.eval.stage import scene_cells, to_markdown
from omcrl.eval.stats import BOUNDED, DEFAULT_REPS, aggregate, cell_rng, term
from omcrl.eval.table1 import ci_text
from omcrl.eval.verdicts import holm_verdicts, judge, ledger_verdicts
from omcrl.interpret.encoder_report import REPORT, read_report, suite_settings, write_encoder_report
from omcrl.interpret.transfer import setting_samples
from omcrl.pipeline.griddata import GridData, grid_data_dir
from omcrl.pipeline.grids import GRIDS
from omcrl.pipeline.pages import render
from omcrl.pipeline.reference import config_suite
from omcrl.pipeline.sweep import rest_plan
from omcrl.planners import PLANNERS
from omcrl.rl.train import rollout_geometry
from omcrl.runs import read_identity
from omcrl.utils.io import atomic_write_bytes, atomic_write_text
from omcrl.viz import save_figure
from omcrl.viz.ladder import plot_ladder

BASE_GRID = "table1"
# ladder -> (its grid, the field whose multiplier is the ladder's budget)
LADDERS: dict[str, tuple[str, str]] = {
    "pretrain": ("ladder-pretrain", "pretrain.iterations"),
    "rl": ("ladder-rl", "rl.total_steps"),
}
# The issue's seeds for the ladder; Table I's ×1 points are taken at the same ones.
LADDER_SEEDS = (0, 1, 2)
SHOWN = ("SR", "CR", "SPL")
# Beside a ladder grid's data: the rates (units/s per rate_key) its plan was made with, written by
# ``python -m omcrl sweep <grid> --plan --rates-out`` before its first job; --rates with this file plans the same.
PLAN_RATES = "plan_rates.json"


def _multiplier(overrides: Sequence[str], field_name: str) -> float | None:
    for o in overrides:
        m = re.fullmatch(rf"{re.escape(field_name)}\*=([0-9.]+)", o.strip())
        if m:
            return float(m.group(1))
    return None


def ladder_points() -> pd.DataFrame:
    """Every point of every ladder: ``axis, grid, label, method, scale`` (the ×1 points are Table I's labels)."""
    rows = []
    for axis, (grid, field_name) in LADDERS.items():
        variants = GRIDS[grid]
        for method in dict.fromkeys(v.method for v in variants):
            rows.append({"axis": axis, "grid": BASE_GRID, "label": method, "method": method, "scale": 1.0})
        for v in variants:
            scale = _multiplier(v.overrides, field_name)
            if scale is None:
                raise ValueError(f"ladder {axis}: variant {v.label!r} of {grid} has no '{field_name}*=' override")
            rows.append({"axis": axis, "grid": grid, "label": v.label, "method": v.method, "scale": scale})
    return pd.DataFrame(rows)


def budgets(cfg: Config) -> dict[str, str]:
    """``{axis: what its ×1 is at cfg}``, for the figure's axis labels."""
    return {
        "pretrain": f"{cfg.pretrain.iterations:,} iterations on {cfg.data.episodes:,} episodes",
        "rl": f"{rollout_geometry(cfg.rl)[3]:,} env steps",  # what a run makes: whole updates, not total_steps
    }


def _planners(cfg: Config) -> pd.DataFrame:
    """The planners' recorded episodes (budget-free: they join every point)."""
    ep = GridData(grid_data_dir(cfg, BASE_GRID)).episodes()
    return ep[ep["method"].isin(list(PLANNERS))] if len(ep) else ep


def ladder_episodes(cfg: Config, seeds: Sequence[int] = LADDER_SEEDS) -> pd.DataFrame:
    """Every recorded episode of every ladder point at the training ``seeds``, with ``axis`` and ``scale`` columns
    (``method`` is the point's method, ``label`` its grid label); an empty frame when nothing is recorded."""
    frames = []
    data = {g: GridData(grid_data_dir(cfg, g)) for g in {BASE_GRID, *(g for g, _ in LADDERS.values())}}
    for p in ladder_points().itertuples():
        ep = data[p.grid].episodes([p.label])
        if len(ep):
            ep = ep[ep["train_seed"].isin(list(seeds))]
            frames.append(ep.assign(axis=p.axis, scale=p.scale, method=p.method))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def ladder_table(episodes: pd.DataFrame, reps: int = DEFAULT_REPS) -> pd.DataFrame:
    """Mean and 95 % CI (omcrl.eval.stats.aggregate) of every metric per ``axis, method, scale, scene``; a point
    recorded in both ladders (×1) gets the same interval in each."""
    if episodes.empty:
        return pd.DataFrame(columns=["axis", "method", "scale", "scene", "seeds", "episodes"])
    # Per ladder, with the ladder left out of the bootstrap's key: both ladders' ×1 points are Table I's runs, and the
    # same runs should print the same interval in either.
    out = pd.concat(
        [
            aggregate(ep, ("method", "scale", "scene"), reps=reps).reset_index().assign(axis=axis)
            for axis, ep in episodes.groupby("axis", sort=False)
        ],
        ignore_index=True,
    )
    return out.sort_values(["axis", "method", "scale"], kind="stable", ignore_index=True)


def scale_effects(episodes: pd.DataFrame, reps: int = DEFAULT_REPS, seed: int = 0) -> pd.DataFrame:
    """Does SR move with budget? Per ladder, method, point above ×1 and scene: SR at ×k minus SR at ×1.

    The two are paired as Table I's contrasts are (:func:`omcrl.eval.stats.contrast`): the same layouts, and the
    ×1 runs taken at the training seeds the ×k point has, each seed's two runs resampled together. Holm–Bonferroni
    over every (method, point, scene) of a ladder (:func:`omcrl.eval.verdicts.holm_verdicts`, one family per ladder).
    This is the direct test of a change with scale; a ledger verdict that differs between budgets may also differ
    because each point's Holm family holds the rows that point judges.

    Parameters
    ----------
    episodes : :func:`ladder_episodes` (``axis, method, scale, scene, train_seed, seed``, the metrics' columns).

    Returns
    -------
    DataFrame ``axis, method, scale, scene, seeds, diff, lo, hi, p, p_holm, verdict``: ``diff`` in percentage
    points with its 95 % CI; ``verdict`` ``up`` / ``down`` (Holm-adjusted p < 0.05, by its sign), ``no change
    resolved``, or ``one seed`` (a point of one training seed: shown, not judged).
    """
    cols = ["axis", "method", "scale", "scene", "seeds", "diff", "lo", "hi", "p", "p_holm", "verdict"]
    if episodes.empty:
        return pd.DataFrame(columns=cols)
    values = episode_values(episodes)
    rows = []
    for (axis, method), g in episodes.groupby(["axis", "method"], sort=False):
        base = g[g["scale"] == 1.0]
        for scale in sorted(s for s in g["scale"].unique() if s != 1.0):
            top = g[g["scale"] == scale]
            for scene in dict.fromkeys(top["scene"]):
                hi_ = top[top["scene"] == scene]
                lo_ = base[(base["scene"] == scene) & base["train_seed"].isin(set(hi_["train_seed"]))]
                terms = [
                    term(hi_, values.loc[hi_.index, "SR"].to_numpy(), scene, 1.0),
                    term(lo_, values.loc[lo_.index, "SR"].to_numpy(), scene, -1.0) if len(lo_) else None,
                ]
                rng = cell_rng(seed, "scale", axis, method, scale, scene)
                rows.append({"axis": axis, "method": method, "scale": scale, "scene": scene,
                             **judge(terms, [True, True], reps, rng, BOUNDED["SR"])})  # fmt: skip
    if not rows:
        return pd.DataFrame(columns=cols)
    out = holm_verdicts(pd.DataFrame(rows), "axis").rename(columns={"estimate": "diff"})
    out["verdict"] = out["verdict"].replace({"holds": "up", "reversed": "down", "undecided": "no change resolved"})
    return out[cols]


def timed_jobs(folder: Path) -> pd.DataFrame | None:
    """The rows of a grid's ``jobs.csv`` (under ``folder``) that ran and were timed (``done``, seconds > 0); None
    when the grid keeps no ``jobs.csv``."""
    if not (folder / "jobs.csv").is_file():
        return None
    jobs = pd.read_csv(folder / "jobs.csv")
    return jobs[(jobs["status"] == "done") & (jobs["seconds"] > 0)]


def cost_table(cfg: Config, groups: Mapping[str, str] | None = None, column: str = "ladder") -> pd.DataFrame:
    """The plan's predicted cost against the measured time, per ladder and kind of job, for the jobs its grid ran.

    ``groups``: ``{row name: grid}`` (default: each ladder's grid, :data:`LADDERS`), the name in ``column``; the
    ablations' account passes their grids.

    Reads what a ladder's grid keeps beside its data (:func:`grid_data_dir`): ``jobs.csv`` (each job this grid ran,
    its work and seconds; a training or pretraining resumed from a checkpoint counts the part after it) and
    :data:`PLAN_RATES` (the rates its plan used, ``sweep <grid> --plan --rates-out``). Jobs found finished
    (``skipped``) ran nothing and are left out.

    Returns
    -------
    DataFrame ``ladder, rate_key, jobs, work, planned_h, measured_h``: ``planned_h`` = Σ work / the plan's rate
    (NaN for a kind the plan had no rate for, or no plan kept), ``measured_h`` = Σ seconds, both in hours.
    """
    rows = []
    for axis, grid in (groups or {a: g for a, (g, _) in LADDERS.items()}).items():
        folder = grid_data_dir(cfg, grid)
        if (jobs := timed_jobs(folder)) is None:
            continue
        rates = json.loads((folder / PLAN_RATES).read_text()) if (folder / PLAN_RATES).is_file() else {}
        for key, g in jobs.groupby("rate_key", sort=False):
            rate = rates.get(key)
            rows.append({column: axis, "rate_key": key, "jobs": len(g), "work": int(g["work"].sum()),
                         "planned_h": g["work"].sum() / rate / 3600 if rate else math.nan,
                         "measured_h": g["seconds"].sum() / 3600})  # fmt: skip
    return pd.DataFrame(rows, columns=[column, "rate_key", "jobs", "work", "planned_h", "measured_h"])


def rest_cost(cfg: Config, cost: pd.DataFrame, seeds: Sequence[int] = LADDER_SEEDS) -> pd.DataFrame:
    """What the rest of each ladder would cost: its jobs at ``seeds`` that no record in the checkout holds (Table
    I's runs left out, as the plan leaves them), per kind of job.

    Parameters
    ----------
    cost : :func:`cost_table`'s rows; their measured / planned ratio scales the plan's hours to this machine.

    Returns
    -------
    DataFrame ``ladder, rate_key, jobs, work, planned_h, ratio, estimate_h``: ``planned_h`` at the rates the ladder's
    plan kept (:data:`PLAN_RATES`; a ladder without them is left out), ``ratio`` the measured / planned hours of the
    jobs of that kind that ran in either ladder, else of every job that ran (NaN when none has), ``estimate_h`` =
    ``planned_h × ratio``. A job half run counts whole; a job no plan rate covers has NaN hours.
    """
    cols = ["ladder", "rate_key", "jobs", "work", "planned_h", "ratio", "estimate_h"]
    rows = []
    for axis, (grid, _) in LADDERS.items():
        folder = grid_data_dir(cfg, grid)
        if not (folder / PLAN_RATES).is_file():
            continue
        rates = json.loads((folder / PLAN_RATES).read_text())
        rows += [{"ladder": axis, **r} for r in estimate_rest(rest_plan(cfg, [grid], seeds), rates, cost)]
    return pd.DataFrame(rows, columns=cols)


def estimate_rest(rest: pd.DataFrame, rates: Mapping[str, float], cost: pd.DataFrame) -> list[dict]:
    """One row per kind of job of ``rest`` (:func:`omcrl.pipeline.sweep.rest_plan`'s rows): ``rate_key, jobs, work,
    planned_h, ratio, estimate_h``, its hours at the plan's ``rates`` (NaN for a kind without one) and those × the
    measured / planned ratio of that kind in ``cost`` (:func:`cost_table`), or of every job there where none of that
    kind ran (NaN when none has)."""
    measured = cost.groupby("rate_key")[["planned_h", "measured_h"]].sum(min_count=1)
    ratio = (measured["measured_h"] / measured["planned_h"]).dropna()
    overall = cost["measured_h"].sum() / cost["planned_h"].sum() if cost["planned_h"].sum() > 0 else math.nan
    rows = []
    for key, g in rest.groupby("rate_key", sort=False):
        planned = g["work"].sum() / rates[key] / 3600 if key in rates else math.nan
        r = float(ratio.get(key, overall))
        rows.append({"rate_key": key, "jobs": len(g), "work": int(g["work"].sum()), "planned_h": planned,
                     "ratio": r, "estimate_h": planned * r})  # fmt: skip
    return rows


def encoder_rows(cfg: Config, seeds: Sequence[int] = LADDER_SEEDS) -> pd.DataFrame:
    """The recorded encoder reports of the pretraining ladder's points, long: ``method, scale, seed, quantity,
    setting, value`` (quantity ``top1``, ``probe_r2`` or ``mmd``)."""
    rows = []
    for p in ladder_points().query("axis == 'pretrain'").itertuples():
        data = GridData(grid_data_dir(cfg, p.grid))
        for s in seeds:
            rep = read_report(data.folder(p.label, s) / "pretrain")
            if rep is None:
                continue
            base = {"method": p.method, "scale": p.scale, "seed": s}
            rows.append({**base, "quantity": "top1", "setting": "", "value": rep.get("top1", math.nan)})
            for q in ("probe_r2", "mmd"):
                rows += [{**base, "quantity": q, "setting": k, "value": v} for k, v in rep.get(q, {}).items()]
    return pd.DataFrame(rows, columns=["method", "scale", "seed", "quantity", "setting", "value"])


def encoder_table(rows: pd.DataFrame, reference: str) -> pd.DataFrame:
    """One row per ``method, scale``: ``seeds`` reported, ``top1`` and a column per setting for the probe's R²
    (``R2 <setting>``) and the shift from ``reference`` (``MMD <setting>``; the reference itself, 0 by
    construction, left out), each the mean over the seeds."""
    if rows.empty:
        return pd.DataFrame(columns=["method", "scale", "seeds", "top1"])
    out = rows.groupby(["method", "scale"], sort=False)["seed"].nunique().rename("seeds").to_frame()
    for q, prefix in (("top1", ""), ("probe_r2", "R2 "), ("mmd", "MMD ")):
        sub = rows[(rows["quantity"] == q) & ~((q == "mmd") & (rows["setting"] == reference))]
        wide = sub.pivot_table(index=["method", "scale"], columns="setting", values="value", aggfunc="mean", sort=False)
        out = out.join(wide.rename(columns=lambda c, p=prefix: (p + c) if c else "top1"))
    return out.reset_index().sort_values(["method", "scale"], kind="stable", ignore_index=True)


def _training(cfg: Config, axis: str, scale: float, seeds: Sequence[int]) -> dict[str, dict[int, Path]]:
    """``{method: {seed: metrics.csv.gz}}`` of the point's RL runs (Fig. 5's rows of the ledger)."""
    out: dict[str, dict[int, Path]] = {}
    points = ladder_points()
    for p in points[(points["axis"] == axis) & (points["scale"] == scale)].itertuples():
        data = GridData(grid_data_dir(cfg, p.grid))
        runs = data.metrics("rl").get(data.folder(p.label, 0).parent.name, {})  # keyed by the label's folder
        got = {s: m for s, m in runs.items() if s in seeds}
        if got:
            out[p.method] = got
    return out


def verdicts_by_budget(
    cfg: Config, episodes: pd.DataFrame, seeds: Sequence[int] = LADDER_SEEDS, reps: int = DEFAULT_REPS
) -> pd.DataFrame:
    """The ledger judged at every point of every ladder, long: the ledger's columns plus ``axis`` and ``scale``.

    A point's episodes are its methods' and the planners' (which have no budget); its training runs are its
    methods'. The rows kept are those that point can judge (a method outside the ladder makes a row ``not run``) and
    that involve a method of the ladder, so each point's Holm family is the ledger rows of its own methods."""
    suite = config_suite(cfg)
    planners = _planners(cfg)
    frames = []
    points = ladder_points()
    for axis in LADDERS:
        for scale in sorted(points.loc[points["axis"] == axis, "scale"].unique()):
            ep = episodes[(episodes["axis"] == axis) & (episodes["scale"] == scale)] if len(episodes) else episodes
            ep = pd.concat([ep, planners], ignore_index=True) if len(planners) else ep
            v = ledger_verdicts(ep, _training(cfg, axis, scale, seeds), suite, reps)
            # Rows of planners alone do not depend on a budget: only those with a method of the ladder are kept.
            mine = v["a"].isin(set(points.loc[points["axis"] == axis, "method"])) | v["b"].isin(
                set(points.loc[points["axis"] == axis, "method"])
            )
            v = v[mine & (v["verdict"] != "not run")]
            if len(v):
                frames.append(v.assign(axis=axis, scale=scale))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _encoder_rows(enc: pd.DataFrame, cols: Sequence[str]) -> list[str]:
    """Markdown rows of the encoder table's ``cols`` (headed by the scene alone: ``R2 tree-v2`` → ``tree-v2``)."""
    heads = [c.split(" ", 1)[1] if c.startswith(("R2 ", "MMD ")) else c for c in cols]
    lines = ["", "| method | budget | seeds | " + " | ".join(heads) + " |", "|---|---|---|" + "---|" * len(cols)]
    for row in enc.to_dict("records"):
        vals = [f"{row[c]:.3g}" if isinstance(row[c], float) and math.isfinite(row[c]) else "" for c in cols]
        lines.append(f"| {row['method']} | ×{row['scale']:g} | {int(row['seeds'])} | " + " | ".join(vals) + " |")
    return lines


def verdicts_wide(long: pd.DataFrame) -> pd.DataFrame:
    """One row per hypothesis, one column per ``<axis> ×<scale>`` (its verdict and estimate; empty where that point
    has no data), and per ladder ``stable <axis>``: ``yes`` when every budget that judged the row (holds, reversed
    or undecided; not ``one seed``) gave the same verdict, ``no`` when they differ, empty when fewer than two did."""
    if long.empty:
        return pd.DataFrame()
    long = long.assign(point=[f"{a} ×{s:g}" for a, s in zip(long["axis"], long["scale"])])
    long["shown"] = [f"{v} ({e:+.1f})" if math.isfinite(e) else v for v, e in zip(long["verdict"], long["estimate"])]
    wide = long.pivot_table(index=["claim", "hypothesis"], columns="point", values="shown", aggfunc="first", sort=False)
    for axis in LADDERS:
        judged = long[(long["axis"] == axis) & (long["verdict"] != "one seed")]
        same = judged.groupby(["claim", "hypothesis"], sort=False)["verdict"].agg(
            lambda v: "" if len(v) < 2 else ("yes" if v.nunique() == 1 else "no")
        )
        wide[f"stable {axis}"] = same
    return wide.fillna("").reset_index()


def record_encoder_reports(cfg: Config, grids: Sequence[str] = (BASE_GRID, "ladder-pretrain")) -> tuple[list, list]:
    """Write the encoder report of every recorded pretraining run of ``grids`` that lacks one, from its encoder in
    ``<run_root>/runs/pretrain/`` (found by the run's key), and record it beside the run's record.

    Returns ``(written, missing)``: the record folders given a report, and those whose encoder is not on this
    machine (each with the run folder looked for), or is there but is not the file the record's run wrote (another
    digest: pretrained again). Pilot frames are flown once, on the first report written."""
    written, missing, samples = [], [], None
    for grid in grids:
        data = GridData(grid_data_dir(cfg, grid))
        for rec in sorted(data.root.glob("*/seed*/pretrain/run.json")):
            folder = rec.parent
            if (folder / REPORT).is_file():
                continue
            ident = read_identity(folder) or {}
            run_dir = cfg.run_root / "runs" / "pretrain" / f"{ident['method']}-{ident['key']}" / f"seed{ident['seed']}"
            if not (run_dir / "encoder.pt").is_file():
                missing.append((folder, run_dir))
                continue
            if samples is None:
                samples = setting_samples(cfg, settings=suite_settings(cfg))
            report = write_encoder_report(cfg, run_dir, samples)
            got = (read_report(run_dir) or {}).get("encoder_digest")
            if ident.get("artifact_digest") and got != ident["artifact_digest"]:
                # Another encoder under the same key (pretrained again, not bit for bit): not this record's.
                missing.append((folder, run_dir))
                continue
            atomic_write_bytes(folder / REPORT, report.read_bytes())
            written.append(folder)
    return written, missing


@dataclass
class LadderResult:
    """What :func:`ladder_stage` wrote and the tables it wrote them from."""

    table: pd.DataFrame
    encoders: pd.DataFrame
    verdicts: pd.DataFrame
    effects: pd.DataFrame = field(default_factory=pd.DataFrame)
    cost: pd.DataFrame = field(default_factory=pd.DataFrame)
    rest: pd.DataFrame = field(default_factory=pd.DataFrame)
    paths: dict[str, Path] = field(default_factory=dict)
    seconds: float = 0.0

    def __repr__(self) -> str:
        return f"LadderResult({len(self.table)} cells, {len(self.verdicts)} verdicts, {len(self.paths)} files)"


def ladder_stage(
    cfg: Config, *, seeds: Sequence[int] = LADDER_SEEDS, reports: bool = False, reps: int = DEFAULT_REPS
) -> LadderResult:
    """CLI stage ``ladder``: the module's tables and figures from the grids' records (FileNotFoundError when no
    point has recorded episodes). ``reports``: first write the encoder reports the records lack
    (:func:`record_encoder_reports`, from this machine's encoders)."""
    t0 = time.perf_counter()
    if reports:
        written, missing = record_encoder_reports(cfg)
        for folder, run_dir in missing:
            print(f"ladder: no encoder for {folder} on this machine (looked in {run_dir}); its report is left out")
    episodes = ladder_episodes(cfg, seeds)
    if episodes.empty:
        raise FileNotFoundError(
            f"no ladder point has recorded episodes under {grid_data_dir(cfg, BASE_GRID).parent}; run python -m omcrl "
            f"sweep table1|ladder-pretrain|ladder-rl --preset {cfg.preset} --to-reference first"
        )
    table = ladder_table(episodes, reps)
    reference = suite_settings(cfg)[0][0]
    encoders = encoder_table(encoder_rows(cfg, seeds), reference)
    long = verdicts_by_budget(cfg, episodes, seeds, reps)
    wide = verdicts_wide(long)
    effects = scale_effects(episodes, reps)
    out = cfg.run_root / "tables"
    out.mkdir(parents=True, exist_ok=True)
    cols = ["axis", "method", "scale", "scene", "seeds", *(c for m in SHOWN for c in (m, f"{m}_lo", f"{m}_hi"))]
    shown = table[[c for c in cols if c in table]]
    paths: dict[str, Path] = {}
    for name, df, md in (
        ("ladder_table", shown, to_markdown(shown.round(1).set_index("axis"), "axis")),
        ("ladder_encoders", encoders, to_markdown(encoders.round(3).set_index("method"), "method")),
        ("ladder_verdicts", long, to_markdown(wide.set_index("claim"), "claim") if len(wide) else "(none)\n"),
        ("ladder_scale", effects, "\n".join(_effects_md(effects)) + "\n"),
    ):
        paths[f"{name}.csv"], paths[f"{name}.md"] = out / f"{name}.csv", out / f"{name}.md"
        atomic_write_text(paths[f"{name}.csv"], df.to_csv(index=False))
        atomic_write_text(paths[f"{name}.md"], md)
    points = ladder_points()
    scales = {a: sorted(points.loc[points["axis"] == a, "scale"].unique()) for a in LADDERS}
    keys = ["axis", "method", "scale", "scene", "train_seed"]
    per_seed = episodes[keys].assign(SR=episode_values(episodes)["SR"]).groupby(keys, as_index=False)["SR"].mean()
    for scene in dict.fromkeys(table["scene"]):
        fig = plot_ladder(table, scene, budgets(cfg), scales, per_seed=per_seed)
        paths[f"ladder_{scene}"] = save_figure(fig, cfg.run_root / "figures", f"ladder_{scene}")
        plt.close(fig)
    cost = cost_table(cfg)
    return LadderResult(table, encoders, long, effects, cost, rest_cost(cfg, cost, seeds), paths,
                        time.perf_counter() - t0)  # fmt: skip


def _effects_md(effects: pd.DataFrame) -> list[str]:
    """Markdown lines of :func:`scale_effects`: one row per ladder, method and point, one cell per scene."""
    if effects.empty:
        return ["(no point above ×1 recorded yet)"]
    scenes = list(dict.fromkeys(effects["scene"]))
    lines = [
        "| ladder | method | budget | seeds | " + " | ".join(scenes) + " |",
        "|---|---|---|---|" + "---|" * len(scenes),
    ]
    mark = {"up": " ↑", "down": " ↓"}

    def change(r: pd.Series) -> str:
        if not math.isfinite(r["diff"]):
            return ""
        return f"{r['diff']:+.0f} [{r['lo']:+.0f}, {r['hi']:+.0f}]{mark.get(r['verdict'], '')}"

    for (axis, method, scale), g in effects.groupby(["axis", "method", "scale"], sort=False):
        lines.append(f"| {axis} | {method} | ×{scale:g} | {int(g['seeds'].max())} | {scene_cells(g, scenes, change)} |")
    n = effects["verdict"].value_counts()
    lines += [
        "",
        f"{int(n.get('up', 0))} up, {int(n.get('down', 0))} down, {int(n.get('no change resolved', 0))} with no change "
        f"resolved" + (f", {int(n.get('one seed', 0))} of one seed (not judged)" if n.get("one seed", 0) else "") + ".",
    ]
    return lines


def _sum_of_all(hours: pd.Series) -> float:
    """The sum, or NaN when any kind of job lacks hours (a total that leaves one out would read as complete)."""
    return hours.sum(min_count=len(hours))


def _cost_totals(cost: pd.DataFrame) -> pd.DataFrame:
    """One row per ladder, kind ``all``: the sums of :func:`cost_table`'s rows (planned only where every kind has a
    plan rate)."""
    out = cost.groupby("ladder", sort=False).agg(
        jobs=("jobs", "sum"), planned_h=("planned_h", _sum_of_all), measured_h=("measured_h", "sum")
    )
    return out.reset_index().assign(rate_key="all", work=0)


def _each_with_total(rows: pd.DataFrame, totals: pd.DataFrame) -> list:
    """The rows of each ladder in turn, each ladder's followed by its total (both with a ``ladder`` column)."""
    return [r for axis in LADDERS for df in (rows, totals) for r in df[df["ladder"] == axis].itertuples()]


def _rest_md(rest: pd.DataFrame) -> list[str]:
    """Markdown lines of :func:`rest_cost`: a row per ladder and kind, and per ladder its total."""
    lines = [
        "What the rest would cost: each ladder's jobs that no record holds yet (Table I's runs left out; a job half "
        "run counts whole) at the plan's rates, and those hours × the measured / planned ratio of the jobs of that "
        "kind that ran (of every job that ran where none of that kind has): the estimate for this machine.",
        "",
        "| ladder | kind | jobs | work | planned h | measured / planned | estimated h |",
        "|---|---|---|---|---|---|---|",
    ]
    totals = rest.groupby("ladder", sort=False).agg(
        jobs=("jobs", "sum"), planned_h=("planned_h", _sum_of_all), estimate_h=("estimate_h", _sum_of_all)
    )
    totals = totals.reset_index().assign(rate_key="all", work=0, ratio=totals["estimate_h"].to_numpy()
                                         / totals["planned_h"].to_numpy())  # fmt: skip
    for r in _each_with_total(rest, totals):
        work = "–" if r.rate_key == "all" else f"{r.work:,}"  # (the kinds' units differ)
        lines.append(f"| {r.ladder} | {r.rate_key} | {r.jobs} | {work} | {r.planned_h:.2f} | {r.ratio:.2f} | "
                     f"{r.estimate_h:.2f} |".replace("nan", "–"))  # fmt: skip
    return lines


def _stability_line(wide: pd.DataFrame) -> str:
    """One sentence per ladder: of the hypotheses two or more of its budgets judged, how many keep their verdict,
    and how many of those that change go between holds and reversed (a flip) rather than to or from undecided."""
    out = []
    for axis in LADDERS:
        col = f"stable {axis}"
        if col not in wide:
            continue
        judged = wide[wide[col].isin(["yes", "no"])]
        if judged.empty:
            continue
        points = [c for c in wide.columns if c.startswith(f"{axis} ×")]
        moved = judged[judged[col] == "no"]
        flips = sum(
            {"holds", "reversed"} <= {str(x).split(" ")[0] for x in r[points] if x} for _, r in moved.iterrows()
        )
        kept = len(judged) - len(moved)
        out.append(
            f"{axis} ladder: of {len(judged)} hypotheses judged at two or more budgets, {kept} keep their verdict and "
            f"{len(moved)} change ({flips} between holds and reversed, the rest to or from undecided)."
        )
    return " ".join(out)


def ladder_markdown(res: LadderResult, figures: str | None = None, seeds: Sequence[int] = LADDER_SEEDS) -> str:
    """The ladder's Markdown for docs/results.md (``templates/ladder.md.j2``): which points have which seeds, SR per
    point and scene (mean [95 % CI], seeds × layouts), the encoders per pretraining point, the verdicts' tally per
    point and every hypothesis that some point decides or whose verdict moves; with ``figures`` (a folder relative
    to the page), the per-scene figures :func:`ladder_stage` wrote, as images under that folder."""
    points = ladder_points()
    t = res.table
    recorded = []
    for axis in LADDERS:
        p = points[points["axis"] == axis]
        scales = sorted(p["scale"].unique())
        rows = []
        for method in dict.fromkeys(p["method"]):
            cells = []
            for s in scales:
                got = t[(t["axis"] == axis) & (t["method"] == method) & (t["scale"] == s)]
                cells.append(f"{int(got['seeds'].max())}/{len(seeds)}" if len(got) else f"0/{len(seeds)}")
            rows.append((method, cells))
        recorded.append((axis, [f"×{s:g}" for s in scales], rows))
    scenes = list(dict.fromkeys(t["scene"]))
    sr = [
        f"| {axis} | {method} | ×{scale:g} | {int(g['seeds'].max())} | "
        + scene_cells(g, scenes, lambda r: ci_text(r["SR"], r["SR_lo"], r["SR_hi"]))
        + " |"
        for (axis, method, scale), g in t.groupby(["axis", "method", "scale"], sort=False)
    ]
    probe, shift = [], []
    if len(res.encoders):
        enc = res.encoders
        # Two tables, not one of thirteen columns: each fits a page's width, its columns named by scene alone.
        probe = _encoder_rows(enc, ["top1", *(c for c in enc.columns if c.startswith("R2 "))])
        mmd = [c for c in enc.columns if c.startswith("MMD ")]
        shift = _encoder_rows(enc, mmd) if mmd else []
    v = res.verdicts
    tallies, stability, shown, others, hypotheses = [], None, 0, 0, ""
    if len(v):
        for (axis, scale), g in v.groupby(["axis", "scale"], sort=False):
            n = g["verdict"].value_counts()
            tally = ", ".join(f"{int(n.get(k, 0))} {k}" for k in ("holds", "reversed", "undecided"))
            one = int(n.get("one seed", 0))
            tallies.append(f"{axis} ×{scale:g}: {len(g)} hypotheses, {tally}" + (f", {one} one seed" if one else ""))
        wide = verdicts_wide(v)
        stability = _stability_line(wide)
        point_cols = [c for c in wide.columns if " ×" in c]
        decided = wide[point_cols].apply(lambda col: col.str.startswith(("holds", "reversed"))).any(axis=1)
        moved = (wide[[c for c in wide.columns if c.startswith("stable ")]] == "no").any(axis=1)
        rows = wide[decided | moved]
        shown, others = len(rows), len(wide) - len(rows)
        hypotheses = to_markdown(rows.set_index("claim"), "claim").strip() if len(rows) else ""
    cost = []
    if len(res.cost):
        c = res.cost
        for r in _each_with_total(c, _cost_totals(c)):
            ratio = r.measured_h / r.planned_h if r.planned_h > 0 else math.nan
            work = "–" if r.rate_key == "all" else f"{r.work:,}"  # (the kinds' units differ)
            cost.append(f"| {r.ladder} | {r.rate_key} | {r.jobs} | {work} | {r.planned_h:.2f} | "
                        f"{r.measured_h:.2f} | {ratio:.2f} |".replace("nan", "–"))  # fmt: skip
    return render(
        "ladder.md.j2",
        seeds=list(seeds),
        recorded=recorded,
        scenes=scenes,
        sr=sr,
        probe=probe,
        shift=shift,
        points=tallies,
        stability=stability,
        shown=shown,
        others=others,
        hypotheses=hypotheses,
        effects=_effects_md(res.effects) if len(res.effects) else [],
        cost=cost,
        rest=_rest_md(res.rest) if len(res.rest) else [],
        figures=figures,
    )
