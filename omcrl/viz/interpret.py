"""Figures of the interpretability notebook: disturbance tests (Fig. 12 and the real-world table), Grad-CAM
(Fig. 13) and t-SNE (Fig. 14)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.collections import LineCollection

from omcrl.viz.scenes import draw_map, scene_snapshot


def plot_disturbance(table: pd.DataFrame) -> plt.Figure:
    """SR (%) with 95 % CI per condition (groups) and method (bars); the paper's real-world SR as black ticks."""
    conds = list(dict.fromkeys(table.condition))
    methods = list(dict.fromkeys(table.method))
    fig, ax = plt.subplots(figsize=(2.8 + 1.5 * len(conds), 3.4))
    w = 0.8 / max(1, len(methods))
    # The paper's value of each method in a marker of its own, in the colour of its bars, so two methods' values
    # never look alike; the legend sits outside the axes, clear of the bars.
    markers = ("D", "^", "s", "v", "P", "X", "o")
    for i, m in enumerate(methods):
        t = table[table.method == m].set_index("condition").reindex(conds)
        x = np.arange(len(conds)) + (i - (len(methods) - 1) / 2) * w
        err = np.vstack([t.SR - t.lo, t.hi - t.SR])
        bars = ax.bar(x, t.SR, w, yerr=err, capsize=3, label=m)
        paper = t.paper_SR.astype(float)
        if paper.notna().any():
            ax.plot(x, paper, markers[i % len(markers)], color=bars.patches[0].get_facecolor(), mec="k", ms=7,
                    ls="none", label=f"{m}, paper (real Tello)")  # fmt: skip
    ax.set_xticks(np.arange(len(conds)), conds)
    ax.set_ylabel("SR (%)")
    ax.set_ylim(0, 105)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    ax.set_title("Disturbance tests in the simulated room (95 % CI)")
    fig.tight_layout()
    return fig


def plot_speed_trajectories(
    episodes: pd.DataFrame, env_config: Any, eval_seed: int | None = None, methods: Sequence[str] | None = None
) -> plt.Figure:
    """Fig. 12: one episode (``eval_seed``; default the first one every method finished) per method (rows) and
    condition (columns) on the room's top-down map, the path coloured by speed (m/s)."""

    methods = list(methods or dict.fromkeys(episodes.method))
    conds = list(dict.fromkeys(episodes.condition))
    if eval_seed is None:
        ok = episodes[episodes.success.astype(bool)].groupby("eval_seed").method.nunique()
        eval_seed = int(ok.idxmax()) if len(ok) else int(episodes.eval_seed.iloc[0])
    snap = scene_snapshot("box", eval_seed, env_config, image_size=32)
    fig, axes = plt.subplots(len(methods), len(conds), figsize=(3.0 * len(conds), 3.0 * len(methods)), squeeze=False)
    norm = plt.Normalize(0.0, float(getattr(env_config, "max_speed", 1.5)) * 1.42)
    lc = None
    for r, m in enumerate(methods):
        for c, cond in enumerate(conds):
            ax = axes[r, c]
            draw_map(ax, snap)
            ax.get_legend().remove()
            row = episodes[(episodes.method == m) & (episodes.condition == cond) & (episodes.eval_seed == eval_seed)]
            if len(row):
                xy = np.asarray(row.trajectory.iloc[0], float)
                if len(xy) > 1:
                    segs = np.stack([xy[:-1], xy[1:]], 1)
                    speed = np.linalg.norm(np.diff(xy, axis=0), axis=1) * float(env_config.control_hz)
                    lc = LineCollection(segs, cmap="viridis", norm=norm, linewidths=2.5)
                    lc.set_array(speed)
                    ax.add_collection(lc)
                outcome = (
                    "success" if bool(row.success.iloc[0]) else "collision" if bool(row.collision.iloc[0]) else "fail"
                )
                ax.set_title(f"{m} · {cond} · {outcome}", fontsize=8)
            ax.set_xlabel("")
            ax.set_ylabel("")
    if lc is not None:
        fig.colorbar(lc, ax=axes, shrink=0.6, label="speed (m/s)")
    return fig


def plot_gradcam(frames: np.ndarray, cams: Mapping[str, np.ndarray], titles: Sequence[str], crop: int) -> plt.Figure:
    """Fig. 13: rows = frames (newest RGB frame of each stack, centre crop), columns = the frame and each method's
    Grad-CAM overlaid. ``frames`` (N, 3L, H, W) uint8; ``cams`` {method: (N, crop, crop)}."""
    n = len(frames)
    fig, axes = plt.subplots(n, 1 + len(cams), figsize=(2.2 * (1 + len(cams)), 2.2 * n), squeeze=False)
    o = (frames.shape[-1] - crop) // 2
    for i in range(n):
        img = frames[i, -3:, o : o + crop, o : o + crop].transpose(1, 2, 0)
        axes[i, 0].imshow(img)
        axes[i, 0].set_title(titles[i], fontsize=8)
        for j, (m, cam) in enumerate(cams.items(), start=1):
            c = cam[i] / cam[i].max() if cam[i].max() > 0 else cam[i]
            axes[i, j].imshow(img)
            overlay = axes[i, j].imshow(c, cmap="jet", alpha=0.45, vmin=0, vmax=1)
            axes[i, j].set_title(m, fontsize=8)
    for ax in axes.flat:
        ax.axis("off")
    fig.tight_layout()
    if cams:
        fig.colorbar(overlay, ax=axes[:, 1:].ravel().tolist(), shrink=0.6, label="Grad-CAM, each frame's max = 1")
    return fig


def plot_tsne(embeddings: Mapping[str, pd.DataFrame]) -> plt.Figure:
    """Fig. 14: one panel per encoder; clean features and each disturbance in its own colour."""
    fig, axes = plt.subplots(1, len(embeddings), figsize=(3.4 * len(embeddings), 3.4), squeeze=False)
    for ax, (name, emb) in zip(axes[0], embeddings.items()):
        for cond in dict.fromkeys(emb.condition):
            e = emb[emb.condition == cond]
            ax.scatter(e.x, e.y, s=6, alpha=0.6, label=cond, marker="o" if cond == "clean" else ".")
        ax.set_title(name)
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0, 0].legend(fontsize=7, markerscale=2)
    fig.tight_layout()
    return fig
