"""Episode metrics NE, OS, SR, SPL, CR, TTS (paper V-B) and the method × scene table (paper Table I).

Input is a tidy DataFrame with one row per episode and at least the columns ``final_distance`` (m),
``min_distance`` (m), ``success`` (bool), ``collision`` (bool), ``path_length`` (m, executed),
``optimal_path_length`` (m, shortest feasible path) and ``steps``; :func:`omcrl.eval.evaluate` produces it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

METRICS = ("NE", "OS", "SR", "SPL", "CR", "TTS")
# metric -> (name, definition, unit, better); the one glossary the README, tables and summary print.
GLOSSARY: dict[str, tuple[str, str, str, str]] = {
    "NE": ("navigation error", "distance from the drone to the goal when the episode ends", "m", "lower"),
    "OS": (
        "oracle success",
        "episodes that came within 0.5 m of the goal at any time (≥ SR; not the oracle)",
        "%",
        "higher",
    ),
    "SR": (
        "success rate",
        "episodes that reached the goal (within env.goal_radius, 0.3 m) without a collision",
        "%",
        "higher",
    ),
    "SPL": (
        "success weighted by path length",
        "mean of S·ℓ/max(d, ℓ): S success, ℓ shortest path, d flown",
        "0-1",
        "higher",
    ),
    "CR": ("collision rate", "episodes that ended in a collision", "%", "lower"),
    "TTS": (
        "time to success",
        "control steps (10 Hz) of the successful episodes; '–' when none succeeded",
        "steps",
        "lower",
    ),
}


def glossary_markdown() -> str:
    """The metrics glossary as a Markdown table (metric, name, definition, unit, better)."""
    rows = ["| metric | name | definition | unit | better |", "|---|---|---|---|---|"]
    rows += [f"| {k} | {n} | {d} | {u} | {b} |" for k, (n, d, u, b) in GLOSSARY.items()]
    return "\n".join(rows)


REQUIRED = (
    "final_distance",
    "min_distance",
    "success",
    "collision",
    "path_length",
    "optimal_path_length",
    "steps",
)


def episode_values(df: pd.DataFrame, os_threshold: float = 0.5) -> pd.DataFrame:
    """Per-episode values whose means are the paper's metrics: columns NE OS SR SPL CR TTS (TTS NaN if failed).

    ``df`` has one row per episode with the columns in :data:`omcrl.eval.metrics.REQUIRED`.
    """
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise KeyError(f"episode_values: missing columns {missing}; got {list(df.columns)}")
    success = df["success"].astype(bool).to_numpy()
    ell = df["optimal_path_length"].to_numpy(float)
    d = df["path_length"].to_numpy(float)
    # max(d, ℓ) > 0 unless both are 0; a zero-length optimal path contributes 0 rather than NaN.
    denom = np.maximum(d, ell)
    spl = np.where(success & (denom > 0), ell / np.where(denom > 0, denom, 1.0), 0.0)
    return pd.DataFrame(
        {
            "NE": df["final_distance"].to_numpy(float),
            "OS": 100.0 * (df["min_distance"].to_numpy(float) <= os_threshold),
            "SR": 100.0 * success,
            "SPL": spl,
            "CR": 100.0 * df["collision"].astype(bool).to_numpy(),
            "TTS": np.where(success, df["steps"].to_numpy(float), np.nan),
        },
        index=df.index,
    )


def summarize(df: pd.DataFrame, os_threshold: float = 0.5) -> pd.Series:
    """Aggregate episodes into the paper's metrics (means of :func:`episode_values`).

    Parameters
    ----------
    df : one row per episode (columns in ``REQUIRED``).
    os_threshold : ε for the oracle success rate (m); the paper uses 0.5 m.

    Returns
    -------
    Series with NE (mean final distance to the goal, m), OS (% episodes whose trajectory came within
    ``os_threshold`` of the goal, i.e. ``min_distance <= ε``), SR (% successful episodes), SPL (mean of
    I_i · ℓ_i / max(d_i, ℓ_i), as a fraction in [0, 1]), CR (% episodes with a collision), TTS (mean steps
    over successful episodes only; NaN when none succeeded) and ``episodes`` (count).
    """
    v = episode_values(df, os_threshold)
    if len(df) == 0:
        return pd.Series({**{m: math.nan for m in METRICS}, "episodes": 0})
    out = {m: float(v[m].mean()) for m in METRICS if m != "TTS"}
    out["TTS"] = float(v["TTS"].mean()) if v["TTS"].notna().any() else math.nan
    return pd.Series({**{m: out[m] for m in METRICS}, "episodes": len(df)})


def summary_table(df: pd.DataFrame, by: Sequence[str] = ("method", "scene"), os_threshold: float = 0.5) -> pd.DataFrame:
    """Metrics per group, e.g. rows = (method, scene) as in the paper's Table I.

    Returns a DataFrame indexed by ``by`` with columns NE, OS, SR, SPL, CR, TTS, episodes. Use
    ``table.unstack("scene")`` for the paper's wide layout (scenes side by side).
    """
    by = list(by)
    rows = {key: summarize(g, os_threshold) for key, g in df.groupby(by, sort=False)}
    out = pd.DataFrame.from_dict(rows, orient="index")
    out.index = pd.MultiIndex.from_tuples([k if isinstance(k, tuple) else (k,) for k in out.index], names=by)
    return out[[*METRICS, "episodes"]]


def format_table(table: pd.DataFrame, decimals: int = 2) -> pd.DataFrame:
    """Wide, rounded view: rows = method, columns = (scene, metric); TTS NaN shown as '-'.

    Methods and scenes keep their order of first appearance in ``table`` (the paper lists scenes by rising
    difficulty, box → furniture → barrier → tree), metrics the order of ``METRICS``.
    """
    if "scene" not in table.index.names:
        wide = table
    else:
        metrics = [c for c in table.columns if c != "episodes"]
        scenes = list(dict.fromkeys(table.index.get_level_values("scene")))
        rest = [n for n in table.index.names if n != "scene"]
        rows = list(dict.fromkeys(table.index.droplevel("scene"))) if rest else None
        wide = table[metrics].unstack("scene")  # unstack sorts both axes; restore the given order below
        wide = wide.swaplevel(0, 1, axis=1).reindex(columns=pd.MultiIndex.from_product([scenes, metrics]))
        if rows is not None:
            wide = wide.reindex(rows)
    return wide.round(decimals).astype(object).where(wide.notna(), "-")
