"""docs/results.md's "Why the numbers differ from the paper" (issue 75): the tables, generated from ``reference/``.

So far the teacher's ceiling: SR / CR / timeout of every Table I method by the detour of its layouts
(:func:`detour_block`), from the shipped per-episode rows of the Table I grid and the layouts' geometry (rebuilt from
their seeds, no episode flown). The controls are rows of Table I and of the ledger (family ``controls``); the
attribution of the zero-shot loss to geometry and look joins here once its flights are recorded.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import pandas as pd

from omcrl.config import load_config
from omcrl.eval.stats import Term, cell_rng, contrast, term
from omcrl.interpret.transfer import DETOUR_BINS, layout_stats, with_detour_bins
from omcrl.pipeline.griddata import GridData, grid_data_dir
from omcrl.pipeline.grids import RETRAIN_LOOK
from omcrl.pipeline.pages import render
from omcrl.planners import LABELS as PLANNER_LABELS
from omcrl.rl.methods import METHODS, TABLE1_METHODS
from omcrl.scenes import SUITES
from omcrl.utils.io import atomic_write_text

WHY_DETOUR_START = "<!-- why-detour-v2: start (python -m omcrl summary --preset quick --readme writes this block) -->"
WHY_DETOUR_END = "<!-- why-detour-v2: end -->"
WHY_LOOK_START = "<!-- why-look-v2: start (python -m omcrl summary --preset quick --readme writes this block) -->"
WHY_LOOK_END = "<!-- why-look-v2: end -->"
TRAIN_SCENE = SUITES["v2"][0]


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


def method_label(method: str) -> str:
    """The name a table shows for ``method``: its label in the method table, or a planner's (local APF, blind)."""
    return METHODS[method].label if method in METHODS else PLANNER_LABELS.get(method, method)


def detour_block(preset: str = "quick", table: pd.DataFrame | None = None) -> str:
    """The block: per scene, one row per method, each detour bin's ``SR / CR / TO`` in % (seeds × layouts pooled;
    :func:`detour_table`) and the share of the scene's layouts in the bin."""
    t = detour_table(preset) if table is None else table
    bins = list(dict.fromkeys(t["detour"])) if len(t) else []
    scenes = []
    for scene, g in t.groupby("scene", sort=False) if len(t) else ():
        share = g.drop_duplicates("detour").set_index("detour")["layouts"]
        rows = []
        for method, m in g.groupby("method", sort=False):
            cells = m.set_index("detour")
            rows.append((method_label(method), [f"{cells.SR[b]:.0f} / {cells.CR[b]:.0f} / {cells.TO[b]:.0f}"
                                          if b in cells.index else "–" for b in bins]))  # fmt: skip
        scenes.append((scene, [f"{b} ({share.get(b, 0):.0f} % of layouts)" for b in bins], rows))
    return render("why_detour_v2.md.j2", preset=preset, edges=list(DETOUR_BINS)[1:-1], scenes=scenes)


def _sr_term(episodes: pd.DataFrame, method: str, scene: str, pool: str, coef: float) -> Term | None:
    g = episodes[(episodes["method"] == method) & (episodes["scene"] == scene)]
    if g.empty:
        return None
    return term(g, 100.0 * g["success"].astype(float).to_numpy(), pool, coef)


def attribution_table(preset: str = "quick", reps: int = 2000) -> pd.DataFrame:
    """Each learned method's loss from box-v2 to an unseen v2 scene split in two, from the Table I grid's episodes
    and the box-look grid's (``table1-boxlook``: the same runs on the unseen scenes' own layouts drawn in box-v2's
    look). One row per method and unseen scene, SR in %, each with its 95 % CI (seeds × layouts crossed,
    :func:`omcrl.eval.stats.contrast`):

    * ``box``: SR in box-v2; ``box_look``: SR on the scene's layouts in box-v2's look; ``own``: SR in the scene as it
      is (Table I's cell);
    * ``geometry`` = box_look − box (the training seeds paired, the two scenes' layouts independent): what the
      scene's layouts cost with the look held at the training one;
    * ``look`` = own − box_look (seeds and layouts paired: the same episodes' starts and goals): what the scene's
      look costs on its own layouts.

    Only methods and seeds flown in both grids enter; ``seeds`` counts them. A seed the retrain grid
    (``table1-retrain``: Table I's run of it could not be retrained as it was) flew in both its variants is taken
    whole from there, in place of Table I's run of that seed; ``retrained`` counts those. Empty while the box-look
    grid holds nothing.
    """
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(preset, overrides=[f"results_dir={tmp}"])
        own = GridData(grid_data_dir(cfg, "table1")).episodes()
        look = GridData(grid_data_dir(cfg, "table1-boxlook")).episodes()
        retrain = GridData(grid_data_dir(cfg, "table1-retrain")).episodes()
    return attribution(own, look, reps, retrain)


def _runs(episodes: pd.DataFrame) -> pd.MultiIndex:
    """The (method, training seed) of each episode."""
    return pd.MultiIndex.from_frame(episodes[["method", "train_seed"]])


