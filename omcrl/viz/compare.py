"""Figures of the comparison (notebook 07): learning curves over seeds (Fig. 5), trajectories of every method
(Fig. 6) and sample efficiency (env steps to a training success rate).

Curves read the runs' tidy ``metrics.csv`` (:func:`omcrl.runs.metric_series`); x is env steps over all envs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from omcrl.eval.verdicts import verdict_counts
from omcrl.rl.methods import METHODS
from omcrl.runs import metric_series
from omcrl.scenes import PAPER_SUITE
from omcrl.viz import method_color, steps_axis
from omcrl.viz.pretrain import smooth
from omcrl.viz.rl import TRAJECTORY_KEY, plot_trajectories

CURVE_METRICS = (("episodic_return", "episodic reward"), ("success_rate", "training success rate"))


def curve_window(total_steps: int, buffer_size: int) -> int:
    """Fig. 5's moving-average window in updates: about 15 windows over a run of ``total_steps`` env steps
    collected ``buffer_size`` at a time."""
    return max(1, total_steps // (buffer_size * 15))


def _labels() -> dict[str, str]:

    return {m: s.label for m, s in METHODS.items()}


def seed_curves(
    runs: Mapping[int, str | Path], metric: str, window: int = 5, points: int = 100
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean over seeds of a smoothed training metric on a common step grid, with a 95% t-interval.

    Parameters
    ----------
    runs : ``{seed: run folder or metrics.csv}``.
    metric : a metric of the runs' ``metrics.csv`` (e.g. ``success_rate``).
    window : trailing moving average over updates, applied per seed before averaging.

    Returns
    -------
    steps (P,), mean (P,), lo (P,), hi (P,); lo = hi = mean with one seed.
    """
    from scipy import stats

    series = []
    for path in runs.values():
        m = metric_series(path)
        if metric in m and len(m[metric][0]):
            series.append((m[metric][0], smooth(m[metric][1], window)))
    if not series:
        return (np.zeros(0),) * 4
    end = min(s[0][-1] for s in series)
    grid = np.linspace(min(s[0][0] for s in series), end, points)
    ys = np.stack([np.interp(grid, x, y) for x, y in series])
    mean = ys.mean(0)
    if len(ys) < 2:
        return grid, mean, mean, mean
    half = stats.t.ppf(0.975, len(ys) - 1) * ys.std(0, ddof=1) / math.sqrt(len(ys))
    return grid, mean, mean - half, mean + half


