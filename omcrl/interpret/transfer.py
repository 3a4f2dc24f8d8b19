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
from omcrl.scenes import SUITES, is_stress, scene_id, suite_of
from omcrl.utils.io import atomic_write_text
from omcrl.utils.progress import track

PILOT_SEED = 5_000_000


def _suite_scenes(cfg: Config) -> tuple[str, list[str], list[str]]:
    """The training scene of ``cfg``'s policies, the unseen scenes of its suite, and the stress scenes evaluated."""
    train = scene_id(cfg.env.scene)
    suite = suite_of(train)
    evaluated = [scene_id(s) for s in cfg.eval.scenes]
    if suite is None:  # a box of no published suite: the evaluated scenes stand in for its unseen ones
        unseen = [s for s in evaluated if s != train and not is_stress(s)]
    else:
        unseen = [scene_id(s) for s in SUITES[suite][1:]]
    if not unseen:
        raise ValueError(f"transfer: no unseen scene to compare with {train} (eval.scenes: {evaluated})")
    return train, unseen, [s for s in evaluated if is_stress(s)]


def transfer_settings(cfg: Config) -> tuple[tuple[str, str, dict | None], ...]:
    """(setting, layout scene, disturbance) of the shift and probe tables, in the suite of ``cfg``'s policies
    (training scene ``cfg.env.scene``; box-v2's suite by default): the training scene (the reference), its other
    layouts (the sampling floor), the first unseen scene's look on the training layouts and the training look on
    its layouts (geometry held fixed), then each unseen and stress scene as it is. Each is named by its scene id."""
    train, unseen, stress = _suite_scenes(cfg)
    first = unseen[0]
    return (
        (train, train, None),
        (f"{train}, other layouts", train, None),
        (f"{train} layout, {first} look", train, {"appearance": first}),
        (first, first, None),
        (f"{first} layout, {train} look", first, {"appearance": train}),
        *((s, s, None) for s in [*unseen[1:], *stress]),
    )


def transfer_swaps(cfg: Config) -> tuple[tuple[str, str, str], ...]:
    """(layout, look, part swapped) of the SR table, in the suite of ``cfg``'s policies: the training scene and the
    first unseen scene each in its own look, the other's whole look, its surroundings alone and its obstacles alone;
    each other unseen scene in its own look and in the training scene's."""
    train, unseen, _ = _suite_scenes(cfg)
    first = unseen[0]
    out = [(train, train, "all"), *((train, first, part) for part in ("all", "surroundings", "obstacles"))]
    out += [(first, first, "all"), *((first, train, part) for part in ("all", "surroundings", "obstacles"))]
    for s in unseen[1:]:
        out += [(s, s, "all"), (s, train, "all")]
    return tuple(out)


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
    settings: Sequence[tuple[str, str, dict | None]] | None = None,
    progress: bool = False,
) -> dict[str, dict[str, np.ndarray]]:
    """:func:`omcrl.interpret.shift.pilot_samples` (with the probe's privileged targets) of every setting in
    ``settings`` (``(name, scene, disturbance)``, default :func:`transfer_settings` of ``cfg``). The first setting (the
    reference: the training scene) flies twice the episodes on seeds of its own; every other setting flies the seeds
    of the second (its other layouts), so the two look-swapped settings share their geometry with a scene of their
    own."""

    n = int(episodes if episodes is not None else pilot_episodes(cfg))
    out = {}
    chosen = settings if settings is not None else transfer_settings(cfg)
    reference = chosen[0][0]
    for name, scene, dist in track(chosen, desc="transfer/pilot frames", unit="setting", enabled=progress):
        seed, k = (PILOT_SEED + 100, 2 * n) if name == reference else (PILOT_SEED, n)
        out[name] = pilot_samples(scene, k, seed, env_config=cfg.env, disturbance=dist, privileged=True)
    return out


def appearance_table(
    cfg: Config, seeds: Sequence[int] | None = None, method: str = "ours", *, progress: bool = False
) -> pd.DataFrame:
    """SR/CR/NE of ``method`` for every (layout, look, part) of :func:`transfer_swaps` of ``cfg``, over ``seeds``
    (default ``cfg.seeds``), on Table I's evaluation episodes, with 95 % CIs (seeds and layouts crossed)."""

    frames = []
    seeds = list(seeds if seeds is not None else cfg.seeds)
    chosen = transfer_swaps(cfg)
    jobs = [(s, *swap) for s in seeds for swap in chosen]
    for s, layout, look, part in track(jobs, desc="transfer/looks", unit="eval", enabled=progress):
        c = cfg.with_seed(s)
        dist = None if look == layout else {"appearance": look, "appearance_parts": part}
        df = evaluate_methods(c, {method: _policy(c, method)}, [layout], disturbance=dist)
        frames.append(df.assign(setting=f"{layout} | {look} | {part}"))
    ep = pd.concat(frames, ignore_index=True)
    agg = aggregate(ep, ("setting",))
    rows = []
    for (layout, look, part), (_, r) in zip(chosen, agg.iterrows(), strict=True):
        shown = look if part == "all" else f"{look} {part}"
        rows.append({"layout": layout, "look": shown, "own look": look == layout, "seeds": int(r.seeds),
                     "SR": r.SR, "SR_lo": r.SR_lo, "SR_hi": r.SR_hi, "CR": r.CR, "NE": r.NE})  # fmt: skip
    return pd.DataFrame(rows)


