"""The scenes' gradient of difficulty, measured with nothing learned (``python -m omcrl gradient --preset P``).

The paper's four scenes form "a gradient of perceptual and navigational difficulty" (V-A): box (training) <
furniture (easy) < barrier (medium) < tree (hard). Whether a scene suite follows it must be settled before any
learned method flies it, so no learned method's success can pick the scenes. ``gradient_stage(cfg)`` writes

    tables/scene_gradient.{csv,md}   per setting: the perceptual shift from box and the navigational difficulty
    tables/scene_gradient_order.md   does each measure order box < furniture-v1 < barrier < tree?

**Perceptual**: frames along scripted-pilot flights (Hybrid APF on the true map; seeds from
:data:`omcrl.interpret.transfer.PILOT_SEED`, disjoint from training and evaluation) in each scene, compared with
box frames of other layouts by

- ``random_mmd``: MMD² (:func:`omcrl.interpret.shift.mmd_rbf`) between the features of a **randomly initialised**
  encoder of the student's shape, for each of ``inits`` seeds (mean, min and max in the table): how far the
  frames move for a network that has learnt nothing;
- ``pixel_mmd``: MMD² between the newest frames downsampled to ``PIXEL_SIDE`` × ``PIXEL_SIDE`` RGB (no network);
- ``colour_js``: the Jensen–Shannon divergence (bits, 0–1) between the pooled RGB colour histograms
  (``HIST_BINS``³ bins) of the newest frames (no network).

"box, other layouts" (box frames from other seeds) is the sampling floor of each measure.

**Navigational**, on Table I's evaluation layouts (``cfg.eval.episodes`` seeds from ``cfg.eval.seed_offset``):
the share of the arena blocked at flight altitude, the detour (shortest path / straight line, mean and the share
of layouts bending by more than 2 %), and the success and collision rates of two planners: the privileged
Hybrid APF (global path on the true map) and the local APF on the depth camera (NPE's non-expert guide).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from omcrl.config import Config
from omcrl.envs.stats import geometry_stats
from omcrl.eval.runner import eval_seeds
from omcrl.eval.stage import evaluate_methods
from omcrl.eval.stats import aggregate
from omcrl.interpret.shift import encode, mmd_rbf, pilot_frames
from omcrl.interpret.transfer import PILOT_SEED, pilot_episodes
from omcrl.models.artifact import random_encoder
from omcrl.rl.methods import encoder_config
from omcrl.scenes import PAPER_SUITE, SCENE_SPECS, scene_spec
from omcrl.utils.io import atomic_write_text
from omcrl.utils.progress import track

REFERENCE = "box"
FLOOR = "box, other layouts"
PIXEL_SIDE = 8
HIST_BINS = 8
PLANNERS = ("hybrid-apf", "local-apf")
MEASURES = ("random_mmd", "pixel_mmd", "colour_js")


def gradient_order() -> tuple[str, ...]:
    """The settings whose measures must rise in this order on the paper's gradient: the box floor, then the
    paper's evaluation scenes (``furniture-v1`` < ``barrier-v0`` < ``tree-v0``)."""
    return (FLOOR, *PAPER_SUITE[1:])


def newest_frames(stacks: np.ndarray) -> np.ndarray:
    """The newest RGB frame of each observation stack: (N, 3L, H, W) uint8 -> (N, H, W, 3) uint8."""
    return np.ascontiguousarray(np.moveaxis(stacks[:, -3:], 1, -1))


def pixel_features(stacks: np.ndarray, side: int = PIXEL_SIDE) -> np.ndarray:
    """(N, 3·side²) float64 in [0, 1]: the newest frame of each stack (N, 3L, H, W) uint8, area-averaged to
    ``side`` × ``side`` pixels (what a frame shows at a glance: colours and their layout, no detail)."""
    import cv2

    frames = newest_frames(stacks)
    small = np.stack([cv2.resize(f, (side, side), interpolation=cv2.INTER_AREA) for f in frames])
    return small.reshape(len(small), -1).astype(np.float64) / 255.0


def colour_histogram(stacks: np.ndarray, bins: int = HIST_BINS) -> np.ndarray:
    """(bins³,) the pooled, normalised joint RGB histogram of the newest frames of ``stacks`` (N, 3L, H, W)."""
    q = (newest_frames(stacks).reshape(-1, 3).astype(np.int64) * bins) // 256
    counts = np.bincount((q[:, 0] * bins + q[:, 1]) * bins + q[:, 2], minlength=bins**3).astype(np.float64)
    return counts / counts.sum()


