"""Table I: every method of the comparison × four scenes × training seeds, with CIs and the paper beside it.

``evaluate_grid(cfg)`` evaluates each finished learned run (every method at every seed of ``cfg.seeds``) and
each planner in every scene on the same evaluation episodes (cached per checkpoint, see
:func:`omcrl.eval.evaluate_methods`). ``write_table1`` aggregates with :func:`omcrl.eval.stats.aggregate`
(mean and 95% CI with training seeds and layouts as crossed factors) and writes, under ``<run_root>/tables/``::

    table1.csv            long form: method, scene, metric, mean, lo, hi, seeds, episodes
    table1.md, .tex       the paper's layout (methods × scenes × NE OS SR SPL CR TTS), mean ± CI half-width,
                          best non-privileged method in bold, best learned method in italics (LaTeX:
                          underlined), "–" for TTS without a success
    table1_vs_paper.csv/.md   the paper's reported values beside ours (paper_table1.csv in this package)
    table1_significance.csv   ours vs every other method, SR difference per scene with CI and p-value
    table1_episodes.csv   every evaluated episode
"""

from __future__ import annotations

import math
import textwrap
import time
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from omcrl import planners
from omcrl.config import Config
from omcrl.eval.metrics import GLOSSARY, METRICS
from omcrl.eval.runner import EvalPool
from omcrl.eval.stage import evaluate_methods
from omcrl.eval.stats import aggregate, compare_sr
from omcrl.eval.verdicts import write_verdicts
from omcrl.rl.methods import METHODS, TABLE1_METHODS, final_policy_path, get_method, training_runs
from omcrl.scenes import DEFAULT_SUITE, scene_id, scene_label, scene_spec, suite_of
from omcrl.utils.io import atomic_write_text
from omcrl.utils.progress import track

PAPER_TABLE1 = Path(__file__).with_name("paper_table1.csv")
# Direction of "better" per metric (for bold).
# Read from the one glossary (omcrl.eval.metrics.GLOSSARY): which way each metric is better.
HIGHER_IS_BETTER = {m: GLOSSARY[m][3] == "higher" for m in METRICS}


@dataclass(repr=False)
class Table1Result:
    """Episodes, aggregates and significance of a Table I evaluation, and the files written."""

    episodes: pd.DataFrame
    table: pd.DataFrame
    significance: pd.DataFrame
    missing: list[str] = field(default_factory=list)
    paths: dict[str, Path] = field(default_factory=dict)
    wall_time_s: float = 0.0
    verdicts: pd.DataFrame = field(default_factory=pd.DataFrame)  # the claim ledger's (omcrl.eval.verdicts)

    def __repr__(self) -> str:
        lines = [f"Table I: {len(self.episodes)} episodes in {self.wall_time_s:.0f} s"]
        if self.missing:
            lines.append("not evaluated (no finished run): " + ", ".join(self.missing))
        lines += [f"{k}: {v}" for k, v in self.paths.items()]
        lines += list(self.significance.get("statement", []))
        if len(self.verdicts):
            n = self.verdicts["verdict"].value_counts()
            lines.append("claim ledger: " + ", ".join(f"{int(n[k])} {k}" for k in n.index))
        return "\n".join(lines)


def method_sources(cfg: Config, methods: Sequence[str], seeds: Sequence[int]) -> tuple[dict, list[str]]:
    """``{(method, seed): final.pt or planner name}`` for every finished run, and the list of missing ones (a
    control's absent runs are not listed: the notebooks do not train them).

    Planners are deterministic and untrained: they appear once, under the first seed.
    """

    found, missing = {}, []
    for m in methods:
        spec = get_method(m)
        if not spec.learned:
            found[(m, seeds[0])] = m
            continue
        for s in seeds:
            p = final_policy_path(cfg.with_seed(s), m)
            if p is None:
                if not spec.control:  # a control is flown where it was trained (the grid), not asked for
                    missing.append(f"{m}/seed{s}")
            else:
                found[(m, s)] = p
    return found, missing


def evaluate_grid(
    cfg: Config,
    methods: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    scenes: Sequence[str] | None = None,
    episodes: int | None = None,
    *,
    progress: bool = False,
) -> tuple[pd.DataFrame, list[str]]:
    """Evaluate every finished run of ``methods`` (default: all) at ``seeds`` (default ``cfg.seeds``).

    Returns the episodes (one row each; ``method``, ``train_seed``, ``scene`` ...) and the runs not found.
    """

    methods = list(methods or TABLE1_METHODS)
    seeds = list(seeds if seeds is not None else cfg.seeds)
    sources, missing = method_sources(cfg, methods, seeds)
    frames = []
    # One set of workers for the whole grid, started when the first uncached evaluation needs them.
    with EvalPool(cfg.eval.workers) if cfg.eval.workers != 1 else nullcontext() as pool:
        for (m, s), src in track(list(sources.items()), desc="evaluate", unit="run", enabled=progress):
            frames.append(evaluate_methods(cfg.with_seed(s), {m: src}, scenes, episodes, pool=pool))
    df = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    return df, missing


