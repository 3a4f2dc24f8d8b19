"""The scenes' gradient of difficulty, measured with nothing learned (``python -m omcrl gradient --preset P``).

The paper's four scenes form "a gradient of perceptual and navigational difficulty" (V-A): box (training) <
furniture (easy) < barrier (medium) < tree (hard). Whether a scene suite follows it must be settled before any
learned method flies it, so no learned method's success can pick the scenes. ``gradient_stage(cfg)`` writes

    tables/scene_gradient.{csv,md}    per setting of the default suite (v2): the perceptual shift from its box and
                                      the navigational difficulty
    tables/scene_gradient_order.md    does each measure order box < furniture < barrier < tree?
    tables/scene_navigation.{csv,md}  navigation with nothing learned, every suite (v1, v2) side by side
    tables/scene_criteria.{csv,md}    the suite criteria (:data:`CRITERIA`) with 95 % Wilson intervals, per suite

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
the share of the arena blocked at flight altitude, the detour (shortest path / straight line, mean and the shares
of layouts bending by more than 2 % and 10 %), the difficulty measures of :mod:`omcrl.envs.difficulty` (narrowest
corridor, view occlusion, turning per metre), and the success and collision rates of four planners from no
sensing to the true map: the blind pilot, the local APF on the depth camera (NPE's non-expert guide), the Hybrid
APF on the map its depth camera has seen, and the privileged Hybrid APF (global path on the true map).

**Criteria** (scenes v2, fixed before any learned method flew them): on layouts no table uses
(:data:`CRITERIA_SEED_OFFSET`), the blind pilot fails, the privileged Hybrid APF succeeds, the local APF stays a
non-expert that is worth following in box, and box's layouts hold detours (:data:`CRITERIA`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from omcrl import planners
from omcrl.config import Config
from omcrl.envs.difficulty import difficulty_stats
from omcrl.envs.stats import geometry_stats
from omcrl.eval.runner import EvalPool, eval_seeds, evaluate
from omcrl.eval.stage import evaluate_methods
from omcrl.eval.stats import aggregate
from omcrl.interpret.shift import encode, mmd_rbf, pilot_frames
from omcrl.interpret.transfer import PILOT_SEED, pilot_episodes
from omcrl.models.artifact import random_encoder
from omcrl.rl.methods import encoder_config
from omcrl.scenes import DEFAULT_SUITE, STRESS_SCENES, SUITES, scene_spec
from omcrl.utils.io import atomic_write_text
from omcrl.utils.progress import track

REFERENCE = "box"
FLOOR = "box, other layouts"
PIXEL_SIDE = 8
HIST_BINS = 8
# The navigation table's planners, from no sensing to the true map: every planner of the kit.
PLANNERS = tuple(planners.PLANNERS)
MEASURES = ("random_mmd", "pixel_mmd", "colour_js")
# Layouts of the suite criteria: episode seeds from here on, which no table, training or pilot uses.
CRITERIA_SEED_OFFSET = 7_000_000


def gradient_order(suite: str = DEFAULT_SUITE) -> tuple[str, ...]:
    """The settings whose measures must rise in this order on the paper's gradient: the box floor, then the
    suite's evaluation scenes (v2: ``furniture-v2`` < ``barrier-v2`` < ``tree-v2``)."""
    return (FLOOR, *SUITES[suite][1:])


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


