"""Aggregates across training seeds with 95% confidence intervals, and significance of SR differences.

Every metric of the paper is a mean of a per-episode value (:func:`episode_values`): NE = final distance (m),
OS/SR/CR = 100·indicator (%), SPL = I·ℓ/max(d, ℓ), TTS = steps of a successful episode (undefined otherwise,
so its mean is over successful episodes only).

Confidence intervals come from a **two-stage (hierarchical) bootstrap**: each replicate draws training seeds
with replacement, then, within each drawn seed, that seed's evaluation episodes with replacement, and takes
the metric over all drawn episodes. Both sources of variation — which seed was trained and which episodes
were drawn — enter the interval, and each seed's episodes stay within their seed (stratified). We do not use
``rliable`` here: its stratified bootstrap resamples whole runs per task from a (runs × tasks) score matrix and
has no level for the episodes inside a run, which with 3 seeds would leave an interval of 3 points.
With one seed the interval reflects episode sampling only; say so when reporting it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from omcrl.eval.metrics import METRICS, episode_values

DEFAULT_REPS = 2000


def bootstrap_means(
    groups: Sequence[np.ndarray], reps: int = DEFAULT_REPS, rng: np.random.Generator | None = None
) -> np.ndarray:
    """Two-stage bootstrap replicates of the mean of ``groups`` (one 1-D array of episode values per seed).

    NaNs are left out of the mean (TTS of failed episodes); a replicate with no value at all is NaN.
    Returns (reps,) float64.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    groups = [np.asarray(g, float) for g in groups if len(g)]
    k = len(groups)
    if k == 0:
        return np.full(reps, math.nan)
    # For every seed: resampled sums and counts of its finite values, one per (replicate, slot).
    sums = np.empty((k, reps, k))
    counts = np.empty((k, reps, k))
    for s, g in enumerate(groups):
        idx = rng.integers(len(g), size=(reps, k, len(g)))
        v = g[idx]
        ok = np.isfinite(v)
        sums[s] = np.where(ok, v, 0.0).sum(-1)
        counts[s] = ok.sum(-1)
    pick = rng.integers(k, size=(reps, k))  # which seed fills each slot of each replicate
    r, j = np.meshgrid(np.arange(reps), np.arange(k), indexing="ij")
    tot, cnt = sums[pick, r, j].sum(1), counts[pick, r, j].sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, tot / np.maximum(cnt, 1), math.nan)


def mean_ci(
    groups: Sequence[np.ndarray], reps: int = DEFAULT_REPS, conf: float = 0.95, rng: np.random.Generator | None = None
) -> tuple[float, float, float]:
    """(mean over all episodes, lower, upper) with the two-stage bootstrap percentile interval."""
    allv = np.concatenate([np.asarray(g, float) for g in groups]) if len(groups) else np.zeros(0)
    if not np.isfinite(allv).any():
        return math.nan, math.nan, math.nan
    boot = bootstrap_means(groups, reps, rng)
    boot = boot[np.isfinite(boot)]
    a = (1.0 - conf) / 2.0
    return float(np.nanmean(allv)), float(np.quantile(boot, a)), float(np.quantile(boot, 1.0 - a))


def aggregate(
    episodes: pd.DataFrame,
    by: Sequence[str] = ("method", "scene"),
    os_threshold: float = 0.5,
    reps: int = DEFAULT_REPS,
    seed: int = 0,
) -> pd.DataFrame:
    """Mean and 95% CI of each metric per group, over seeds and episodes.

    Parameters
    ----------
    episodes : one row per episode with ``train_seed`` (the training seed) and the columns of ``by``.
    by : grouping columns; groups keep their order of first appearance.

    Returns
    -------
    DataFrame indexed by ``by`` with columns ``<metric>``, ``<metric>_lo``, ``<metric>_hi`` for NE OS SR SPL
    CR TTS, plus ``seeds`` (count) and ``episodes`` (count).
    """
    rng = np.random.default_rng(seed)
    vals = episode_values(episodes, os_threshold)
    rows = {}
    for key, g in episodes.groupby(list(by), sort=False):
        v = vals.loc[g.index]
        seeds = g["train_seed"].to_numpy() if "train_seed" in g else np.zeros(len(g), int)
        row: dict[str, float] = {}
        for m in METRICS:
            groups = [v[m].to_numpy()[seeds == s] for s in dict.fromkeys(seeds)]
            row[m], row[f"{m}_lo"], row[f"{m}_hi"] = mean_ci(groups, reps, rng=rng)
        row["seeds"], row["episodes"] = len(set(seeds.tolist())), len(g)
        rows[key if isinstance(key, tuple) else (key,)] = row
    out = pd.DataFrame.from_dict(rows, orient="index")
    out.index = pd.MultiIndex.from_tuples(list(rows), names=list(by))
    return out


def compare_sr(
    episodes: pd.DataFrame,
    reference: str = "ours",
    scenes: Sequence[str] | None = None,
    reps: int = DEFAULT_REPS,
    seed: int = 0,
    alpha: float = 0.05,
) -> pd.DataFrame:
    """SR of ``reference`` minus SR of every other method, per scene, with a bootstrap CI and p-value.

    Each method's SR is bootstrapped independently with the two-stage scheme; the difference's percentile
    interval and the two-sided bootstrap p-value ``2·min(P(Δ ≤ 0), P(Δ ≥ 0))`` decide the statement.

    Returns
    -------
    DataFrame with columns scene, method, diff (percentage points), lo, hi, p, significant (bool), statement.
    """
    rng = np.random.default_rng(seed)
    if reference not in set(episodes["method"]):
        raise KeyError(f"compare_sr: reference method {reference!r} has no episodes")
    scenes = list(scenes or dict.fromkeys(episodes["scene"]))
    out = []
    for scene in scenes:
        sub = episodes[episodes.scene == scene]

        def groups(method: str, sub: pd.DataFrame = sub) -> list[np.ndarray]:
            g = sub[sub.method == method]
            seeds = g["train_seed"] if "train_seed" in g else pd.Series(0, index=g.index)
            return [100.0 * g.loc[seeds == s, "success"].astype(float).to_numpy() for s in dict.fromkeys(seeds)]

        ref = groups(reference)
        if not ref:
            continue
        ref_boot = bootstrap_means(ref, reps, rng)
        ref_mean = float(np.mean(np.concatenate(ref)))
        for method in dict.fromkeys(sub["method"]):
            if method == reference:
                continue
            other = groups(method)
            diff_boot = ref_boot - bootstrap_means(other, reps, rng)
            diff = ref_mean - float(np.mean(np.concatenate(other)))
            lo, hi = (float(q) for q in np.quantile(diff_boot, [alpha / 2, 1 - alpha / 2]))
            p = float(min(1.0, 2.0 * min((diff_boot <= 0).mean(), (diff_boot >= 0).mean())))
            sig = lo > 0 or hi < 0
            rel = (">" if diff > 0 else "<") if sig else "≈"
            verdict = "significant" if sig else "not significant"
            out.append(
                {
                    "scene": scene,
                    "method": method,
                    "diff": diff,
                    "lo": lo,
                    "hi": hi,
                    "p": p,
                    "significant": sig,
                    "statement": f"{scene}: {reference} {rel} {method} in SR by {diff:+.1f} pp "
                    f"[{lo:+.1f}, {hi:+.1f}], p={p:.3f} ({verdict} at {1 - alpha:.0%})",
                }
            )
    return pd.DataFrame(out, columns=["scene", "method", "diff", "lo", "hi", "p", "significant", "statement"])
