"""Feature shift between scenes (see :mod:`omcrl.interpret.shift`)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.colors import TwoSlopeNorm


def plot_feature_shift(table: pd.DataFrame, metrics: tuple[str, ...] = ("mmd", "frechet", "saturated")) -> plt.Figure:
    """One panel per metric: grouped bars, one group per setting (scene or look), one bar per encoder.

    ``table`` is :func:`omcrl.interpret.shift.shift_table`'s output. MMD² and Fréchet distance are measured
    from the reference setting's features; "saturated" is the share of f's tanh units with |h| > 0.99.
    """
    settings = list(dict.fromkeys(table["setting"]))
    encoders = list(dict.fromkeys(table["encoder"]))
    labels = {
        "mmd": "MMD² to the reference",
        "frechet": "Fréchet distance to the reference",
        "saturated": "share of saturated tanh units",
    }
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.8 * len(metrics), 4.2), squeeze=False)
    x = np.arange(len(settings))
    w = 0.8 / max(1, len(encoders))
    for ax, m in zip(axes[0], metrics):
        for i, e in enumerate(encoders):
            sub = table[table["encoder"] == e].set_index("setting")
            ax.bar(x + (i - (len(encoders) - 1) / 2) * w, [sub.loc[s, m] for s in settings], w, label=e)
        ax.set_xticks(x, settings, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel(labels.get(m, m))
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_probe_across(table: pd.DataFrame, target: str | None = None) -> plt.Figure:
    """Heatmap of the box-fitted probe's R² per encoder (rows) and setting (columns), the value printed in each cell.

    ``table`` is :func:`omcrl.interpret.shift.probe_across`'s output with an ``encoder`` column added. ``target``
    picks one probe target; None averages the five. The colour scale spans the data: R² is unbounded below, so its
    negative side runs from the lowest value to 0 and its positive side from 0 to 1, each with its own slope
    (0, no better than the mean, is the middle colour), and the colour bar shows both.
    """
    sub = table if target is None else table[table["target"] == target]
    if sub.empty:
        raise ValueError(f"plot_probe_across: no rows for target {target!r}")
    wide = sub.groupby(["encoder", "setting"], sort=False)["r2"].mean().unstack("setting")
    wide = wide[list(dict.fromkeys(sub["setting"]))]
    fig, ax = plt.subplots(figsize=(1.5 + 1.3 * wide.shape[1], 1.0 + 0.5 * wide.shape[0]))
    low = min(float(np.nanmin(wide.to_numpy())), -1e-3)
    norm = TwoSlopeNorm(vmin=low, vcenter=0.0, vmax=1.0)
    im = ax.imshow(wide.to_numpy(), cmap="RdYlGn", norm=norm, aspect="auto")
    for (i, j), v in np.ndenumerate(wide.to_numpy()):
        ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=8)
    ax.set_xticks(range(wide.shape[1]), wide.columns, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(wide.shape[0]), wide.index, fontsize=8)
    ax.set_title(f"probe fitted in the reference, R² ({target or 'mean of the targets'})", fontsize=9)
    bar = fig.colorbar(im, ax=ax, fraction=0.03)
    bar.set_ticks(sorted({low, low / 2, 0.0, 0.5, 1.0}))
    bar.set_label("R²")
    fig.tight_layout()
    return fig