def gradient_samples(
    cfg: Config, episodes: int | None = None, *, suite: str = DEFAULT_SUITE, progress: bool = False
) -> dict[str, np.ndarray]:
    """Pilot RGB stacks (N, 3L, H, W) uint8 per setting: the reference, the suite's box (twice the episodes, its
    own seeds), "box, other layouts", the suite's other scenes and the stress scenes; the settings other than the
    reference fly the same seeds."""

    n = int(episodes if episodes is not None else pilot_episodes(cfg))
    box = SUITES[suite][0]
    settings = [(REFERENCE, box), (FLOOR, box)]
    settings += [(s, s) for s in (*SUITES[suite][1:], *STRESS_SCENES)]
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
    """Per scene, on Table I's evaluation layouts (``cfg.eval.episodes`` seeds from ``cfg.eval.seed_offset``):

    ``blocked_pct`` (mean % of the arena blocked at flight altitude), ``detour`` (mean shortest path / straight
    line), ``bent_pct`` and ``bent10_pct`` (% of layouts with detour > 1.02 and > 1.10), the difficulty measures of
    :mod:`omcrl.envs.difficulty` (``corridor_m``: median narrowest corridor, m; ``occlusion``: mean view
    occlusion, 0-1; ``turning_rad_m``: mean angle over length, rad/m), and SR / CR (%) with 95 % CIs of each
    planner of :data:`PLANNERS` (evaluations cached as Table I's).
    """

    seeds = eval_seeds(cfg.eval.episodes, 0, cfg.eval.seed_offset)
    geo = pd.concat([geometry_stats(s, seeds, cfg.env) for s in scenes], ignore_index=True)
    dif = pd.concat([difficulty_stats(s, seeds, cfg.env) for s in scenes], ignore_index=True)
    g, d = geo.groupby("scene", sort=False), dif.groupby("scene", sort=False)
    nav = pd.DataFrame(
        {
            "blocked_pct": g.blocked_pct.mean(),
            "detour": d.detour.mean(),
            "bent_pct": d.detour.apply(lambda x: 100.0 * float((x > 1.02).mean())),
            "bent10_pct": d.detour.apply(lambda x: 100.0 * float((x > 1.10).mean())),
            "corridor_m": d.corridor_m.median(),
            "occlusion": d.occlusion.mean(),
            "turning_rad_m": d.turning_rad_m.mean(),
        }
    )
    ep = evaluate_methods(cfg, {p: p for p in PLANNERS}, list(scenes), progress=progress)
    agg = aggregate(ep, ("method", "scene"))
    for p in PLANNERS:
        a = agg.xs(p, level="method")
        for col in ("SR", "SR_lo", "SR_hi", "CR"):
            nav[f"{p}_{col}"] = a[col]
    return nav.rename_axis("scene").reset_index()


@dataclass(frozen=True)
class Criterion:
    """One bound a suite must meet before any learned method flies it: ``measure`` of ``scenes`` (``"unseen"``:
    the suite's scenes but the training one; ``"all"``; ``"training"``) compared ``op`` (``<=`` or ``>=``) with
    ``bound`` (%)."""

    name: str
    measure: str
    scenes: str
    op: str
    bound: float


# The v2 suite's criteria (fixed before any learned method flew it): a blind pilot fails everywhere, the map planner
# succeeds everywhere, the local potential field stays a non-expert that is still worth following in box, and box's
# layouts hold detours a policy can learn. The perceptual order is checked by order_verdicts.
CRITERIA = (
    Criterion("a blind pilot fails", "blind_SR", "all", "<=", 20.0),
    Criterion("every layout is solvable with the map", "hybrid-apf_SR", "all", ">=", 90.0),
    Criterion("the local APF is a non-expert", "local-apf_SR", "all", "<=", 70.0),
    Criterion("the local APF is a guide worth following in box", "local-apf_SR", "training", ">=", 20.0),
    Criterion("box holds detours (> 1.10)", "bent10_pct", "training", ">=", 30.0),
)
CRITERIA_PLANNERS = ("blind", "local-apf", "hybrid-apf")


def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval (%, %) of ``k`` successes in ``n`` independent trials."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    c = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    m = (p + z * z / (2 * n)) / (1 + z * z / n)
    return (100.0 * max(0.0, m - c), 100.0 * min(1.0, m + c))


