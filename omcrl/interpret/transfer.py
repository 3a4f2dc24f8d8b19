"""The zero-shot diagnosis as a stage (``python -m omcrl transfer --preset P``; docs/generalization.md).

Why does a student trained in box fail in an unseen scene? ``transfer_stage(cfg)`` measures, for the Table I runs at
``cfg.seeds`` (the encoders at ``cfg.seed``):

    tables/transfer_appearance.{csv,md}  SR of ``ours`` with each scene's layouts in its own and in another look
                                         (geometry vs appearance; ``Disturbance.appearance``), 95 % CIs
    tables/transfer_blind.{csv,md}       SR of ``ours`` with its visual features fixed at the mean box feature
                                         (does goal seeking survive without vision?) beside its SR with vision
    tables/transfer_shift.{csv,md}       feature shift from box (MMD², Fréchet, saturated units) of OMC, CURL and a
                                         random encoder, per setting
    tables/transfer_probe.{csv,md}       the pretraining probe fitted on box pilot frames and tested per setting
    tables/transfer_geometry.{csv,md}    per scene, the geometry of those evaluation layouts (obstacles, share of
                                         the arena occupied and blocked at flight altitude, shortest path; mean
                                         and sd over layouts): how cluttered each scene is, whatever its look
    tables/transfer_detour.{csv,md}      SR/CR of ``ours`` and the ``oracle`` per scene by how far the layout's
                                         shortest path bends from the straight start-goal line (Table I's
                                         episodes): which failures no encoder can fix

Frames come from scripted-pilot flights (Hybrid APF on the true map) with seeds from :data:`PILOT_SEED`, disjoint
from training and evaluation; the SR tables use Table I's evaluation episodes, so their own-look rows are Table I's
cached evaluations.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from omcrl.config import Config
from omcrl.envs.stats import geometry_stats, geometry_summary
from omcrl.eval.runner import eval_seeds
from omcrl.eval.stage import evaluate_methods, to_markdown
from omcrl.eval.stats import aggregate
from omcrl.interpret.shift import encode, pilot_samples, probe_across, shift_table, with_fixed_features
from omcrl.interpret.stage import encoders_for_stability
from omcrl.rl import load_policy
from omcrl.rl.methods import final_policy_path
from omcrl.rl.policy import CheckpointError
from omcrl.utils.io import atomic_write_text
from omcrl.utils.progress import track

PILOT_SEED = 5_000_000
# (setting, layout scene, disturbance): what the shift and probe tables compare with box. "box, other layouts"
# is a second box sample (the sampling floor); the two look-swapped settings hold geometry fixed.
SETTINGS: tuple[tuple[str, str, dict | None], ...] = (
    ("box", "box-v0", None),
    ("box, other layouts", "box-v0", None),
    ("box layout, furniture-v0 look", "box-v0", {"appearance": "furniture-v0"}),
    ("furniture-v0", "furniture-v0", None),
    ("furniture-v0 layout, box look", "furniture-v0", {"appearance": "box-v0"}),
    ("furniture-v1", "furniture-v1", None),
    ("barrier-v0", "barrier-v0", None),
    ("tree-v0", "tree-v0", None),
)
# (layout, look, part swapped): the student's SR with geometry and appearance varied separately. furniture-v1 is
# furniture-v0's layouts in box's room, i.e. the swap of surroundings that v1 makes the default.
SWAPS: tuple[tuple[str, str, str], ...] = (
    ("box-v0", "box-v0", "all"),
    ("box-v0", "furniture-v0", "all"),
    ("box-v0", "furniture-v0", "surroundings"),
    ("box-v0", "furniture-v0", "obstacles"),
    ("furniture-v0", "furniture-v0", "all"),
    ("furniture-v0", "box-v0", "all"),
    ("furniture-v0", "box-v0", "surroundings"),
    ("furniture-v0", "box-v0", "obstacles"),
    ("furniture-v1", "furniture-v1", "all"),
    ("barrier-v0", "barrier-v0", "all"),
    ("barrier-v0", "box-v0", "all"),
    ("tree-v0", "tree-v0", "all"),
    ("tree-v0", "box-v0", "all"),
)


@dataclass(repr=False)
class TransferResult:
    """The four diagnosis tables, the pilot samples behind the last two, and the files written."""

    appearance: pd.DataFrame
    blind: pd.DataFrame
    shift: pd.DataFrame
    probe: pd.DataFrame
    geometry: pd.DataFrame = field(default_factory=pd.DataFrame)
    detour: pd.DataFrame = field(default_factory=pd.DataFrame)
    samples: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    paths: dict[str, Path] = field(default_factory=dict)

    def __repr__(self) -> str:
        with pd.option_context("display.width", 160, "display.max_columns", 20):
            probe = self.probe.groupby(["encoder", "setting"], sort=False)["r2"].mean().unstack(0)
            parts = [
                "-- geometry vs appearance (SR %)",
                self.appearance.round(1).to_string(index=False),
                "-- with the mean box feature instead of vision (SR %)",
                self.blind.round(1).to_string(index=False),
                "-- feature shift from box",
                self.shift.round(3).to_string(index=False),
                "-- box-fitted probe, mean R² over the targets",
                probe.round(2).to_string(),
                "-- scene geometry at flight altitude (mean over the evaluation layouts)",
                self.geometry.round(2).to_string(index=False),
                "-- SR (%) by detour (shortest path / straight line)",
                self.detour.round(1).to_string(index=False),
            ]
        return "\n".join(parts + [f"{k}: {v}" for k, v in self.paths.items()])


def pilot_episodes(cfg: Config) -> int:
    """Pilot episodes per setting (the box reference flies twice as many): a quarter of the evaluation episodes,
    at least 2 (quick: 12)."""
    return max(2, cfg.eval.episodes // 4)


def setting_samples(
    cfg: Config,
    episodes: int | None = None,
    *,
    settings: Sequence[tuple[str, str, dict | None]] = SETTINGS,
    progress: bool = False,
) -> dict[str, dict[str, np.ndarray]]:
    """:func:`omcrl.interpret.shift.pilot_samples` (with the probe's privileged targets) of every setting in
    ``settings`` (``(name, scene, disturbance)``, default :data:`SETTINGS`). The first setting (the reference:
    box) flies twice the episodes on seeds of its own; every other setting flies the seeds of the second ("box,
    other layouts"), so the two look-swapped settings share their geometry with a scene of their own."""

    n = int(episodes if episodes is not None else pilot_episodes(cfg))
    out = {}
    reference = settings[0][0]
    for name, scene, dist in track(settings, desc="transfer/pilot frames", unit="setting", enabled=progress):
        seed, k = (PILOT_SEED + 100, 2 * n) if name == reference else (PILOT_SEED, n)
        out[name] = pilot_samples(scene, k, seed, env_config=cfg.env, disturbance=dist, privileged=True)
    return out


def appearance_table(
    cfg: Config, seeds: Sequence[int] | None = None, method: str = "ours", *, progress: bool = False
) -> pd.DataFrame:
    """SR/CR/NE of ``method`` for every (layout, look, part) of :data:`SWAPS`, over ``seeds`` (default
    ``cfg.seeds``), on Table I's evaluation episodes, with 95 % CIs (seeds and layouts crossed)."""

    frames = []
    seeds = list(seeds if seeds is not None else cfg.seeds)
    jobs = [(s, *swap) for s in seeds for swap in SWAPS]
    for s, layout, look, part in track(jobs, desc="transfer/looks", unit="eval", enabled=progress):
        c = cfg.with_seed(s)
        dist = None if look == layout else {"appearance": look, "appearance_parts": part}
        df = evaluate_methods(c, {method: _policy(c, method)}, [layout], disturbance=dist)
        frames.append(df.assign(setting=f"{layout} | {look} | {part}"))
    ep = pd.concat(frames, ignore_index=True)
    agg = aggregate(ep, ("setting",))
    rows = []
    for (layout, look, part), (_, r) in zip(SWAPS, agg.iterrows(), strict=True):
        shown = look if part == "all" else f"{look} {part}"
        rows.append({"layout": layout, "look": shown, "own look": look == layout, "seeds": int(r.seeds),
                     "SR": r.SR, "SR_lo": r.SR_lo, "SR_hi": r.SR_hi, "CR": r.CR, "NE": r.NE})  # fmt: skip
    return pd.DataFrame(rows)


def blind_table(
    cfg: Config, reference: dict[str, np.ndarray], seeds: Sequence[int] | None = None, method: str = "ours"
) -> pd.DataFrame:
    """SR of ``method`` with vision and with its features fixed at the mean feature of ``reference`` (box pilot
    samples: ``{"rgb": (N, 3L, H, W) uint8}``), per evaluation scene, over ``seeds`` (default ``cfg.seeds``)."""

    frames = []
    for s in seeds if seeds is not None else cfg.seeds:
        c = cfg.with_seed(s)
        path = _policy(c, method)
        policy = load_policy(path, name=method)
        z, _ = encode(policy.agent.features.encoder, reference["rgb"])
        blind = with_fixed_features(policy, z.mean(0))
        frames.append(evaluate_methods(c, {"with vision": path}).assign(method="with vision"))
        frames.append(evaluate_methods(c, {"mean box feature": blind}, cache=False).assign(method="mean box feature"))
    agg = aggregate(pd.concat(frames, ignore_index=True), ("scene", "method"))
    return agg.reset_index()[["scene", "method", "seeds", "SR", "SR_lo", "SR_hi", "CR", "NE"]]


def encoders(cfg: Config, methods: Sequence[str] = ("ours", "curl")) -> dict[str, Any]:
    """The frozen encoders of ``methods`` at ``cfg.seed`` and a random one of ``methods[0]``'s shape.
    A missing one raises :class:`~omcrl.rl.policy.CheckpointError` naming the command that makes it."""

    return encoders_for_stability(cfg, methods)


def transfer_stage(
    cfg: Config,
    *,
    methods: Sequence[str] = ("ours", "curl"),
    episodes: int | None = None,
    progress: bool = True,
) -> TransferResult:
    """CLI stage ``transfer``: the four tables of the module docstring under ``<run_root>/tables``.

    Every input (the ``ours`` runs at ``cfg.seeds``, the encoders of ``methods`` at ``cfg.seed``) is found before
    any episode runs. ``episodes``: pilot episodes per setting (default :func:`pilot_episodes`).
    """

    for s in cfg.seeds:
        for m in ("ours", "oracle"):
            _policy(cfg.with_seed(s), m)  # fail early, before the long parts
    enc = encoders(cfg, methods)
    samples = setting_samples(cfg, episodes, progress=progress)
    appearance = appearance_table(cfg, progress=progress)
    blind = blind_table(cfg, samples["box"])
    shift = shift_table(enc, {k: v["rgb"] for k, v in samples.items()}, reference="box")
    probe = pd.concat([probe_across(e, samples, seed=cfg.seed).assign(encoder=k) for k, e in enc.items()])
    layouts = layout_stats(cfg)  # once, for both tables
    geometry = geometry_table(cfg, layouts)
    detour = detour_table(cfg, stats=layouts)
    out = cfg.run_root / "tables"
    out.mkdir(parents=True, exist_ok=True)
    probe_wide = probe.groupby(["setting", "encoder"], sort=False)["r2"].mean().unstack("encoder")
    paths: dict[str, Path] = {}
    for name, df, md in (
        ("appearance", appearance, to_markdown(appearance.round(2).set_index("layout"), "layout")),
        ("blind", blind, to_markdown(blind.round(2).set_index("scene"), "scene")),
        ("shift", shift, to_markdown(shift.round(3).set_index("encoder"), "encoder")),
        ("probe", probe, to_markdown(probe_wide.round(2).loc[list(dict.fromkeys(probe.setting))], "setting")),
        ("geometry", geometry, to_markdown(geometry.round(2).set_index("scene"), "scene")),
        ("detour", detour, to_markdown(detour.round(1).set_index("method"), "method")),
    ):
        paths[f"transfer_{name}.csv"] = out / f"transfer_{name}.csv"
        paths[f"transfer_{name}.md"] = out / f"transfer_{name}.md"
        atomic_write_text(paths[f"transfer_{name}.csv"], df.to_csv(index=False))
        atomic_write_text(paths[f"transfer_{name}.md"], md)
    return TransferResult(appearance, blind, shift, probe, geometry, detour, samples, paths)


def layout_stats(cfg: Config) -> pd.DataFrame:
    """:func:`omcrl.envs.stats.geometry_stats` of the layouts Table I flies: in every scene of ``cfg.eval.scenes``,
    the ``cfg.eval.episodes`` episode seeds from ``cfg.eval.seed_offset`` that
    :func:`omcrl.eval.stage.evaluate_methods` gives every training seed alike (one row per scene and layout)."""

    seeds = eval_seeds(cfg.eval.episodes, 0, cfg.eval.seed_offset)  # evaluate_methods' seeds, for every cfg.seed
    return pd.concat([geometry_stats(sc, seeds, cfg.env) for sc in cfg.eval.scenes], ignore_index=True)


def geometry_table(cfg: Config, stats: pd.DataFrame | None = None) -> pd.DataFrame:
    """:func:`omcrl.envs.stats.geometry_summary` of Table I's evaluation layouts (``stats``: :func:`layout_stats`,
    computed when not given); one row per scene."""

    return geometry_summary(layout_stats(cfg) if stats is None else stats)


# Bins of a layout's detour, shortest path / straight start-goal line: straight (a clear line, or nearly), a small
# bend (box's evaluation layouts reach 1.08 at most, so training saw these), a real detour, and a long way round.
DETOUR_BINS: tuple[float, ...] = (1.0, 1.02, 1.1, 1.3, float("inf"))


def by_detour(
    episodes: pd.DataFrame, detour: pd.Series, bins: Sequence[float] = DETOUR_BINS, reps: int = 2000
) -> pd.DataFrame:
    """SR and CR per (method, scene, detour bin), with 95 % CIs (seeds and layouts crossed).

    Parameters
    ----------
    episodes : one row per episode (:func:`omcrl.eval.stage.evaluate_methods`): ``method``, ``scene``,
        ``eval_seed``, ``train_seed`` and the metric columns.
    detour : shortest path / straight line (≥ 1) per layout, indexed by (scene, seed) as from
        :func:`omcrl.envs.stats.geometry_stats`; every episode's layout must be in it.
    bins : right-closed bin edges of the detour ratio.

    Returns
    -------
    DataFrame, one row per non-empty group, columns method, scene, detour (bin label), layouts (% of the
    scene's episodes in the bin), episodes, SR, SR_lo, SR_hi, CR (percent).
    """

    keys = pd.MultiIndex.from_arrays([episodes["scene"], episodes["eval_seed"]])
    missing = ~keys.isin(detour.index)
    if missing.any():
        raise ValueError(f"by_detour: no detour for layouts {list(keys[missing][:5])} (scene, eval_seed)")
    edges = list(bins)
    labels = [f"{lo:.2f}–{hi:.2f}" if np.isfinite(hi) else f"> {lo:.2f}" for lo, hi in itertools.pairwise(edges)]
    cut = pd.cut(detour.reindex(keys).to_numpy(), edges, labels=labels, include_lowest=True)
    if pd.isna(cut).any():
        raise ValueError(f"by_detour: detour ratios outside the bins {edges}")
    ep = episodes.assign(detour=np.asarray(cut, dtype=object))
    agg = aggregate(ep, ("method", "scene", "detour"), reps=reps).reset_index()
    total = ep.groupby(["method", "scene"]).size()
    agg["layouts"] = 100.0 * agg.episodes / total.reindex(pd.MultiIndex.from_frame(agg[["method", "scene"]])).values
    order = {b: i for i, b in enumerate(labels)}
    agg = agg.sort_values(["method", "scene", "detour"], key=lambda c: c.map(order) if c.name == "detour" else c)
    cols = ["method", "scene", "detour", "layouts", "episodes", "SR", "SR_lo", "SR_hi", "CR"]
    return agg[cols].reset_index(drop=True)


def detour_table(
    cfg: Config,
    methods: Sequence[str] = ("ours", "oracle"),
    seeds: Sequence[int] | None = None,
    stats: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """:func:`by_detour` of ``methods`` in every scene of ``cfg.eval.scenes`` over ``seeds`` (default
    ``cfg.seeds``), on Table I's evaluation episodes (cached evaluations are read, not flown again); ``stats``:
    :func:`layout_stats`, computed when not given."""

    frames = []
    for s in seeds if seeds is not None else cfg.seeds:
        c = cfg.with_seed(s)
        frames.append(evaluate_methods(c, {m: _policy(c, m) for m in methods}))
    episodes = pd.concat(frames, ignore_index=True)
    geo = (layout_stats(cfg) if stats is None else stats).set_index(["scene", "seed"])
    ratio = geo.shortest_path_m / geo.straight_line_m
    order = {m: i for i, m in enumerate(methods)} | {sc: i for i, sc in enumerate(cfg.eval.scenes)}
    out = by_detour(episodes, ratio)
    return out.sort_values(["method", "scene"], key=lambda c: c.map(order), kind="stable").reset_index(drop=True)


def _policy(cfg: Config, method: str) -> Path:

    path = final_policy_path(cfg, method)
    if path is None:
        raise CheckpointError(
            f"transfer: no finished {method} run at seed {cfg.seed}; run first: "
            f"python -m omcrl train --method {method} --preset {cfg.preset} --seed {cfg.seed}"
        )
    return path
