"""Scene gallery: top-down maps with start, goal and shortest path, and first-person RGB and depth frames."""

from __future__ import annotations

from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from omcrl.config import EnvConfig
from omcrl.envs import make_env
from omcrl.interpret.gradient import gradient_order, order_verdicts
from omcrl.scenes import SCENE_SPECS, families, scene_label, scene_spec


def scene_snapshot(scene: str, seed: int, env_config: EnvConfig | None = None, image_size: int = 128) -> dict[str, Any]:
    """Reset one env of ``scene`` with ``seed`` and return what a map and FPV figure need.

    Returns
    -------
    dict with ``grid`` (OccupancyGrid), ``pose`` (3,) x, y m and yaw rad, ``goal`` (2,) m, ``path`` (K, 2) m,
    ``optimal_path_length`` m, ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) m, ``n_primitives``, ``arena_half`` m.
    """
    env = make_env(scene, seed=seed, image_size=image_size, config=env_config)
    obs, info = env.reset(seed=seed)
    out = {
        "scene": env.scene,
        "grid": env.grid,
        "pose": info["pose"],
        "goal": info["goal"],
        "path": np.asarray(info["path"]),
        "optimal_path_length": info["optimal_path_length"],
        "rgb": obs["rgb"][-1].transpose(1, 2, 0),
        "depth": obs["depth"][-1],
        "n_primitives": len(env.primitives),
        "arena_half": env.cfg.arena_half,
    }
    env.close()
    return out


def draw_map(ax: plt.Axes, snap: dict[str, Any]) -> None:
    """Top-down map: obstacle clearance (dark = blocked for the drone centre), start, heading, goal, path."""
    grid, a = snap["grid"], snap["arena_half"]
    shade = np.where(grid.occ, 0.0, 0.55 + 0.45 * np.clip(grid.dist / grid.dist.max(), 0, 1))
    ax.imshow(shade.T, origin="lower", cmap="gray", vmin=0, vmax=1, extent=(-a, a, -a, a))
    p = snap["path"]
    if len(p):
        ax.plot(p[:, 0], p[:, 1], "-", color="tab:orange", lw=2, label=f"shortest {snap['optimal_path_length']:.1f} m")
    x, y, yaw = snap["pose"]
    ax.plot(x, y, "o", color="tab:blue", ms=7, label="start")
    ax.arrow(x, y, 0.9 * np.cos(yaw), 0.9 * np.sin(yaw), color="tab:blue", width=0.08, length_includes_head=True)
    ax.plot(*snap["goal"], "*", color="tab:red", ms=14, label="goal")
    ax.set_xlim(-a, a)
    ax.set_ylim(-a, a)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="best", fontsize=7, framealpha=0.7)  # a fixed corner can hide a start or goal placed there


def scene_gallery(
    scenes: tuple[str, ...] = tuple(SCENE_SPECS),
    seed: int = 0,
    env_config: EnvConfig | None = None,
    image_size: int = 128,
) -> tuple[plt.Figure, list[dict[str, Any]]]:
    """One column per scene (default: every registered scene and version): map (row 1), FPV RGB (row 2) and
    depth in metres (row 3) at the start pose.

    A scene of the ``j``-th family is reset with seed ``seed + j``: one seed for all would draw the same start and
    goal in every scene, and the gallery is meant to show each scene's own episode; versions of one family share
    the seed, so furniture-v0 and -v1 show the same layout in their two rooms.
    """
    fam = families()
    snaps = [scene_snapshot(s, seed + fam.index(scene_spec(s).family), env_config, image_size) for s in scenes]
    fig, axes = plt.subplots(3, len(scenes), figsize=(4.2 * len(scenes), 12), squeeze=False)
    for j, snap in enumerate(snaps):
        draw_map(axes[0, j], snap)
        axes[0, j].set_title(f"{scene_label(snap['scene'])}, {snap['n_primitives']} solids")
        axes[1, j].imshow(snap["rgb"])
        axes[1, j].set_title("first-person RGB")
        im = axes[2, j].imshow(snap["depth"], cmap="viridis_r", vmin=0, vmax=min(10.0, float(snap["depth"].max())))
        axes[2, j].set_title("depth (m)")
        fig.colorbar(im, ax=axes[2, j], fraction=0.046)
        for ax in axes[1:, j]:
            ax.axis("off")
    fig.tight_layout()
    return fig, snaps


def plot_gradient(table: Any) -> plt.Figure:
    """The scenes' gradient (:func:`omcrl.interpret.gradient.gradient_stage`'s table): one panel per measure of
    the shift from box, one bar per setting in the table's order (the box floor, the paper's scenes, then the stress
    test), with the random encoders' min–max as error bars; the title of each panel says whether the paper's order
    holds."""

    verdict = order_verdicts(table).set_index("measure").holds
    panels = (
        ("random_mmd", "random-init encoders: MMD² (mean, min–max of 3)"),
        ("pixel_mmd", "8×8 pixels: MMD²"),
        ("colour_js", "colour histogram: JS (bits)"),
    )
    order = list(gradient_order())
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 3.8))
    for ax, (col, title) in zip(axes, panels):
        colors = ["tab:gray" if s not in order else "tab:blue" for s in table.setting]
        err = None
        if col == "random_mmd":
            err = np.stack([table[col] - table["random_mmd_min"], table["random_mmd_max"] - table[col]])
        ax.bar(range(len(table)), table[col], yerr=err, color=colors, capsize=3)
        ax.set_xticks(range(len(table)), [s.replace(", ", ",\n") for s in table.setting], rotation=30, fontsize=8)
        ax.set_title(f"{title}\npaper's order {'holds' if verdict[col] else 'fails'}", fontsize=9)
        ax.set_ylabel("shift from box")
    fig.suptitle("Perceptual shift from box (blue: the paper's suite in its order; grey: stress test)", fontsize=10)
    fig.tight_layout()
    return fig
