"""The budget ladder's figure: success rate against budget, one panel per ladder (pretraining, RL)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt
import pandas as pd

from omcrl.viz import method_color


def plot_ladder(
    table: pd.DataFrame,
    scene: str,
    budgets: Mapping[str, str],
    scales: Mapping[str, Sequence[float]] | None = None,
    metric: str = "SR",
    per_seed: pd.DataFrame | None = None,
) -> plt.Figure:
    """``metric`` (mean and 95 % CI, seeds × layouts) against the budget multiplier (log axis) in ``scene``.

    Parameters
    ----------
    table : :func:`omcrl.pipeline.ladder.ladder_table`'s output (columns ``axis, method, scale, scene, seeds,
        <metric>, <metric>_lo, <metric>_hi``).
    scene : the scene drawn.
    budgets : ``{axis: what ×1 is}``, e.g. ``{"pretrain": "1,500 iterations on 80 episodes", "rl": "450,560 env
        steps"}``: one panel per axis, in this order; the x label says what the multiplier multiplies.
    scales : ``{axis: the ladder's multipliers}``, ticked whether or not they have data yet (default: those in
        ``table``). Methods are drawn side by side around each multiplier, so their intervals do not hide each other.
        A point with fewer training seeds than the method's other points is hollow and labelled with its count.
    per_seed : optional, columns ``axis, method, scale, scene, train_seed, <metric>``: each training seed's mean
        over the layouts, drawn as small faint dots beside its point (where the seeds disagree, the interval is wide).
    """
    axes_names = [a for a in budgets if (table["axis"] == a).any()] or list(budgets)
    fig, axes = plt.subplots(1, len(axes_names), figsize=(5.2 * len(axes_names), 3.8), squeeze=False, sharey=True)
    for ax, axis in zip(axes[0], axes_names):
        sub = table[(table["axis"] == axis) & (table["scene"] == scene)]
        methods = list(dict.fromkeys(sub["method"]))
        for i, method in enumerate(methods):
            g = sub[sub["method"] == method].sort_values("scale")
            dodge = 2 ** (0.06 * (i - (len(methods) - 1) / 2))
            err = [g[metric] - g[f"{metric}_lo"], g[f"{metric}_hi"] - g[metric]]
            lo, hi = int(g["seeds"].min()), int(g["seeds"].max())
            seeds = f"{lo} seed{'s' if hi > 1 else ''}" if lo == hi else f"{lo}-{hi} seeds"
            color = method_color(method)
            ax.errorbar(g["scale"] * dodge, g[metric], yerr=err, marker="o", capsize=3, color=color,
                        label=f"{method} ({seeds})")  # fmt: skip
            if per_seed is not None:
                at = per_seed[["axis", "scene", "method"]].eq([axis, scene, method]).all(axis=1)
                ps = per_seed[at]
                ax.plot(ps["scale"] * dodge * 2**0.05, ps[metric], ".", ms=5, alpha=0.6, color=color, zorder=2)
            # A point of fewer seeds than the method's others is not their like (its interval leaves out the seed
            # spread it cannot see): drawn hollow and labelled, so the line is not read as a trend of equals.
            few = g[g["seeds"] < hi]
            ax.plot(few["scale"] * dodge, few[metric], "o", mfc="white", mec=color, zorder=3)
            for x, y, n in zip(few["scale"] * dodge, few[metric], few["seeds"]):
                ax.annotate(f"{int(n)} seed{'s' if n > 1 else ''}", (x, y), xytext=(6, 4), textcoords="offset points",
                            fontsize=7, color=color)  # fmt: skip
        ticks = sorted(scales[axis]) if scales and axis in scales else sorted(sub["scale"].unique()) or [1.0]
        ax.set_xscale("log", base=2)
        ax.set_xticks(ticks, [f"×{s:g}" for s in ticks])
        ax.minorticks_off()
        ax.set_xlim(min(ticks) / 1.6, max(ticks) * 1.6)
        ax.set_xlabel(f"{axis} budget (×1 = {budgets[axis]})")
        ax.set_title(f"{scene}: {axis} ladder")
        ax.grid(alpha=0.3)
        if len(sub):
            ax.legend(fontsize=8)
    axes[0][0].set_ylabel(f"{metric} % (95 % CI)" if metric in ("SR", "CR", "OS") else metric)
    if metric in ("SR", "CR", "OS"):
        axes[0][0].set_ylim(-2, 102)
    fig.tight_layout()
    return fig