def criteria_table(
    cfg: Config,
    suites: Sequence[str] = (DEFAULT_SUITE,),
    layouts: int = 100,
    *,
    scenes: Sequence[str] | None = None,
    seed_offset: int = CRITERIA_SEED_OFFSET,
    progress: bool = False,
) -> pd.DataFrame:
    """The :data:`CRITERIA` on ``layouts`` layouts per scene that no table uses (episode seeds from
    ``seed_offset``), for each suite of ``suites``.

    Each planner of :data:`CRITERIA_PLANNERS` flies each layout once (they are deterministic); the detour share is
    over the same layouts. ``scenes`` keeps only those of the suites' scenes. Returns one row per (suite,
    criterion, scene): ``value`` (%), its 95 % Wilson interval
    ``lo``, ``hi`` (layouts are independent draws), ``bound``, ``op`` and ``holds`` (the value meets the bound).
    """

    seeds = eval_seeds(layouts, 0, seed_offset)
    jobs = [(suite, sc) for suite in suites for sc in SUITES[suite] if scenes is None or sc in scenes]
    with EvalPool(cfg.eval.workers) as pool:
        rows = _criteria_rows(cfg, jobs, seeds, layouts, seed_offset, pool, progress)
    return pd.DataFrame(rows)


def _criteria_rows(
    cfg: Config, jobs: list, seeds: list[int], layouts: int, seed_offset: int, pool: EvalPool, progress: bool
) -> list[dict]:
    rows = []
    for suite, sc in track(jobs, desc="gradient/criteria", unit="scene", enabled=progress):
        counts: dict[str, tuple[int, int]] = {}
        det = difficulty_stats(sc, seeds, cfg.env).detour.to_numpy()
        counts["bent10_pct"] = (int((det > 1.10).sum()), len(det))
        for p in CRITERIA_PLANNERS:
            ep = evaluate(
                planners.make_planner(p), sc, layouts, 0, seed_offset=seed_offset, workers=pool, config=cfg.env
            )
            counts[f"{p}_SR"] = (int(ep.success.sum()), len(ep))
        training = scene_spec(sc).difficulty == "training"
        for c in CRITERIA:
            if (c.scenes == "training" and not training) or (c.scenes == "unseen" and training):
                continue
            k, n = counts[c.measure]
            value = 100.0 * k / n
            lo, hi = wilson(k, n)
            holds = value <= c.bound if c.op == "<=" else value >= c.bound
            row = {"suite": suite, "criterion": c.name, "scene": sc, "measure": c.measure, "value": value}
            rows.append({**row, "lo": lo, "hi": hi, "op": c.op, "bound": c.bound, "holds": bool(holds), "layouts": n})
    return rows


def order_verdicts(table: pd.DataFrame, suite: str = DEFAULT_SUITE) -> pd.DataFrame:
    """Per measure (and per random init): the values along :func:`gradient_order` and whether they rise strictly.

    Returns DataFrame ``measure, values, holds``.
    """
    order = list(gradient_order(suite))
    t = table.set_index("setting").loc[order]
    measures = [*MEASURES, *sorted(c for c in table.columns if c.startswith("random_mmd_") and c[11:].isdigit())]
    rows = []
    for m in measures:
        v = t[m].to_numpy(np.float64)
        rows.append({"measure": m, "values": " < ".join(f"{x:.3f}" for x in v), "holds": bool(np.all(np.diff(v) > 0))})
    return pd.DataFrame(rows)


@dataclass(repr=False)
class GradientResult:
    """The gradient table of one suite, its ordering verdicts, the navigation table of every suite side by side,
    the suite criteria, the files written and the wall time (s)."""

    table: pd.DataFrame
    order: pd.DataFrame
    navigation: pd.DataFrame = field(default_factory=pd.DataFrame)
    criteria: pd.DataFrame = field(default_factory=pd.DataFrame)
    paths: dict[str, Path] = field(default_factory=dict)
    wall_time_s: float = 0.0

    def __repr__(self) -> str:
        with pd.option_context("display.width", 200, "display.max_columns", 40):
            parts = [self.table.round(3).to_string(index=False), "", self.order.to_string(index=False), ""]
            if len(self.navigation):
                parts += [self.navigation.round(3).to_string(index=False), ""]
            if len(self.criteria):
                parts += [self.criteria.round(1).to_string(index=False), ""]
            return "\n".join(parts + [f"{k}: {v}" for k, v in self.paths.items()] + [f"{self.wall_time_s:.0f} s"])


