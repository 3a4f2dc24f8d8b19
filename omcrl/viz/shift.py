"""Feature shift between scenes (see :mod:`omcrl.interpret.shift`)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd


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