# Columns of ``tables/table1.csv`` (:func:`write_table1`), one row per method, scene and metric.
TABLE1_COLUMNS = ("method", "scene", "metric", "mean", "lo", "hi", "seeds", "episodes")


def read_table1_csv(path: str | Path) -> pd.DataFrame:
    """Table I's long rows as :func:`write_table1` writes them; ValueError naming the file when it is not that."""
    df = pd.read_csv(path)
    missing = sorted(set(TABLE1_COLUMNS) - set(df.columns))
    if missing:
        raise ValueError(
            f"{path}: not Table I's long form (columns {missing} missing); it is written by `python -m omcrl tables` "
            "(notebook 07)"
        )
    return df


def paper_table1() -> pd.DataFrame:
    """The paper's Table I values (long: method, scene, NE OS SR SPL CR TTS), method names as in the kit."""
    return pd.read_csv(PAPER_TABLE1, comment="#")


def signed_points(x: float) -> str:
    """A difference in whole points with its sign and a minus sign (``+5``, ``−3``; ``0`` without one)."""
    text = f"{x:+.0f}"
    return "0" if text in ("+0", "-0") else text.replace("-", "−")


def ci_text(mean: float, lo: float, hi: float, digits: int = 0) -> str:
    """``mean [lo, hi]`` at ``digits`` decimals; the interval left out where it is not finite or, at that precision,
    collapses onto the mean (a planner flown once, a cell at 100 %); ``–`` for a mean that is not finite."""

    def num(x: float) -> str:
        return f"{x:.{digits}f}"

    if not math.isfinite(mean):
        return "–"
    text = num(mean)
    if math.isfinite(lo) and math.isfinite(hi) and (num(lo), num(hi)) != (text, text):
        text += f" [{num(lo)}, {num(hi)}]"
    return text


def _fmt(mean: float, lo: float, hi: float, metric: str) -> str:
    if not math.isfinite(mean):
        return "–"
    d = 2 if metric in ("NE", "SPL") else (0 if metric == "TTS" else 1)
    half = (hi - lo) / 2 if math.isfinite(lo) and math.isfinite(hi) else math.nan
    return f"{mean:.{d}f}" + (f" ± {half:.{d}f}" if math.isfinite(half) else "")


def _best(table: pd.DataFrame, scene: str, metric: str, eligible: Sequence[str]) -> set[str]:
    vals = {m: table.loc[(m, scene), metric] for m in eligible if (m, scene) in table.index}
    vals = {m: v for m, v in vals.items() if math.isfinite(v)}
    if not vals:
        return set()
    target = (max if HIGHER_IS_BETTER[metric] else min)(vals.values())
    return {m for m, v in vals.items() if np.isclose(v, target)}