def js_divergence(p: np.ndarray, q: np.ndarray) -> float:
    """Jensen–Shannon divergence in bits (0 for equal distributions, 1 for disjoint ones)."""
    p, q = np.asarray(p, np.float64), np.asarray(q, np.float64)
    m = (p + q) / 2.0

    def kl(a: np.ndarray) -> float:
        nz = a > 0
        return float((a[nz] * np.log2(a[nz] / m[nz])).sum())

    return max(0.0, 0.5 * kl(p) + 0.5 * kl(q))


def gradient_samples(cfg: Config, episodes: int | None = None, *, progress: bool = False) -> dict[str, np.ndarray]:
    """Pilot RGB stacks (N, 3L, H, W) uint8 per setting: the box reference (twice the episodes, its own seeds),
    "box, other layouts", and every scene of :data:`~omcrl.scenes.SCENE_SPECS` but box; the settings
    other than the reference fly the same seeds (so furniture-v0 and v1 share their layouts)."""

    n = int(episodes if episodes is not None else pilot_episodes(cfg))
    settings = [(REFERENCE, "box-v0"), (FLOOR, "box-v0")]
    settings += [(s, s) for s in SCENE_SPECS if scene_spec(s).difficulty != "training"]
    out = {}
    for name, scene in track(settings, desc="gradient/pilot frames", unit="setting", enabled=progress):
        seed, k = (PILOT_SEED + 100, 2 * n) if name == REFERENCE else (PILOT_SEED, n)
        out[name] = pilot_frames(scene, k, seed, env_config=cfg.env)
    return out


def perceptual_table(samples: Mapping[str, np.ndarray], encoders: Mapping[int, Any]) -> pd.DataFrame:
    """The perceptual shift of every setting of ``samples`` from ``samples["box"]``.

    Parameters
    ----------
    samples : ``{setting: (N, 3L, H, W) uint8}``, holding :data:`REFERENCE`.
    encoders : ``{init seed: randomly initialised frozen encoder}``.

    Returns
    -------
    DataFrame, one row per setting other than the reference: ``setting, frames, pixel_mmd, colour_js`` and
    ``random_mmd_<init>`` per encoder, ``random_mmd`` (their mean), ``random_mmd_min``, ``random_mmd_max``.
    """

    ref = samples[REFERENCE]
    ref_px, ref_hist = pixel_features(ref), colour_histogram(ref)
    ref_z = {i: encode(e, ref)[0] for i, e in encoders.items()}
    rows = []
    for setting, stacks in samples.items():
        if setting == REFERENCE:
            continue
        row: dict[str, Any] = {"setting": setting, "frames": len(stacks)}
        row["pixel_mmd"] = mmd_rbf(ref_px, pixel_features(stacks))
        row["colour_js"] = js_divergence(ref_hist, colour_histogram(stacks))
        per = {i: mmd_rbf(ref_z[i], encode(e, stacks)[0]) for i, e in encoders.items()}
        row.update({f"random_mmd_{i}": v for i, v in per.items()})
        row.update(random_mmd=float(np.mean(list(per.values()))), random_mmd_min=min(per.values()),
                   random_mmd_max=max(per.values()))  # fmt: skip
        rows.append(row)
    return pd.DataFrame(rows)


def navigation_table(cfg: Config, scenes: Sequence[str], *, progress: bool = False) -> pd.DataFrame:
    """Per scene, on Table I's evaluation layouts: ``blocked_pct`` (mean), ``detour`` (mean shortest path /
    straight line), ``bent_pct`` (% of layouts with detour > 1.02) and SR / CR (%) with 95 % CIs of each planner of
    :data:`PLANNERS` (evaluations cached as Table I's)."""

    seeds = eval_seeds(cfg.eval.episodes, 0, cfg.eval.seed_offset)
    geo = pd.concat([geometry_stats(s, seeds, cfg.env) for s in scenes], ignore_index=True)
    geo["detour"] = geo.shortest_path_m / geo.straight_line_m
    g = geo.groupby("scene", sort=False)
    bent = g.detour.apply(lambda d: 100.0 * float((d > 1.02).mean()))
    nav = pd.DataFrame({"blocked_pct": g.blocked_pct.mean(), "detour": g.detour.mean(), "bent_pct": bent})
    ep = evaluate_methods(cfg, {p: p for p in PLANNERS}, list(scenes), progress=progress)
    agg = aggregate(ep, ("method", "scene"))
    for p in PLANNERS:
        a = agg.xs(p, level="method")
        for col in ("SR", "SR_lo", "SR_hi", "CR"):
            nav[f"{p}_{col}"] = a[col]
    return nav.rename_axis("scene").reset_index()