def plot_learning_curves(
    runs: Mapping[str, Mapping[int, str | Path]],
    metrics: Sequence[tuple[str, str]] = CURVE_METRICS,
    window: int = 5,
) -> plt.Figure:
    """Fig. 5: one panel per metric, one line per method (mean over seeds, shaded 95% CI across seeds).

    ``runs`` is ``{method: {seed: run folder}}`` (:func:`omcrl.rl.methods.training_runs`). The oracle is
    drawn dashed as the upper bound.
    """
    labels = _labels()
    # The legend sits right of the last panel (1.9 in more width): inside it, eleven methods covered curves.
    fig, axes = plt.subplots(1, len(metrics), figsize=(5.2 * len(metrics) + 1.9, 3.6), squeeze=False)
    for ax, (metric, title) in zip(axes[0], metrics):
        for i, (method, seeds) in enumerate(runs.items()):
            x, y, lo, hi = seed_curves(seeds, metric, window)
            if not len(x):
                continue
            style = "--" if method == "oracle" else "-"
            n = len(seeds)
            # The method's colour in every figure; lines that are not methods (a sweep's variants) take the cycle.
            color = method_color(method) if method in METHODS or method in labels.values() else f"C{i}"
            ax.plot(x, y, style, color=color, label=f"{labels.get(method, method)} ({n} seed{'s' if n > 1 else ''})")
            ax.fill_between(x, lo, hi, color=color, alpha=0.18, lw=0)
        ax.set(xlabel="env steps", title=title)
        steps_axis(ax.xaxis)
        if metric == "success_rate":
            ax.set(ylim=(-0.02, 1.02), ylabel="fraction of episodes")
        else:
            ax.set(ylabel="return per episode")
    axes[0][-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    return fig


def steps_to_success(path: str | Path, threshold: float = 0.8, window: int = 5) -> float:
    """First env step at which the moving-average training success rate reaches ``threshold`` (NaN: never)."""
    m = metric_series(path)
    if "success_rate" not in m:
        return math.nan
    x, y = m["success_rate"]
    hit = np.flatnonzero(smooth(y, window) >= threshold)
    return float(x[hit[0]]) if len(hit) else math.nan


def sample_efficiency(
    runs: Mapping[str, Mapping[int, str | Path]], threshold: float = 0.8, window: int = 5
) -> pd.DataFrame:
    """Per method and seed: env steps to reach ``threshold`` training success in box (NaN when never)."""
    rows = [
        {"method": m, "train_seed": s, "steps": steps_to_success(p, threshold, window)}
        for m, seeds in runs.items()
        for s, p in seeds.items()
    ]
    return pd.DataFrame(rows, columns=["method", "train_seed", "steps"])


def plot_sample_efficiency(eff: pd.DataFrame, budget: float, threshold: float = 0.8) -> plt.Figure:
    """Bars: mean env steps to ``threshold`` training success per method (dots: seeds; hatched: some seed
    never reached it within ``budget`` env steps, drawn at the budget)."""
    labels = _labels()
    methods = list(dict.fromkeys(eff["method"]))
    fig, ax = plt.subplots(figsize=(1.0 + 0.9 * len(methods), 3.4))
    for i, m in enumerate(methods):
        v = eff.loc[eff.method == m, "steps"].to_numpy(float)
        reached = np.isfinite(v)
        shown = np.where(reached, v, budget)
        ax.bar(i, shown.mean(), color=f"C{i}", hatch=None if reached.all() else "//", alpha=0.8)
        ax.plot(np.full(len(v), i), shown, "k.", ms=5)
        if not reached.all():
            ax.text(i, budget, f"{(~reached).sum()}/{len(v)}\nnot\nreached", ha="center", va="bottom", fontsize=7)
    ax.set(
        xticks=range(len(methods)),
        xticklabels=[labels.get(m, m) for m in methods],
        ylabel="env steps",
        title=f"env steps to {threshold:.0%} training success (box)",
        ylim=(0, budget * 1.25),
    )
    ax.tick_params(axis="x", rotation=30)
    steps_axis(ax.yaxis)
    fig.tight_layout()
    return fig


def plot_trajectory_grid(
    episodes: pd.DataFrame,
    scenes: Sequence[str] = PAPER_SUITE[1:],
    episode: int = 0,
    train_seed: int | None = None,
    env_config: Any = None,
) -> plt.Figure:
    """Fig. 6: every method's path from the same start to the same goal, one panel per scene, on the map."""

    labels = _labels()
    seed = train_seed if train_seed is not None else int(episodes["train_seed"].min())
    sub = episodes[episodes["train_seed"] == seed].assign(method=lambda d: d["method"].map(lambda m: labels.get(m, m)))
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.8 * len(scenes), 5.6), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        plot_trajectories(sub, scene, episode, env_config=env_config, ax=ax, legend=False)
    # One legend for the figure, below the maps (inside one it hid the tree map), methods in a fixed colour.
    handles, names = {}, []
    for ax in axes[0]:
        for h, n in zip(*ax.get_legend_handles_labels()):
            if n not in handles and n not in ("start", "goal") and not n.startswith("shortest"):
                handles[n] = h
                names.append(n)
    fig.legend([handles[n] for n in names], names, loc="lower center", ncol=min(6, len(names)), fontsize=8,
               title=TRAJECTORY_KEY.replace("\n", " "), title_fontsize=8, frameon=False)  # fmt: skip
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    return fig


VERDICT_COLORS = {
    "holds": "#4daf4a",
    "reversed": "#e41a1c",
    "undecided": "#bdbdbd",
    "one seed": "#c6dbef",
    "not run": "#ffffff",
}


def plot_ledger_verdicts(verdicts: pd.DataFrame) -> plt.Figure:
    """The claim ledger's verdicts (:func:`omcrl.eval.verdicts.ledger_verdicts`): one bar per claim, its hypotheses
    stacked by verdict (holds, reversed, undecided after Holm; one seed: shown, not judged; not run), the claim's
    verdict written beside it.

    Parameters
    ----------
    verdicts : one row per hypothesis with columns ``claim``, ``family`` and ``verdict``.
    """
    from matplotlib.patches import Patch

    c = verdict_counts(verdicts)
    fig, ax = plt.subplots(figsize=(8.0, 0.3 * len(c) + 1.4))
    rows = c.to_dict("records")
    for i, r in enumerate(rows):
        left = 0
        for v, color in VERDICT_COLORS.items():
            if r[v]:
                ax.barh(i, r[v], left=left, color=color, edgecolor="#636363", lw=0.5)
                left += r[v]
        ax.text(left + 0.2, i, r["verdict"], va="center", fontsize=7)
    ax.set_yticks(range(len(rows)), [f"{r['claim']} ({r['family'][0]})" for r in rows], fontsize=7)
    ax.set_ylim(len(c) - 0.5, -0.5)
    ax.set_xlabel("hypotheses", fontsize=8)
    ax.set_xlim(0, float(c["hypotheses"].max()) * 1.25 + 1)
    ax.legend(handles=[Patch(facecolor=col, edgecolor="#636363", label=v) for v, col in VERDICT_COLORS.items()],
              loc="lower right", fontsize=7, frameon=False)  # fmt: skip
    ax.set_title("The claim ledger: each claim's hypotheses by verdict (p: primary, s: secondary; Holm within)",
                 fontsize=9)  # fmt: skip
    fig.tight_layout()
    return fig