def with_retrained(
    own: pd.DataFrame, look: pd.DataFrame, retrain: pd.DataFrame | None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``own`` and ``look`` with every (method, training seed) that ``retrain`` flew in both its variants (``<method>``
    in Table I's evaluation, ``<method> box-look`` in box-v2's look: :data:`omcrl.pipeline.grids.RETRAIN_LOOK`)
    taken from ``retrain`` in place of Table I's run of that seed: a retrained policy is another policy, so all three
    of its SRs are its own and none is paired with Table I's. A bool column ``retrained`` marks the rows taken."""
    own, look = own.assign(retrained=False), look.assign(retrained=False)
    if retrain is None or retrain.empty:
        return own, look
    boxlook = retrain["label"].astype(str).str.endswith(RETRAIN_LOOK)
    mine, theirs = retrain[~boxlook & (retrain["label"] == retrain["method"])], retrain[boxlook]
    whole = _runs(mine).intersection(_runs(theirs))

    def swap(table: pd.DataFrame, new: pd.DataFrame) -> pd.DataFrame:
        took = new[_runs(new).isin(whole)].assign(retrained=True)
        return pd.concat([table[~_runs(table).isin(whole)], took], ignore_index=True)

    return swap(own, mine), swap(look, theirs)


def attribution(
    own: pd.DataFrame, look: pd.DataFrame, reps: int = 2000, retrain: pd.DataFrame | None = None
) -> pd.DataFrame:
    """:func:`attribution_table` from the episodes themselves: ``own`` (Table I's, with box-v2 and the unseen scenes)
    and ``look`` (the unseen scenes in box-v2's look); one row per episode with ``method``, ``scene``,
    ``train_seed``, the layout ``seed`` and ``success``. ``retrain``: the retrain grid's episodes (with ``label``),
    whose whole seeds replace Table I's (:func:`with_retrained`)."""
    if look.empty or own.empty:
        return pd.DataFrame()
    own, look = with_retrained(own, look, retrain)
    rows = []
    learned = [m for m in TABLE1_METHODS if METHODS[m].learned]
    for method in [m for m in learned if m in set(look["method"])]:
        seeds = set(look.loc[look["method"] == method, "train_seed"]) & set(
            own.loc[own["method"] == method, "train_seed"]
        )
        o = own[(own["method"] == method) & own["train_seed"].isin(seeds)]
        lk = look[(look["method"] == method) & look["train_seed"].isin(seeds)]
        again = o.loc[o["retrained"], "train_seed"].nunique()
        for scene in SUITES["v2"][1:]:
            parts = {
                "box": [_sr_term(o, method, TRAIN_SCENE, TRAIN_SCENE, 1.0)],
                "box_look": [_sr_term(lk, method, scene, scene, 1.0)],
                "own": [_sr_term(o, method, scene, scene, 1.0)],
                "geometry": [
                    _sr_term(lk, method, scene, scene, 1.0),
                    _sr_term(o, method, TRAIN_SCENE, TRAIN_SCENE, -1.0),
                ],
                "look": [_sr_term(o, method, scene, scene, 1.0), _sr_term(lk, method, scene, scene, -1.0)],
            }
            row: dict = {"method": method, "scene": scene, "seeds": len(seeds), "retrained": again}
            for name, terms in parts.items():
                if any(t is None for t in terms):
                    row[name] = row[f"{name}_lo"] = row[f"{name}_hi"] = math.nan
                    continue
                # SR in %: a cell's interval on the logit scale, a difference's cut to the [-100, 100] it can take.
                e = contrast(terms, reps, rng=cell_rng(0, "attribution", method, scene, name), bounded=100.0)
                row[name], row[f"{name}_lo"], row[f"{name}_hi"] = e.estimate, e.lo, e.hi
            rows.append(row)
    return pd.DataFrame(rows)


def attribution_block(preset: str = "quick", table: pd.DataFrame | None = None) -> str:
    """The block: per unseen scene, one row per learned method, SR box-v2 → on the scene's layouts in box-v2's look
    → in its own look, and the two differences (:func:`attribution_table`), each mean [95 % CI]."""
    t = attribution_table(preset) if table is None else table

    def ci(r: pd.Series, name: str, sign: bool = False) -> str:
        v, lo, hi = r[name], r[f"{name}_lo"], r[f"{name}_hi"]
        if not math.isfinite(v):
            return "–"
        f = "{:+.0f}" if sign else "{:.0f}"
        return f"{f.format(v)} [{f.format(lo)}, {f.format(hi)}]".replace("-", "−")  # a minus sign, as every table

    def seeds(r: pd.Series) -> str:
        again = int(r.get("retrained", 0))
        return f"{r['seeds']} ({again} retrained)" if again else str(r["seeds"])

    scenes = [
        (scene, [[method_label(r["method"]), seeds(r), ci(r, "box"), ci(r, "box_look"), ci(r, "own"),
                  ci(r, "geometry", True), ci(r, "look", True)] for _, r in g.iterrows()])
        for scene, g in (t.groupby("scene", sort=False) if len(t) else ())
    ]  # fmt: skip
    return render("why_look_v2.md.j2", preset=preset, train=TRAIN_SCENE, scenes=scenes)


def write_why_tables(preset: str, out: str | Path) -> dict[str, Path]:
    """The section's two tables as files beside Table I (``tables --from-reference`` writes them):
    ``why_attribution.{csv,md}`` (:func:`attribution_table`) and ``why_detour.{csv,md}`` (:func:`detour_table`), the
    ``.md`` the same block docs/results.md shows. A table with no data (no box-look flights yet) is not written.
    Returns ``{file name: path}`` of what was written."""
    out = Path(out)
    paths: dict[str, Path] = {}
    for name, build, block in (
        ("why_attribution", attribution_table, attribution_block),
        ("why_detour", detour_table, detour_block),
    ):
        t = build(preset)
        if t.empty:
            continue
        for ext, text in (("csv", t.to_csv(index=False)), ("md", block(preset, table=t) + "\n")):
            paths[f"{name}.{ext}"] = out / f"{name}.{ext}"
            atomic_write_text(paths[f"{name}.{ext}"], text)
    return paths