def blind_table(
    cfg: Config, reference: dict[str, np.ndarray], seeds: Sequence[int] | None = None, method: str = "ours"
) -> pd.DataFrame:
    """SR of ``method`` with vision and with its features fixed at the mean feature of ``reference`` (pilot samples
    of the training scene: ``{"rgb": (N, 3L, H, W) uint8}``), per evaluation scene, over ``seeds`` (default
    ``cfg.seeds``). The fixed-feature rows are labelled ``mean <training scene> feature``."""

    frames = []
    for s in seeds if seeds is not None else cfg.seeds:
        c = cfg.with_seed(s)
        path = _policy(c, method)
        policy = load_policy(path, name=method)
        z, _ = encode(policy.agent.features.encoder, reference["rgb"])
        blind = with_fixed_features(policy, z.mean(0))
        frames.append(evaluate_methods(c, {"with vision": path}).assign(method="with vision"))
        label = f"mean {scene_id(c.env.scene)} feature"
        frames.append(evaluate_methods(c, {label: blind}, cache=False).assign(method=label))
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
    reference = next(iter(samples))  # the training scene
    appearance = appearance_table(cfg, progress=progress)
    blind = blind_table(cfg, samples[reference])
    shift = shift_table(enc, {k: v["rgb"] for k, v in samples.items()}, reference=reference)
    probe = pd.concat(
        [probe_across(e, samples, reference=reference, seed=cfg.seed).assign(encoder=k) for k, e in enc.items()]
    )
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


def with_detour_bins(
    episodes: pd.DataFrame, detour: pd.Series, bins: Sequence[float] = DETOUR_BINS
) -> tuple[pd.DataFrame, list[str]]:
    """``episodes`` with a column ``detour``: the label of its layout's detour bin (``detour`` and ``bins`` as in
    :func:`by_detour`), and the labels in the bins' order."""
    keys = pd.MultiIndex.from_arrays([episodes["scene"], episodes["eval_seed"]])
    missing = ~keys.isin(detour.index)
    if missing.any():
        raise ValueError(f"by_detour: no detour for layouts {list(keys[missing][:5])} (scene, eval_seed)")
    edges = list(bins)
    labels = [f"{lo:.2f}–{hi:.2f}" if np.isfinite(hi) else f"> {lo:.2f}" for lo, hi in itertools.pairwise(edges)]
    cut = pd.cut(detour.reindex(keys).to_numpy(), edges, labels=labels, include_lowest=True)
    if pd.isna(cut).any():
        raise ValueError(f"by_detour: detour ratios outside the bins {edges}")
    return episodes.assign(detour=np.asarray(cut, dtype=object)), labels


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
    scene's episodes in the bin), episodes, SR, SR_lo, SR_hi, CR, TO (percent; TO: episodes that ran out of steps,
    neither reaching the goal nor colliding nor leaving the arena).
    """

    ep, labels = with_detour_bins(episodes, detour, bins)
    agg = aggregate(ep, ("method", "scene", "detour"), reps=reps).reset_index()
    left = ep["out_of_arena"].astype(bool) if "out_of_arena" in ep else False  # rows from before the column
    ended = ep["success"].astype(bool) | ep["collision"].astype(bool) | left
    timeouts = (~ended).groupby([ep["method"], ep["scene"], ep["detour"]], sort=False).mean() * 100.0
    agg["TO"] = timeouts.reindex(pd.MultiIndex.from_frame(agg[["method", "scene", "detour"]])).to_numpy()
    total = ep.groupby(["method", "scene"]).size()
    agg["layouts"] = 100.0 * agg.episodes / total.reindex(pd.MultiIndex.from_frame(agg[["method", "scene"]])).values
    order = {b: i for i, b in enumerate(labels)}
    agg = agg.sort_values(["method", "scene", "detour"], key=lambda c: c.map(order) if c.name == "detour" else c)
    cols = ["method", "scene", "detour", "layouts", "episodes", "SR", "SR_lo", "SR_hi", "CR", "TO"]
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
