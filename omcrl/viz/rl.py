"""Figures and key numbers for downstream RL (notebooks 03-04): training curves, run summaries, eval bars.

Training runs log tidy ``metrics.csv`` files (``step,metric,value``, one row per PPO update and metric; see
:mod:`omcrl.rl.train`); ``step`` is the env-step count over all envs at the end of the update.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from omcrl.scenes import scene_id
from omcrl.viz import method_color, steps_axis
from omcrl.viz.pretrain import final_value, read_metrics, smooth
from omcrl.viz.scenes import draw_map, scene_snapshot

# (panel title, metrics drawn in it); several metrics in one panel are told apart by line style.
ORACLE_PANELS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("episodic return", ("episodic_return",)),
    ("success rate", ("success_rate",)),
    ("guidance weight α", ("alpha",)),
    ("losses", ("policy_loss", "value_loss", "kl")),
    ("policy entropy", ("entropy",)),
    ("throughput (env steps/s)", ("steps_per_s",)),
)
COMPARE_PANELS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("success rate", ("success_rate",)),
    ("episodic return", ("episodic_return",)),
    ("guidance weight α", ("alpha",)),
)
_STYLES = ("-", "--", ":", "-.")


def plot_training_curves(
    runs: Mapping[str, str | Path],
    panels: Sequence[tuple[str, Sequence[str]]] = ORACLE_PANELS,
    window: int = 5,
    ncols: int = 3,
    title: str | None = None,
) -> plt.Figure:
    """One panel per entry of ``panels``, one colour per run; x = env steps.

    Parameters
    ----------
    runs : ``{label: metrics.csv path}`` (a run folder is accepted too).
    panels : ``(title, metric names)``; raw values are drawn faint, a trailing moving average of ``window``
        updates solid. Loss panels use a symmetric-log y axis (policy loss is signed, value loss is not).
    ncols : panels per row.
    """
    n = len(panels)
    nrows = int(np.ceil(n / ncols))
    fig, axes = plt.subplots(nrows, min(ncols, n), figsize=(4.2 * min(ncols, n), 3.0 * nrows), squeeze=False)
    for i, (label, path) in enumerate(runs.items()):
        p = Path(path)
        m = read_metrics(p / "metrics.csv" if p.is_dir() else p)
        for ax, (_, names) in zip(axes.flat, panels):
            for j, name in enumerate(names):
                if name not in m:
                    continue
                s, v = m[name]
                style = _STYLES[j % len(_STYLES)]
                tag = label if len(names) == 1 else f"{label}: {name}"
                ax.plot(s, v, color=f"C{i}", ls=style, alpha=0.2, lw=0.8)
                ax.plot(s, smooth(v, window), color=f"C{i}", ls=style, label=tag)
    for ax, (ptitle, names) in zip(axes.flat, panels):
        ax.set(xlabel="env steps", title=ptitle)
        steps_axis(ax.xaxis)
        if "success_rate" in names:
            ax.set_ylim(-0.03, 1.03)
        if any(nm.endswith("loss") for nm in names):
            ax.set_yscale("symlog", linthresh=1e-2)
        if ax.lines:
            ax.legend(fontsize=7)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def run_summary(metrics_path: str | Path, last: int = 5) -> dict[str, float]:
    """Key numbers of a training run from its ``metrics.csv``.

    Returns ``steps`` (final env-step count), ``train_time_s`` (Σ update env steps / steps_per_s: rollout +
    PPO update time, without start-up and evaluation), ``steps_per_s`` (steps / train_time_s),
    ``final_success_rate`` and ``final_return`` (mean over the last ``last`` updates that finished episodes),
    ``best_success_rate`` (max of a ``last``-update moving average) and ``final_alpha``.
    """
    m = read_metrics(metrics_path)
    out: dict[str, float] = {}
    if "steps_per_s" in m:
        s, sps = m["steps_per_s"]
        per_update = np.diff(np.concatenate([[0], s]))
        out["steps"] = float(s[-1])
        out["train_time_s"] = float(np.sum(per_update / sps))
        out["steps_per_s"] = out["steps"] / out["train_time_s"]
    if "success_rate" in m:
        out["final_success_rate"] = final_value(m, "success_rate", last)
        out["best_success_rate"] = float(np.nanmax(smooth(m["success_rate"][1], last)))
    if "episodic_return" in m:
        out["final_return"] = final_value(m, "episodic_return", last)
    if "alpha" in m:
        out["final_alpha"] = float(m["alpha"][1][-1])
    return out


def plot_eval_bars(
    table: pd.DataFrame, metrics: Sequence[str] = ("SR", "SPL", "CR"), methods: Sequence[str] | None = None
) -> plt.Figure:
    """Grouped bars per scene, one bar per method, one panel per metric.

    Parameters
    ----------
    table : :func:`omcrl.eval.summary_table` output indexed by (method, scene).
    metrics : columns to draw (SR/OS/CR in %, SPL in [0, 1], NE in m, TTS in steps).
    methods : order of the bars (default: order of appearance).
    """
    methods = list(methods or dict.fromkeys(table.index.get_level_values("method")))
    scenes = list(dict.fromkeys(table.index.get_level_values("scene")))
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.5 * len(metrics), 3.2), squeeze=False)
    x = np.arange(len(scenes))
    w = 0.8 / max(1, len(methods))
    for ax, metric in zip(axes[0], metrics):
        for i, method in enumerate(methods):
            vals = [table.loc[(method, sc), metric] if (method, sc) in table.index else np.nan for sc in scenes]
            ax.bar(x + (i - (len(methods) - 1) / 2) * w, vals, w, label=method, color=f"C{i}")
        unit = {"SR": " (%)", "OS": " (%)", "CR": " (%)", "NE": " (m)", "TTS": " (steps)"}.get(metric, "")
        ax.set(xticks=x, xticklabels=scenes, title=metric + unit)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    return fig


TRAJECTORY_KEY = "path per method; ✕ end: green success,\nred collision, grey timeout"


def plot_trajectories(
    episodes: pd.DataFrame,
    scene: str,
    episode: int = 0,
    env_config: Any = None,
    ax: plt.Axes | None = None,
    legend: bool = True,
) -> plt.Figure:
    """Top-down (x, y) paths of every method on one evaluation episode (the same layout for all methods).

    Parameters
    ----------
    episodes : :func:`omcrl.eval.evaluate` rows with ``trajectory``, ``eval_seed``, ``success``, ``collision``.
    scene, episode : which evaluation episode to draw.
    env_config : the :class:`omcrl.config.EnvConfig` evaluated with; when given, the episode's map, start, goal
        and shortest path are drawn underneath (the layout follows from ``eval_seed``).

    ax : draw into this axes (default: a new figure).

    The start is a dot, the end a cross (green: success, red: collision, grey: timeout).
    """
    scene = scene_id(scene)
    rows = episodes[(episodes.scene.map(scene_id) == scene) & (episodes.episode == episode)]
    if ax is None:
        fig, ax = plt.subplots(figsize=(4.6, 4.6))
    else:
        fig = ax.figure
    if env_config is not None and len(rows):
        draw_map(ax, scene_snapshot(scene, int(rows.eval_seed.iloc[0]), env_config, image_size=32))
    for _, r in rows.iterrows():
        xy = np.asarray(r["trajectory"], float)
        if len(xy) == 0:
            continue
        ax.plot(xy[:, 0], xy[:, 1], color=method_color(r["method"]), lw=1.6, label=r["method"])
        end = "green" if r["success"] else ("red" if r["collision"] else "grey")
        ax.plot(*xy[-1], "x", color=end, ms=7, mew=2)
    ax.set(aspect="equal", xlabel="x (m)", ylabel="y (m)", title=f"{scene}, evaluation episode {episode}")
    if legend:
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), title=TRAJECTORY_KEY, title_fontsize=7)
    return fig
