"""Figures for upstream pretraining (notebook 02): loss / masked top-1 accuracy curves and probe R²."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from omcrl.runs import metric_series


def read_metrics(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``metrics.csv`` (or its run folder) → ``{metric: (steps (n,), values float64 (n,))}``; the kit's one
    reader, :func:`omcrl.runs.metric_series`, under the name the plotting code uses."""

    return metric_series(path)


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average over ``window`` points, NaN-aware (NaN where the whole window is NaN)."""
    v = np.asarray(values, np.float64)
    if window <= 1 or len(v) == 0:
        return v
    ok = np.isfinite(v)
    c = np.concatenate([[0.0], np.cumsum(np.where(ok, v, 0.0))])
    n = np.concatenate([[0], np.cumsum(ok)])
    idx = np.arange(1, len(v) + 1)
    lo = np.clip(idx - window, 0, None)
    cnt = n[idx] - n[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, (c[idx] - c[lo]) / cnt, np.nan)


def final_value(metrics: Mapping[str, tuple[np.ndarray, np.ndarray]], name: str, last: int = 50) -> float:
    """Mean of the last ``last`` finite values of ``name`` (a less noisy 'final' number than one step)."""
    v = metrics[name][1]
    v = v[np.isfinite(v)]
    return float(v[-last:].mean()) if len(v) else float("nan")


def plot_curves(
    runs: Mapping[str, str | Path],
    metrics: Sequence[str] = ("loss", "accuracy"),
    window: int = 25,
    chance: Mapping[str, float] | None = None,
) -> plt.Figure:
    """One panel per metric, one line per run (raw values faint, moving average solid).

    Parameters
    ----------
    runs : ``{label: metrics.csv path}``.
    window : moving-average window (iterations).
    chance : ``{label: chance accuracy}`` (1 / number of candidate keys), drawn dashed on the accuracy panel.
    """
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.5 * len(metrics), 3.2), squeeze=False)
    for i, (label, path) in enumerate(runs.items()):
        m = read_metrics(path)
        color = f"C{i}"
        for ax, name in zip(axes[0], metrics):
            if name not in m:
                continue
            s, v = m[name]
            ax.plot(s, v, color=color, alpha=0.2, lw=0.8)
            ax.plot(s, smooth(v, window), color=color, label=label)
            if name == "accuracy" and chance and label in chance:
                ax.axhline(chance[label], color=color, ls="--", lw=0.8)
    for ax, name in zip(axes[0], metrics):
        title = "masked top-1 accuracy (dashed: chance)" if name == "accuracy" else name
        ax.set(xlabel="iteration", title=title, ylabel=_YLABELS.get(name, name))
        if name == "loss":
            ax.set_yscale("log")
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


_YLABELS = {"loss": "InfoNCE loss (log scale)", "accuracy": "fraction of masked queries"}
# Keys of a probe row that are not probe targets.
_PROBE_META = ("encoder", "n_train", "n_test", "mean_r2")


def plot_probe(rows: Sequence[Mapping], targets: Sequence[str] | None = None) -> plt.Figure:
    """Grouped bars of held-out R² per probe target, one bar per encoder (``rows[i]["encoder"]``).

    ``targets`` defaults to every target the rows hold (distance and bearing of the nearest obstacle, depth
    ahead, depth balance, ...), followed by their mean.
    """
    if targets is None:
        targets = [k for k in rows[0] if k not in _PROBE_META] if rows else []
        if rows and "mean_r2" in rows[0]:
            targets = [*targets, "mean_r2"]
    fig, ax = plt.subplots(figsize=(1.3 * len(targets) + 2.5, 3.2))
    x = np.arange(len(targets))
    w = 0.8 / max(1, len(rows))
    for i, r in enumerate(rows):
        ax.bar(x + (i - (len(rows) - 1) / 2) * w, [r[t] for t in targets], w, label=r["encoder"])
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set(xticks=x, xticklabels=targets, ylabel="held-out R²", title="linear probe of frozen features")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