def _ci(r: Any, p: str) -> str:
    return f"{r[f'{p}_SR']:.0f} [{r[f'{p}_SR_lo']:.0f}, {r[f'{p}_SR_hi']:.0f}] / {r[f'{p}_CR']:.0f}"


def _markdown(table: pd.DataFrame, order: pd.DataFrame, cfg: Config, suite: str) -> tuple[str, str]:
    lines = [
        "| setting | role | pixel MMD² | colour JS | random-encoder MMD² (mean [min, max]) | blocked % | detour "
        "| bent % | Hybrid APF SR [CI] / CR | local APF SR [CI] / CR | blind SR [CI] / CR |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, r in table.iterrows():
        role = scene_spec(r.scene).difficulty if r.setting != FLOOR else "floor"
        nav = (
            f"{r.blocked_pct:.1f} | {r.detour:.3f} | {r.bent_pct:.0f} | {_ci(r, 'hybrid-apf')} | {_ci(r, 'local-apf')} "
            f"| {_ci(r, 'blind')}"
        )
        lines.append(
            f"| {r.setting} | {role} | {r.pixel_mmd:.4f} | {r.colour_js:.3f} | {r.random_mmd:.3f} "
            f"[{r.random_mmd_min:.3f}, {r.random_mmd_max:.3f}] | {nav} |"
        )
    n_frames = int(table.frames.min())
    head = (
        f"Suite {suite}: shift from {SUITES[suite][0]} (pilot frames; at least {n_frames} stacks per setting; "
        f"{cfg.env.image_size} px) and navigation on Table I's {cfg.eval.episodes} evaluation layouts per scene. "
        "MMD² (RBF, median bandwidth); colour JS in bits; SR/CR %.\n\n"
    )
    names = " < ".join(gradient_order(suite))
    order_md = [f"| measure | {names} | holds |", "|---|---|---|"]
    order_md += [f"| {r.measure} | {r['values']} | {'yes' if r.holds else 'no'} |" for _, r in order.iterrows()]
    return head + "\n".join(lines) + "\n", "\n".join(order_md) + "\n"


def navigation_markdown(nav: pd.DataFrame, cfg: Config) -> str:
    """The navigation table of every suite, side by side (a row per scene, suites in order)."""
    suite_of = {sc: su for su, scs in SUITES.items() for sc in scs}
    lines = [
        f"Navigation with nothing learned, on Table I's {cfg.eval.episodes} evaluation layouts per scene. SR [95 % CI] "
        "/ CR, %; detour = shortest path / straight line; corridor = median narrowest free width across the "
        "shortest path (m); occlusion = mean share of the path ahead hidden from the camera; turning = rad per m "
        "of shortest path.\n",
        "| suite | scene | role | blind | local APF | perceptive Hybrid APF | Hybrid APF | detour | > 1.02 % | "
        "> 1.10 % | corridor m | occlusion | turning rad/m |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, r in nav.iterrows():
        lines.append(
            f"| {suite_of.get(r.scene, 'stress')} | {r.scene} | {scene_spec(r.scene).difficulty} | {_ci(r, 'blind')} "
            f"| {_ci(r, 'local-apf')} | {_ci(r, 'hybrid-apf-perceptive')} | {_ci(r, 'hybrid-apf')} | {r.detour:.3f} "
            f"| {r.bent_pct:.0f} | {r.bent10_pct:.0f} | {r.corridor_m:.2f} | {r.occlusion:.3f} | "
            f"{r.turning_rad_m:.3f} |"
        )
    return "\n".join(lines) + "\n"


def criteria_markdown(crit: pd.DataFrame, order: pd.DataFrame, suite: str) -> str:
    """The suite criteria as one table: value [95 % Wilson CI] against its bound, per scene, and the perceptual
    order of ``suite`` (``order``, from :func:`order_verdicts`)."""
    n = int(crit.layouts.max()) if len(crit) else 0
    lines = [
        f"Suite criteria on {n} layouts per scene that no table uses (episode seeds from {CRITERIA_SEED_OFFSET}); "
        "value [95 % Wilson CI], %.\n",
        "| suite | criterion | scene | value [CI] | bound | holds |",
        "|---|---|---|---|---|---|",
    ]
    for _, r in crit.iterrows():
        lines.append(
            f"| {r.suite} | {r.criterion} | {r.scene} | {r.value:.1f} [{r.lo:.1f}, {r.hi:.1f}] | {r.op} "
            f"{r.bound:.0f} | {'yes' if r.holds else 'no'} |"
        )
    for _, r in order.iterrows():
        if r.measure in ("pixel_mmd", "random_mmd"):
            lines.append(
                f"| {suite} | box < furniture < barrier < tree: {r.measure} | {' < '.join(gradient_order(suite))} "
                f"| {r['values']} | rising | {'yes' if r.holds else 'no'} |"
            )
    return "\n".join(lines) + "\n"


def gradient_stage(
    cfg: Config,
    *,
    episodes: int | None = None,
    inits: Sequence[int] = (0, 1, 2),
    suite: str = DEFAULT_SUITE,
    layouts: int | None = None,
    progress: bool = True,
) -> GradientResult:
    """CLI stage ``gradient``: the tables of the module docstring under ``<run_root>/tables``; needs nothing
    trained. ``episodes``: pilot episodes per setting (default a quarter of ``cfg.eval.episodes``, at least 2);
    ``inits``: seeds of the random encoders (the student's shape at this preset); ``suite``: whose perceptual
    gradient heads the tables; ``layouts``: layouts per scene of the criteria (default twice ``cfg.eval.episodes``:
    100 at quick; 0 skips them)."""

    t0 = time.perf_counter()
    samples = gradient_samples(cfg, episodes, suite=suite, progress=progress)
    encoders = {int(i): random_encoder(encoder_config(cfg, "ours"), seed=int(i)) for i in inits}
    perc = perceptual_table(samples, encoders)
    scenes = list(dict.fromkeys([*(sc for scs in SUITES.values() for sc in scs), *STRESS_SCENES]))
    nav = navigation_table(cfg, scenes, progress=progress)
    perc["scene"] = [s if s in scenes else SUITES[suite][0] for s in perc.setting]
    table = perc.merge(nav, on="scene", how="left")
    table = table[["setting", "scene", *[c for c in table.columns if c not in ("setting", "scene")]]]
    order = order_verdicts(table, suite)
    layouts = 2 * cfg.eval.episodes if layouts is None else int(layouts)
    crit = criteria_table(cfg, tuple(SUITES), layouts, progress=progress) if layouts else pd.DataFrame()
    out = cfg.run_root / "tables"
    out.mkdir(parents=True, exist_ok=True)
    md, order_md = _markdown(table, order, cfg, suite)
    paths = {
        "csv": out / "scene_gradient.csv",
        "md": out / "scene_gradient.md",
        "order": out / "scene_gradient_order.md",
        "navigation_csv": out / "scene_navigation.csv",
        "navigation": out / "scene_navigation.md",
    }
    atomic_write_text(paths["csv"], table.to_csv(index=False))
    atomic_write_text(paths["md"], md)
    atomic_write_text(paths["order"], order_md)
    atomic_write_text(paths["navigation_csv"], nav.to_csv(index=False))
    atomic_write_text(paths["navigation"], navigation_markdown(nav, cfg))
    if len(crit):
        paths["criteria_csv"], paths["criteria"] = out / "scene_criteria.csv", out / "scene_criteria.md"
        atomic_write_text(paths["criteria_csv"], crit.to_csv(index=False))
        atomic_write_text(paths["criteria"], criteria_markdown(crit, order, suite))
    return GradientResult(table, order, nav, crit, paths, time.perf_counter() - t0)
