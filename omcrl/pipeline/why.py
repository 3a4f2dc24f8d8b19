"""docs/results.md's "Why the numbers differ from the paper" (issue 75): the tables, generated from ``reference/``.

So far the teacher's ceiling: SR / CR / timeout of every Table I method by the detour of its layouts
(:func:`detour_block`), from the shipped per-episode rows of the Table I grid and the layouts' geometry (rebuilt from
their seeds, no episode flown). The controls are rows of Table I and of the ledger (family ``controls``); the
attribution of the zero-shot loss to geometry and look joins here once its flights are recorded.
"""

from __future__ import annotations

import tempfile
import textwrap

import pandas as pd

from omcrl.config import load_config
from omcrl.interpret.transfer import DETOUR_BINS, layout_stats, with_detour_bins
from omcrl.pipeline.griddata import GridData, grid_data_dir
from omcrl.planners import LABELS as PLANNER_LABELS
from omcrl.rl.methods import METHODS, TABLE1_METHODS
from omcrl.scenes import SUITES

WHY_DETOUR_START = "<!-- why-detour-v2: start (python -m omcrl summary --preset quick --readme writes this block) -->"
WHY_DETOUR_END = "<!-- why-detour-v2: end -->"


def detour_table(preset: str = "quick") -> pd.DataFrame:
    """Every method the Table I grid recorded (``reference/<preset>/table1-v2/``), in the v2 suite's four scenes on its
    own layouts, by the detour of the layout (:func:`omcrl.interpret.transfer.with_detour_bins`): one row per
    method, scene and bin with ``layouts`` (% of the scene's layouts in the bin), ``episodes`` and the shares (%) of
    episodes that reached the goal (``SR``), collided (``CR``), left the arena (``OUT``) or ran out of steps
    (``TO``), seeds × layouts pooled."""
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(preset, overrides=[f"results_dir={tmp}", f"eval.scenes=[{', '.join(SUITES['v2'])}]"])
        episodes = GridData(grid_data_dir(cfg, "table1")).episodes()
        if episodes.empty:
            return pd.DataFrame()
        geo = layout_stats(cfg).set_index(["scene", "seed"])
    episodes = episodes[episodes["scene"].isin(SUITES["v2"])].reset_index(drop=True)
    ep, labels = with_detour_bins(episodes, geo.shortest_path_m / geo.straight_line_m)
    success, collision = ep["success"].astype(bool), ep["collision"].astype(bool)
    out = ep["out_of_arena"].astype(bool) & ~collision
    ep = ep.assign(SR=success * 100.0, CR=collision * 100.0, OUT=out * 100.0, TO=~(success | collision | out) * 100.0)
    t = ep.groupby(["method", "scene", "detour"], sort=False)[["SR", "CR", "OUT", "TO"]].mean()
    t.insert(0, "episodes", ep.groupby(["method", "scene", "detour"], sort=False).size())
    per_scene = ep.groupby(["method", "scene"]).size()
    t.insert(0, "layouts", 100.0 * t["episodes"] / per_scene.reindex(t.index.droplevel("detour")).to_numpy())
    t = t.reset_index()
    order = {m: i for i, m in enumerate((*TABLE1_METHODS, *PLANNER_LABELS))}
    order |= {s: i for i, s in enumerate(SUITES["v2"])} | {b: i for i, b in enumerate(labels)}
    return t.sort_values(["scene", "method", "detour"], key=lambda c: c.map(order), kind="stable").reset_index(
        drop=True
    )


def _label(method: str) -> str:
    return METHODS[method].label if method in METHODS else PLANNER_LABELS.get(method, method)


def detour_block(preset: str = "quick", table: pd.DataFrame | None = None) -> str:
    """The block: per scene, one row per method, each detour bin's ``SR / CR / TO`` in % (seeds × layouts pooled;
    :func:`detour_table`) and the share of the scene's layouts in the bin."""
    t = detour_table(preset) if table is None else table
    if t.empty:
        return f"Not run yet (no episodes under `reference/{preset}/table1-v2/`)."
    bins = list(dict.fromkeys(t["detour"]))
    edges = list(DETOUR_BINS)
    caption = (
        f"SR / CR / TO % by the detour of the layout (shortest path / straight line; bin edges {edges[1:-1]}): "
        "reached the goal / collided / ran out of steps (the rest left the arena), every Table I method over its "
        "training seeds × the grid's 50 layouts per scene, episodes pooled. Generated from "
        f"`reference/{preset}/table1-v2/` and the layouts' geometry (rebuilt from their seeds; nothing flown)."
    )
    lines = [*textwrap.wrap(caption, 120), ""]
    for scene, g in t.groupby("scene", sort=False):
        share = g.drop_duplicates("detour").set_index("detour")["layouts"]
        head = " | ".join(f"{b} ({share.get(b, 0):.0f} % of layouts)" for b in bins)
        lines += [f"**{scene}**", "", f"| method | {head} |", "|---" * (len(bins) + 1) + "|"]
        for method, m in g.groupby("method", sort=False):
            cells = m.set_index("detour")
            row = [
                f"{cells.SR[b]:.0f} / {cells.CR[b]:.0f} / {cells.TO[b]:.0f}" if b in cells.index else "–" for b in bins
            ]
            lines.append(f"| {_label(method)} | " + " | ".join(row) + " |")
        lines.append("")
    return "\n".join(lines).rstrip("\n")
