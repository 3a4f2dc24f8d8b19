"""Ablation figures (paper VI-C): Fig. 7 lines over ρ, Fig. 8 radar, Fig. 9 grouped bars, Fig. 10 heatmap.

Every function takes the long table of :func:`omcrl.eval.ablation.ablation_table` (index (variant, scene),
columns ``<metric>``, ``<metric>_lo``, ``<metric>_hi``) and returns its Figure.
"""

from __future__ import annotations

import re

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from omcrl.eval.table1 import HIGHER_IS_BETTER
from omcrl.scenes import scene_label
from omcrl.viz import method_color

FIG_METRICS = ("NE", "SR", "SPL", "CR")


def _scenes(table: pd.DataFrame) -> list[str]:
    return list(dict.fromkeys(table.index.get_level_values("scene")))


LEGEND_RIGHT = {"loc": "upper left", "bbox_to_anchor": (1.02, 1.0), "borderaxespad": 0.0}


def _variants(table: pd.DataFrame) -> list[str]:
    return list(dict.fromkeys(table.index.get_level_values("method")))


def plot_mask_prob(table: pd.DataFrame, reference: str = "CURL") -> plt.Figure:
    """Fig. 7: NE, SR, SPL, CR against the masking probability ρ per scene, CURL as a dashed line."""
    rho = {v: float(m.group(1)) for v in _variants(table) if (m := re.match(r"rho=([0-9.]+)", v))}
    order = sorted(rho, key=rho.get)
    # Legends right of the panels, in this figure and the bars: inside one they hid points (fig7 on v2, rho = 0.9).
    fig, axes = plt.subplots(1, len(FIG_METRICS), figsize=(3.2 * len(FIG_METRICS) + 1.6, 3.0))
    for ax, metric in zip(axes, FIG_METRICS):
        for i, sc in enumerate(_scenes(table)):
            y = [table.loc[(v, sc), metric] for v in order]
            lo = [table.loc[(v, sc), f"{metric}_lo"] for v in order]
            hi = [table.loc[(v, sc), f"{metric}_hi"] for v in order]
            x = [rho[v] for v in order]
            ax.plot(x, y, "o-", color=f"C{i}", label=scene_label(sc))
            ax.fill_between(x, lo, hi, color=f"C{i}", alpha=0.15)
            if (reference, sc) in table.index:
                ax.axhline(table.loc[(reference, sc), metric], color=f"C{i}", ls="--", lw=1)
        ax.set_xlabel("masking probability ρ")
        ax.set_title(metric)
    axes[-1].legend(fontsize=7, title=f"dashed: {reference}", title_fontsize=7, **LEGEND_RIGHT)
    fig.tight_layout()
    return fig


def normalised(table: pd.DataFrame) -> pd.DataFrame:
    """Per scene and metric, each variant as a fraction of the best one (1 = best, in [0, 1]).

    Higher-is-better metrics: ``v / max(v)``; lower-is-better ones: ``min(v) / v``. A ratio rather than a
    min-max scaling, so that with two variants (Fig. 8) the worse one is not drawn at 0 however close it is.
    A column whose best value is 0 (SR 0 everywhere, or CR 0 for the best) gives 1 to the variants at that value.
    """
    out = {}
    for sc in _scenes(table):
        for metric in FIG_METRICS:
            v = table.xs(sc, level="scene")[metric].astype(float)
            if HIGHER_IS_BETTER[metric]:
                s = v / v.max() if v.max() > 0 else v * 0 + 1.0
            else:
                s = v.min() / v if v.min() > 0 else (v == 0).astype(float)
            out[(sc, metric)] = s
    return pd.DataFrame(out)


def plot_radar(table: pd.DataFrame) -> plt.Figure:
    """Fig. 8: one radar per scene over the normalised metrics (1 = best), one polygon per variant."""
    norm = normalised(table)
    scenes = _scenes(table)
    ang = np.linspace(0, 2 * np.pi, len(FIG_METRICS), endpoint=False)
    fig, axes = plt.subplots(1, len(scenes), subplot_kw={"polar": True}, figsize=(3.0 * len(scenes), 3.2))
    for ax, sc in zip(np.atleast_1d(axes), scenes):
        for i, v in enumerate(norm.index):
            r = [norm.loc[v, (sc, m)] for m in FIG_METRICS]
            c = method_color(v, default=f"C{i}")  # a method keeps its colour from every figure
            ax.plot(np.r_[ang, ang[0]], np.r_[r, r[0]], color=c, label=v)
            ax.fill(np.r_[ang, ang[0]], np.r_[r, r[0]], color=c, alpha=0.1)
        ax.set_xticks(ang, FIG_METRICS, fontsize=7)
        ax.set_yticks([])
        ax.set_title(scene_label(sc), fontsize=9)
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="lower left", bbox_to_anchor=(-0.3, -0.3))
    fig.tight_layout()
    return fig