def order_verdicts(table: pd.DataFrame) -> pd.DataFrame:
    """Per measure (and per random init): the values along :func:`gradient_order` and whether they rise strictly.

    Returns DataFrame ``measure, values, holds``.
    """
    order = list(gradient_order())
    t = table.set_index("setting").loc[order]
    measures = [*MEASURES, *sorted(c for c in table.columns if c.startswith("random_mmd_") and c[11:].isdigit())]
    rows = []
    for m in measures:
        v = t[m].to_numpy(np.float64)
        rows.append({"measure": m, "values": " < ".join(f"{x:.3f}" for x in v), "holds": bool(np.all(np.diff(v) > 0))})
    return pd.DataFrame(rows)


@dataclass(repr=False)
class GradientResult:
    """The gradient table, its ordering verdicts, the files written and the wall time (s)."""

    table: pd.DataFrame
    order: pd.DataFrame
    paths: dict[str, Path] = field(default_factory=dict)
    wall_time_s: float = 0.0

    def __repr__(self) -> str:
        with pd.option_context("display.width", 200, "display.max_columns", 30):
            return "\n".join(
                [self.table.round(3).to_string(index=False), "", self.order.to_string(index=False)]
                + [f"{k}: {v}" for k, v in self.paths.items()]
                + [f"{self.wall_time_s:.0f} s"]
            )


def _markdown(table: pd.DataFrame, order: pd.DataFrame, cfg: Config) -> tuple[str, str]:
    def ci(r: Any, p: str) -> str:
        return f"{r[f'{p}_SR']:.0f} [{r[f'{p}_SR_lo']:.0f}, {r[f'{p}_SR_hi']:.0f}] / {r[f'{p}_CR']:.0f}"

    lines = [
        "| setting | role | pixel MMD² | colour JS | random-encoder MMD² (mean [min, max]) | blocked % | detour "
        "| bent % | Hybrid APF SR [CI] / CR | local APF SR [CI] / CR |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, r in table.iterrows():
        role = scene_spec(r.scene).difficulty if r.setting != FLOOR else "floor"
        nav = f"{r.blocked_pct:.1f} | {r.detour:.3f} | {r.bent_pct:.0f} | {ci(r, 'hybrid-apf')} | {ci(r, 'local-apf')}"
        lines.append(
            f"| {r.setting} | {role} | {r.pixel_mmd:.4f} | {r.colour_js:.3f} | {r.random_mmd:.3f} "
            f"[{r.random_mmd_min:.3f}, {r.random_mmd_max:.3f}] | {nav} |"
        )
    n_frames = int(table.frames.min())
    head = (
        f"Shift from box (pilot frames; at least {n_frames} stacks per setting; {cfg.env.image_size} px) and "
        f"navigation on Table I's {cfg.eval.episodes} evaluation layouts per scene. MMD² (RBF, median bandwidth); "
        f"colour JS in bits; SR/CR %.\n\n"
    )
    order_md = ["| measure | box floor < furniture-v1 < barrier-v0 < tree-v0 | holds |", "|---|---|---|"]
    order_md += [f"| {r.measure} | {r['values']} | {'yes' if r.holds else 'no'} |" for _, r in order.iterrows()]
    return head + "\n".join(lines) + "\n", "\n".join(order_md) + "\n"


def gradient_stage(
    cfg: Config, *, episodes: int | None = None, inits: Sequence[int] = (0, 1, 2), progress: bool = True
) -> GradientResult:
    """CLI stage ``gradient``: the tables of the module docstring under ``<run_root>/tables``; needs nothing
    trained. ``episodes``: pilot episodes per setting (default a quarter of ``cfg.eval.episodes``, at least 2);
    ``inits``: seeds of the random encoders (the student's shape at this preset)."""

    t0 = time.perf_counter()
    samples = gradient_samples(cfg, episodes, progress=progress)
    encoders = {int(i): random_encoder(encoder_config(cfg, "ours"), seed=int(i)) for i in inits}
    perc = perceptual_table(samples, encoders)
    nav = navigation_table(cfg, list(SCENE_SPECS), progress=progress)
    perc["scene"] = [s if s in SCENE_SPECS else "box-v0" for s in perc.setting]
    table = perc.merge(nav, on="scene", how="left")
    table = table[["setting", "scene", *[c for c in table.columns if c not in ("setting", "scene")]]]
    order = order_verdicts(table)
    out = cfg.run_root / "tables"
    out.mkdir(parents=True, exist_ok=True)
    md, order_md = _markdown(table, order, cfg)
    paths = {
        "csv": out / "scene_gradient.csv",
        "md": out / "scene_gradient.md",
        "order": out / "scene_gradient_order.md",
    }
    atomic_write_text(paths["csv"], table.to_csv(index=False))
    atomic_write_text(paths["md"], md)
    atomic_write_text(paths["order"], order_md)
    return GradientResult(table, order, paths, time.perf_counter() - t0)