def table1_frames(table: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(long, wide) views: long rows method/scene/metric/mean/lo/hi; wide cells 'mean ± half' with bold marks.

    Bold (``**x**``) marks the best value per scene and metric among methods that are not privileged (the
    oracle and the privileged Hybrid APF are upper references, not competitors). Italics (``_x_``) mark the best
    learned, non-privileged method: a planner that is not privileged (the perceptive Hybrid APF) takes most bolds,
    and without a second mark the best learned policy would not stand out.
    """

    methods = list(dict.fromkeys(table.index.get_level_values("method")))
    scenes = list(dict.fromkeys(table.index.get_level_values("scene")))
    eligible = [m for m in methods if not (m in METHODS and METHODS[m].privileged)]
    learned = [m for m in eligible if m in METHODS and METHODS[m].learned]
    long_rows, wide = [], pd.DataFrame(index=methods, columns=pd.MultiIndex.from_product([scenes, METRICS]))
    for (m, sc), row in table.iterrows():
        for metric in METRICS:
            long_rows.append(
                {
                    "method": m,
                    "scene": sc,
                    "metric": metric,
                    "mean": row[metric],
                    "lo": row[f"{metric}_lo"],
                    "hi": row[f"{metric}_hi"],
                    "seeds": int(row["seeds"]),
                    "episodes": int(row["episodes"]),
                }
            )
    for sc in scenes:
        for metric in METRICS:
            best = _best(table, sc, metric, eligible)
            best_learned = _best(table, sc, metric, learned)
            for m in methods:
                if (m, sc) not in table.index:
                    wide.loc[m, (sc, metric)] = ""
                    continue
                r = table.loc[(m, sc)]
                cell = _fmt(r[metric], r[f"{metric}_lo"], r[f"{metric}_hi"], metric)
                if cell != "–":
                    cell = f"_{cell}_" if m in best_learned else cell
                    cell = f"**{cell}**" if m in best else cell
                wide.loc[m, (sc, metric)] = cell
    return pd.DataFrame(long_rows), wide


def _markdown(wide: pd.DataFrame, labels: dict[str, str]) -> str:
    scenes = list(dict.fromkeys(wide.columns.get_level_values(0)))
    out = []
    arrows = {m: ("↑" if HIGHER_IS_BETTER[m] else "↓") for m in METRICS}
    for sc in scenes:  # one block per scene keeps the table readable (6 columns instead of 24)
        out.append(f"**{scene_label(sc)}**\n")
        out.append("| method | " + " | ".join(f"{m}{arrows[m]}" for m in METRICS) + " |")
        out.append("|---|" + "---|" * len(METRICS))
        for m in wide.index:
            out.append(f"| {labels.get(m, m)} | " + " | ".join(str(wide.loc[m, (sc, x)]) for x in METRICS) + " |")
        out.append("")
    return "\n".join(out)


def _latex(wide: pd.DataFrame, labels: dict[str, str]) -> str:
    scenes = list(dict.fromkeys(wide.columns.get_level_values(0)))
    n = len(METRICS)
    head = " & ".join(f"\\multicolumn{{{n}}}{{c}}{{{scene_label(sc)}}}" for sc in scenes)
    rules = " ".join(f"\\cmidrule(lr){{{2 + i * n}-{1 + (i + 1) * n}}}" for i in range(len(scenes)))
    arrows = {m: ("$\\uparrow$" if HIGHER_IS_BETTER[m] else "$\\downarrow$") for m in METRICS}
    sub = " & ".join(f"{m}{arrows[m]}" for _ in scenes for m in METRICS)

    def cell(v: str) -> str:
        v = str(v).replace("±", "$\\pm$").replace("–", "--")
        bold = v.startswith("**")
        v = v[2:-2] if bold else v
        v = f"\\underline{{{v[1:-1]}}}" if v.startswith("_") else v
        return f"\\textbf{{{v}}}" if bold else v

    lines = [
        "\\begin{tabular}{l" + "c" * (n * len(scenes)) + "}",
        "\\toprule",
        f"Method & {head} \\\\",
        rules,
        f" & {sub} \\\\",
        "\\midrule",
    ]
    for m in wide.index:
        vals = " & ".join(cell(wide.loc[m, (sc, x)]) for sc in scenes for x in METRICS)
        lines.append(f"{labels.get(m, m).replace('_', ' ')} & {vals} \\\\")
    lines += ["\\bottomrule", "\\end{tabular}", ""]
    return "\n".join(lines)


def vs_paper(table: pd.DataFrame, paper: pd.DataFrame | None = None) -> pd.DataFrame:
    """Long table: method, scene, metric, paper (reported), kit (mean), kit_lo, kit_hi — where the paper has a value.

    ``scene`` is the kit's scene that stands for the paper's (:attr:`~omcrl.scenes.SceneSpec.paper_scene`:
    ``furniture-v1`` for the paper's furniture); stress tests have no paper value. ``paper``: the paper's values in
    :func:`paper_table1`'s long form (``method, scene, <metric>...``; default: Table I's)."""
    paper = (paper_table1() if paper is None else paper).set_index(["method", "scene"])
    # The kit's scene that stands for each of the paper's (furniture-v1 for "furniture"; a stress test for none).
    kit_scene = {}
    for s in dict.fromkeys(table.index.get_level_values("scene")):
        kit_scene.setdefault(scene_spec(s).paper_scene, s)
    rows = []
    for (m, psc), prow in paper.iterrows():
        sc = kit_scene.get(psc, scene_id(psc))
        for metric in METRICS:
            k = table.loc[(m, sc)] if (m, sc) in table.index else None
            rows.append(
                {
                    "method": m,
                    "scene": sc,
                    "metric": metric,
                    "paper": prow[metric],
                    "kit": None if k is None else k[metric],
                    "kit_lo": None if k is None else k[f"{metric}_lo"],
                    "kit_hi": None if k is None else k[f"{metric}_hi"],
                }
            )
    return pd.DataFrame(rows)


def vs_paper_markdown(vp: pd.DataFrame, source: str, labels: dict[str, str] | None = None) -> str:
    """:func:`vs_paper`'s rows as a Markdown table, the paper's value beside the kit's mean [95 % CI]; ``source``
    names the paper's table in the caption, ``labels`` the rows' display names."""
    labels = labels or {}
    md = ["| method | scene | metric | paper | kit (mean [95% CI]) |", "|---|---|---|---|---|"]
    for r in vp.itertuples():
        if r.kit is None:
            kit = "not evaluated"
        elif pd.isna(r.kit):
            kit = "– (no success)" if r.metric == "TTS" else "–"
        else:
            kit = f"{r.kit:.2f} [{r.kit_lo:.2f}, {r.kit_hi:.2f}]"
        paper = "–" if pd.isna(r.paper) else f"{r.paper:g}"
        md.append(f"| {labels.get(r.method, r.method)} | {r.scene} | {r.metric} | {paper} | {kit} |")
    return f"Paper: {source}. Kit: this run.\n\n" + "\n".join(md) + "\n"


def write_table1(
    episodes: pd.DataFrame,
    directory: str | Path,
    *,
    name: str = "table1",
    reference: str = "ours",
    os_threshold: float = 0.5,
    reps: int = 2000,
) -> tuple[pd.DataFrame, pd.DataFrame, dict[str, Path]]:
    """Aggregate ``episodes`` and write Table I's files; returns (aggregate table, significance, paths)."""

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    table = aggregate(episodes, ("method", "scene"), os_threshold=os_threshold, reps=reps)
    long, wide = table1_frames(table)
    labels = {**planners.LABELS, **{m: s.label for m, s in METHODS.items()}}
    seeds = int(table["seeds"].max()) if len(table) else 0
    n = int(episodes.groupby(["method", "scene", "train_seed"]).size().min()) if len(episodes) else 0
    note = (
        f"Mean ± half-width of the 95% CI (seeds × layouts crossed, omcrl.eval.stats: {seeds} training seed(s), "
        f"{n} evaluation layouts per seed and scene). NE m, OS/SR/CR %, SPL 0-1, TTS steps over successful "
        "episodes (– none). "
        "Bold: best non-privileged method (the oracle and the privileged Hybrid APF are references). "
        "Italics: best learned method."
    )
    # Wrapped so that the docs that embed this file keep their lines within 120 characters.
    note = textwrap.fill(note, 120, break_long_words=False, break_on_hyphens=False) + "\n\n"
    sig = compare_sr(episodes, reference, reps=reps) if reference in set(episodes["method"]) else pd.DataFrame()
    vp = vs_paper(table)
    paths = {
        "csv": d / f"{name}.csv",
        "md": d / f"{name}.md",
        "tex": d / f"{name}.tex",
        "vs_paper_csv": d / f"{name}_vs_paper.csv",
        "vs_paper_md": d / f"{name}_vs_paper.md",
        "significance": d / f"{name}_significance.csv",
        "episodes": d / f"{name}_episodes.csv",
    }
    atomic_write_text(paths["csv"], long.to_csv(index=False))
    atomic_write_text(paths["md"], note + _markdown(wide, labels))
    atomic_write_text(paths["tex"], _latex(wide, labels))
    atomic_write_text(paths["vs_paper_csv"], vp.to_csv(index=False))
    atomic_write_text(
        paths["vs_paper_md"],
        vs_paper_markdown(vp, "Table I of the OMC-RL paper (200 episodes per scene, Unity scenes)", labels),
    )
    atomic_write_text(paths["significance"], sig.to_csv(index=False))
    atomic_write_text(paths["episodes"], episodes.drop(columns=["trajectory"], errors="ignore").to_csv(index=False))
    return table, sig, paths


def tables_stage(cfg: Config, *, progress: bool = True) -> Table1Result:
    """CLI stage ``tables``: evaluate every finished run of every method at ``cfg.seeds`` and write Table I.

    Runs that do not exist yet are listed (``missing``), not trained; raise FileNotFoundError when no learned
    run exists at all.
    """
    t0 = time.perf_counter()
    episodes, missing = evaluate_grid(cfg, progress=progress)

    learned = [m for m in TABLE1_METHODS if METHODS[m].learned]
    if episodes.empty or not set(episodes["method"]) & set(learned):
        raise FileNotFoundError(
            f"no finished training run under {cfg.run_root / 'runs'} for seeds {cfg.seeds}; train first "
            f"(python -m omcrl train --method <name> --preset {cfg.preset}, or notebooks 03-05)"
        )
    table, sig, paths = write_table1(episodes, cfg.run_root / "tables", os_threshold=cfg.eval.success_threshold_os)
    # The ledger's scenes are resolved in the suite whose box cfg trains in (v2 for a box of no suite).
    suite = suite_of(cfg.env.scene) or DEFAULT_SUITE
    verdicts, vpaths = write_verdicts(episodes, training_runs(cfg), cfg.run_root / "tables", suite)
    return Table1Result(episodes, table, sig, missing, paths | vpaths, time.perf_counter() - t0, verdicts)