UNIT_LABEL = {"NE": "NE (m)", "SR": "SR (%)", "SPL": "SPL (0–1)", "CR": "CR (%)", "OS": "OS (%)", "TTS": "TTS (steps)"}


def plot_bars(table: pd.DataFrame, metric: str = "SR", title: str = "") -> plt.Figure:
    """Fig. 9: ``metric`` per scene (groups) and variant (bars) with 95 % CIs (training seeds and layouts
    crossed, :func:`omcrl.eval.stats.aggregate`)."""
    scenes, variants = _scenes(table), _variants(table)
    fig, ax = plt.subplots(figsize=(2.9 + 1.6 * len(scenes), 3.4))
    w = 0.8 / len(variants)
    for i, v in enumerate(variants):
        x = np.arange(len(scenes)) + (i - (len(variants) - 1) / 2) * w
        y = np.array([table.loc[(v, s), metric] for s in scenes])
        err = np.array([[y[j] - table.loc[(v, s), f"{metric}_lo"], table.loc[(v, s), f"{metric}_hi"] - y[j]]
                        for j, s in enumerate(scenes)]).T  # fmt: skip
        # A variant that is a method of the comparison keeps its colour from every other figure.
        ax.bar(x, y, w, yerr=err, capsize=3, label=v, color=method_color(v, default=None))
    ax.set_xticks(np.arange(len(scenes)), [scene_label(s) for s in scenes], fontsize=7)
    if metric in ("SR", "CR", "OS"):  # percentages: the full scale, also when every bar is 0 (a smoke run)
        ax.set_ylim(0, 105)
    ax.set_xlabel("evaluation scene (trained in box only)")
    ax.set_ylabel(UNIT_LABEL.get(metric, metric))
    ax.legend(fontsize=7, title="variant; bars: 95 % CI", title_fontsize=7, **LEGEND_RIGHT)
    ax.set_title(title or f"{UNIT_LABEL.get(metric, metric)} per scene and variant", fontsize=9)
    fig.tight_layout()
    return fig


def plot_heatmap(table: pd.DataFrame) -> plt.Figure:
    """Fig. 10: variants × (scene, metric), normalised per column (1 = best), raw values printed."""
    norm = normalised(table)
    fig, ax = plt.subplots(figsize=(0.55 * norm.shape[1] + 2.8, 0.5 * norm.shape[0] + 1.8))
    values = norm.to_numpy(float)
    im = ax.imshow(values, cmap="viridis", vmin=0, vmax=1, aspect="auto")
    for i, v in enumerate(norm.index):
        for j, (sc, m) in enumerate(norm.columns):
            # Dark text on the light (yellow) end of viridis, white on the dark end: readable on every cell.
            color = "k" if values[i, j] > 0.6 else "w"
            ax.text(j, i, f"{table.loc[(v, sc), m]:.2g}", ha="center", va="center", fontsize=6, color=color)
    ax.set_yticks(range(len(norm.index)), norm.index)
    # Metrics on the ticks, each scene named once under its group: the labels of every column would overlap.
    ax.set_xticks(range(norm.shape[1]), [m for _, m in norm.columns], fontsize=6)
    groups = list(dict.fromkeys(sc for sc, _ in norm.columns))
    for sc in groups:
        cols = [j for j, (s, _) in enumerate(norm.columns) if s == sc]
        ax.text(np.mean(cols), -0.06, scene_label(sc), transform=ax.get_xaxis_transform(), ha="center", va="top",
                fontsize=7)  # fmt: skip
        if cols[0] > 0:
            ax.axvline(cols[0] - 0.5, color="w", lw=2)
    fig.colorbar(im, ax=ax, fraction=0.03, label="relative to the best variant (1 = best)")
    ax.set_title("Printed: the metric's value (NE m, SR/CR %, SPL 0–1); colour: relative to the best", fontsize=8)
    fig.tight_layout()
    return fig


FIGURES = {
    "mask-prob": ("fig7_mask_prob", plot_mask_prob),
    "dual-transformer": ("fig8_dual_transformer", plot_radar),
    "projection": ("fig9_projection", plot_bars),
    "oracle-teacher": ("fig10_oracle_teacher", plot_heatmap),
}


def plot_ablation(grid: str, table: pd.DataFrame) -> tuple[str, plt.Figure]:
    """The paper's figure for ``grid`` (bars for a grid without one): (file name, Figure)."""
    name, fn = FIGURES.get(grid, (f"ablation_{grid}", plot_bars))
    return name, fn(table)
