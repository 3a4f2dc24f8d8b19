"""Figures for the collected trajectory data (notebook 01): source mix, outcomes, sample frames."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from omcrl.data.dataset import SOURCES, TrajectoryDataset

OUTCOME_COLORS = {"success": "tab:green", "collision": "tab:red", "timeout": "tab:gray"}


def plot_source_mix(summary: dict, mix: dict | None = None) -> plt.Figure:
    """Bar charts of episodes and steps per source, stacked by outcome, with the requested mix as ticks.

    Parameters
    ----------
    summary : :func:`omcrl.data.collect.summarize` output (``per_source`` and ``outcomes``).
    mix : ``cfg.data.mix``; drawn as the expected episode count per source (black tick) when given.
    """
    per, outc = summary["per_source"], summary.get("outcomes", {})
    srcs = [s for s in SOURCES if s in per or (mix and mix.get(s, 0) > 0)]
    x = np.arange(len(srcs))
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(8, 3))
    bottom = np.zeros(len(srcs))
    for kind, color in OUTCOME_COLORS.items():
        h = np.array([outc.get(s, {}).get(kind, 0) for s in srcs], float)
        ax1.bar(x, h, bottom=bottom, color=color, label=kind)
        bottom += h
    if mix:
        tot = sum(mix.values())
        exp = [summary["episodes"] * mix.get(s, 0) / tot for s in srcs]
        ax1.scatter(x, exp, marker="_", s=600, color="k", label="requested mix", zorder=3)
    ax1.set(xticks=x, xticklabels=srcs, ylabel="episodes", title=f"{summary['episodes']} episodes")
    ax1.legend(fontsize=7)
    ax2.bar(x, [per.get(s, {}).get("steps", 0) for s in srcs], color="tab:blue")
    ax2.set(xticks=x, xticklabels=srcs, ylabel="steps", title=f"{summary['steps']} steps")
    fig.tight_layout()
    return fig


def plot_frames(
    ds: TrajectoryDataset, episodes: Sequence[int], n_frames: int = 6, far: float | None = None
) -> plt.Figure:
    """RGB and depth strips: for each episode, ``n_frames`` evenly spaced frames (RGB row, depth row).

    Parameters
    ----------
    ds : open dataset; frames are single images (3, H, W) uint8 and depth (H, W) in metres.
    episodes : episode indices, one pair of rows each.
    far : depth colour-scale maximum in metres (default: the env's ``far`` stored in the file).
    """
    far = float(far or ds.env_config.get("far", 20.0))
    fig, axes = plt.subplots(2 * len(episodes), n_frames, figsize=(1.3 * n_frames, 2.7 * len(episodes)), squeeze=False)
    for r, ep in enumerate(episodes):
        n = int(ds.episode_lengths[ep])
        ts = np.unique(np.linspace(0, n - 1, n_frames).round().astype(int))
        rgb, depth = ds.read(ep, "rgb"), ds.read(ep, "depth").astype(np.float32)
        src = ds.sources[ep]
        for c in range(n_frames):
            a_rgb, a_d = axes[2 * r, c], axes[2 * r + 1, c]
            for a in (a_rgb, a_d):
                a.set_axis_off()
            if c >= len(ts):
                continue
            a_rgb.imshow(rgb[ts[c]].transpose(1, 2, 0))
            a_d.imshow(depth[ts[c]], cmap="magma_r", vmin=0.0, vmax=min(far, 8.0))
            a_rgb.set_title(f"ep {ep} ({src}) t={ts[c]}" if c == 0 else f"t={ts[c]}", fontsize=7)
    fig.tight_layout()
    return fig


def plot_episode_lengths(ds: TrajectoryDataset, outcomes: Sequence[str] | None = None) -> plt.Figure:
    """Histogram of episode lengths (steps) per source."""
    fig, ax = plt.subplots(figsize=(5, 3))
    srcs = [s for s in SOURCES if s in ds.sources]
    data = [ds.episode_lengths[np.array(ds.sources) == s] for s in srcs]
    ax.hist(data, bins=20, label=srcs, stacked=True)
    ax.set(xlabel="episode length (steps)", ylabel="episodes")
    ax.legend()
    fig.tight_layout()
    return fig


def source_table(summary: dict) -> list[dict[str, Any]]:
    """One row per source: episodes, steps, success/collision/timeout counts and success rate."""
    rows = []
    for s, v in summary["per_source"].items():
        o = summary.get("outcomes", {}).get(s, {})
        n = max(1, v["episodes"])
        rows.append(
            {"source": s, "episodes": v["episodes"], "steps": v["steps"], **o, "success_rate": o.get("success", 0) / n}
        )
    return rows
