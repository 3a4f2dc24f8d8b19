"""The answer first (issue 78): the few plain sentences that open the README's results and docs/results.md.

Does OMC-RL work as the paper says? :func:`answer_facts` reads what the committed runs give (the ledger's verdicts on
Table I v2, Table I's cells, the attribution of the zero-shot loss to layouts and look, the teacher's ceiling by
detour, the ablation findings) and returns the facts the sentences state; ``templates/answer_v2.md.j2`` words them
(:func:`answer_block`). Nothing here judges: every verdict is the ledger's or the ablation findings', every number an
estimate of the tables the sentences link to, so a sentence changes when the data do and
``tests/test_answer.py`` fails when a page's copy differs from what the data give.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Sequence
from typing import Any

import pandas as pd

from omcrl import planners
from omcrl.eval.ablation import ABLATION_CLAIMS
from omcrl.eval.ledger import LEDGER, TRAINING_METRICS
from omcrl.eval.table1 import paper_table1, signed_points
from omcrl.eval.verdicts import verdict_counts
from omcrl.pipeline.grids import ABLATION_GRIDS
from omcrl.pipeline.pages import render
from omcrl.pipeline.why import method_label
from omcrl.rl.methods import METHODS, TABLE1_METHODS
from omcrl.scenes import SUITES, scene_spec

ANSWER_START = "<!-- results-answer: start (python -m omcrl summary --preset quick --readme writes this block) -->"
ANSWER_END = "<!-- results-answer: end -->"
# docs/results.md's sections each sentence rests on (GitHub's heading anchors; tests/test_answer.py checks that
# every one is a heading of the page).
ANCHORS = {
    "claims": "claim-ledger-declared-before-the-v2-grid",
    "table1": "table-i-on-v2-how-it-is-made",
    "why": "why-the-numbers-differ-from-the-paper",
    "controls": "the-controls",
    "look": "the-attribution-geometry-or-look",
    "ceiling": "the-teachers-ceiling",
    "ablations": "ablations-and-interpretability",
}
METRIC_WORDS = {"return_auc": "return over training", "return_final": "final return", "SR": "success rate"}
VERDICTS = ("holds", "reversed", "mixed", "undecided", "one seed", "not run")


def _planner(name: str) -> bool:
    """A planner of the comparison (Hybrid APF, its perceptive variant) or of the kit (local APF, blind pilot)."""
    return name in planners.LABELS or (name in METHODS and METHODS[name].features == "planner")


def _names(items: Iterable[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    xs = list(items)
    return xs[0] if len(xs) == 1 else ", ".join(xs[:-1]) + " and " + xs[-1] if xs else ""


def _family(scene: str) -> str:
    return scene_spec(scene).family


def _span(xs: Sequence[float], signed: bool = True) -> str:
    """``lo to hi`` of ``xs`` in whole points (one value alone when they agree)."""
    f = signed_points if signed else (lambda x: f"{x:.0f}")
    lo, hi = f(min(xs)), f(max(xs))
    return lo if lo == hi else f"{lo} to {hi}"


def _possessive(label: str) -> str:
    return f"{label}'" if label.endswith("s") else f"{label}'s"


def claim_words(claim_id: str) -> str:
    """A claim of the ledger in plain words from its fields: ``Ours above PPO, CURL and NPE in return over
    training``; ``NPE lower in furniture, barrier and tree than in box``; ``Ours' lead over CURL larger in tree than
    in furniture``."""
    c = next(c for c in LEDGER if c.id == claim_id)
    metric = METRIC_WORDS.get(c.metric, c.metric)
    if c.kind == "order":
        return f"{method_label(c.a)} above {_names(method_label(b) for b in c.b)} in {metric}"
    if c.kind == "drop":
        return f"{_possessive(method_label(c.a))} {metric} lower in {_names(c.scenes[1:])} than in {c.scenes[0]}"
    lead = f"{_possessive(method_label(c.a))} lead over {method_label(c.b[0])} in {metric}"
    return f"{lead} larger in {c.scenes[0]} than in {c.scenes[1]}"


def _claims(v: pd.DataFrame, ids: Sequence[str]) -> dict[str, list[dict[str, Any]]]:
    """The claims ``ids`` grouped by their verdict (:func:`omcrl.eval.verdicts.verdict_counts`), each with its words
    and, where the verdict is mixed, the scenes of its decided hypotheses."""
    counts = verdict_counts(v[v["claim"].isin(ids)]).set_index("claim")
    out: dict[str, list[dict[str, Any]]] = {k: [] for k in VERDICTS}
    for cid in [c for c in ids if c in counts.index]:
        g = v[v["claim"] == cid]
        where = g["versus_scene"].where(g["versus_scene"] != "", g["scene"]).map(_family)
        by = {k: list(where[g["verdict"] == k]) for k in ("holds", "reversed")}
        out[counts.loc[cid, "verdict"]].append({"id": cid, "words": claim_words(cid), **by})
    return {k: x for k, x in out.items() if x}


def _sr(table: pd.DataFrame, method: str, scene: str) -> float:
    key = (method, scene)
    return float(table.loc[key, "SR"]) if key in table.index else math.nan


def answer_facts(
    verdicts: pd.DataFrame,
    table: pd.DataFrame,
    attribution: pd.DataFrame | None = None,
    detour: pd.DataFrame | None = None,
    ablations: pd.DataFrame | None = None,
    ablation_grids: tuple[Collection[str], int] | None = None,
    ablation_budget: tuple[int, int] | None = None,
    ablations_table1: pd.DataFrame | None = None,
) -> dict[str, Any]:
    """What the answer states, from the data alone.

    Parameters
    ----------
    verdicts : the ledger's verdicts on Table I v2 (:func:`omcrl.eval.verdicts.holm_verdicts`; one row per
        hypothesis with ``claim``, ``family``, ``a``, ``b``, ``scene``, ``versus_scene``, ``estimate``, ``verdict``,
        ``seeds_to_decide``).
    table : Table I's aggregates, index (method, scene), with ``SR`` in %.
    attribution : :func:`omcrl.pipeline.why.attribution_table` (SR in %, steps in points); None or empty: not flown.
    detour : :func:`omcrl.pipeline.why.detour_table` (shares in %); None or empty: not made.
    ablations : :func:`omcrl.eval.ablation.findings_summary` of the recorded ablation grids; None: none recorded.
    ablation_grids : (the names of the grids with every variant at every ablation seed, grids in all); None: (none,
        the six). A finding whose grid is not among them is said to be judged on a grid still running.
    ablation_budget : (the ablation grids' RL env steps, Table I's), e.g. ``(cfg.sweep.rl_steps, cfg.rl.total_steps)``;
        None: not said.
    ablations_table1 : :func:`~omcrl.eval.ablation.findings_summary` of the same orderings judged on Table I's runs
        (:func:`omcrl.pipeline.ablations.table1_counterparts`); None or empty: not said.

    Returns
    -------
    A dict of plain values for ``templates/answer_v2.md.j2``; absent parts are None.
    """
    v = verdicts
    train = SUITES["v2"][0]
    unseen = list(SUITES["v2"][1:])
    learned_b = [m for m in ("npe", "curl", "ppo") if m in set(v["b"])]
    e1 = v[(v["claim"] == "E1") & v["b"].isin(learned_b)]
    e1_planner = v[(v["claim"] == "E1") & v["b"].map(_planner)]
    reversed_rows = v[v["verdict"] == "reversed"]
    vs_planner = reversed_rows[reversed_rows["b"].map(_planner)]
    learned_vs = v[(v["a"] == "ours") & v["b"].isin(learned_b) & ~v["metric"].isin(list(TRAINING_METRICS))]
    paper = _paper_sr()
    hard = [(s, scene_spec(s).family) for s in unseen if scene_spec(s).family in ("barrier", "tree")]
    baselines = [(m, s) for m in learned_b for s, _ in hard]
    here = [_sr(table, m, s) for m, s in baselines]
    there = [paper.get((m, scene_spec(s).family), math.nan) for m, s in baselines]
    facts: dict[str, Any] = {
        "anchors": ANCHORS,
        "training": _claims(v, [c.id for c in LEDGER if c.metric in TRAINING_METRICS]),
        "e1": {
            "versus": _names(method_label(m) for m in learned_b),
            "n": len(e1),
            "decided": int((e1["verdict"] != "undecided").sum()),
            "span": _span(list(e1["estimate"])) if len(e1) else "",
            "all_versus": len(learned_vs),
            "all_undecided": int((learned_vs["verdict"] == "undecided").sum()),
        },
        "baselines": {
            "here": _span([x for x in here if math.isfinite(x)], signed=False),
            "paper": _span([x for x in there if math.isfinite(x)], signed=False),
            "ours": [(f, _sr(table, "ours", s), paper.get(("ours", f))) for s, f in hard],
        },
        "planner": {
            "label": _names(method_label(m) for m in dict.fromkeys(e1_planner["b"])),
            "n": len(e1_planner),
            "reversed": int((e1_planner["verdict"] == "reversed").sum()),
            "span": _span(list(e1_planner["estimate"])) if len(e1_planner) else "",
            "all_reversed": len(reversed_rows),
            "vs_planner": len(vs_planner),
            "others": sorted(set(reversed_rows.loc[~reversed_rows.index.isin(vs_planner.index), "claim"])),
        },
        "table1": _claims(v, [c.id for c in LEDGER if c.family == "primary" and c.metric == "SR" and c.id != "E1"]),
        "e9": [(_family(r.scene), r.estimate, r.verdict) for r in v[v["claim"] == "E9"].itertuples()],
        "loss": _loss(table, train),
        "controls": _controls(v),
        "power": _power(v),
        "look": _look(attribution),
        "ceiling": _ceiling(detour),
        "ablations": _ablations(
            ablations, ablation_grids or ((), len(ABLATION_GRIDS)), ablation_budget, ablations_table1
        ),
    }
    return facts


def _paper_sr() -> dict[tuple[str, str], float]:
    p = paper_table1()
    return {(r.method, r.scene): float(r.SR) for r in p.itertuples()}


def _camera_methods() -> list[str]:
    """The learned Table I methods that fly on the camera alone: not privileged, not the kit's controls."""
    return [m for m in TABLE1_METHODS if METHODS[m].learned and not METHODS[m].privileged and not METHODS[m].control]


def _loss(table: pd.DataFrame, train: str) -> dict[str, Any] | None:
    """SR points each camera method loses from the training scene to barrier and tree (point estimates)."""
    out = {}
    for s in SUITES["v2"][1:]:
        fam = scene_spec(s).family
        if fam not in ("barrier", "tree"):
            continue
        drops = [_sr(table, m, train) - _sr(table, m, s) for m in _camera_methods()]
        drops = [d for d in drops if math.isfinite(d)]
        if drops:
            out[fam] = _span(drops, signed=False)
    ours = (_sr(table, "ours", train), *(_sr(table, "ours", s) for s in SUITES["v2"][1:]
                                        if scene_spec(s).family in ("barrier", "tree")))  # fmt: skip
    if not out or not all(math.isfinite(x) for x in ours):
        return None
    return {"spans": out, "ours": [f"{x:.0f}" for x in ours], "methods": len(_camera_methods())}


def _controls(v: pd.DataFrame) -> dict[str, Any] | None:
    out = {}
    for cid in ("C1", "C2"):
        g = v[v["claim"] == cid]
        if g.empty:
            return None
        out[cid] = {
            "n": len(g),
            "holds": int((g["verdict"] == "holds").sum()),
            "undecided": int((g["verdict"] == "undecided").sum()),
            "span": _span(list(g["estimate"])),
            "held_span": _span(list(g.loc[g["verdict"] == "holds", "estimate"])) if (g["verdict"] == "holds").any()
            else "",
            "seeds": int(g["seeds"].min()),
        }  # fmt: skip
    return out


def _power(v: pd.DataFrame) -> dict[str, int]:
    und = v[v["verdict"] == "undecided"]
    return {"undecided": len(und), "bound": int((und["seeds_to_decide"] == math.inf).sum())}


def _look(attribution: pd.DataFrame | None) -> dict[str, Any] | None:
    """Per barrier and tree: the span of the camera methods' geometry and look steps, how many of each resolved
    (the CI excludes 0), and the training seeds flown."""
    if attribution is None or attribution.empty:
        return None
    a = attribution[attribution["method"].isin(_camera_methods())].dropna(subset=["geometry", "look"])
    if a.empty:
        return None
    scenes = []
    for scene, g in a.groupby("scene", sort=False):
        fam = scene_spec(scene).family
        if fam not in ("barrier", "tree"):
            continue
        step = {}
        for name in ("geometry", "look"):
            resolved = (g[f"{name}_hi"] < 0) | (g[f"{name}_lo"] > 0)
            step[name] = {"span": _span(list(g[name])), "resolved": int(resolved.sum())}
        scenes.append({"scene": fam, "methods": len(g), **step})
    seeds = sorted(set(a["seeds"]))
    return {"scenes": scenes, "seeds": f"{seeds[0]}" if len(seeds) == 1 else f"{seeds[0]}–{seeds[-1]}"}


def _ceiling(detour: pd.DataFrame | None) -> dict[str, Any] | None:
    """barrier-v2's longest-detour bin: its share of the layouts, the oracle's SR there and the best student's; its
    straightest bin: ours' SR and CR against the oracle's."""
    if detour is None or detour.empty:
        return None
    barrier = next((s for s in SUITES["v2"] if scene_spec(s).family == "barrier"), None)
    d = detour[detour["scene"] == barrier]
    bins = list(dict.fromkeys(d["detour"]))
    if "oracle" not in set(d["method"]) or "ours" not in set(d["method"]) or not bins:
        return None
    cell = d.set_index(["method", "detour"])
    last, first = bins[-1], bins[0]
    students = [m for m in _camera_methods() if (m, last) in cell.index]
    return {
        "bin": last,
        "straight": first,
        "share": f"{cell.loc[('oracle', last), 'layouts']:.0f}",
        "oracle": f"{cell.loc[('oracle', last), 'SR']:.0f}",
        "best_student": f"{max(cell.loc[(m, last), 'SR'] for m in students):.0f}",
        "students": len(students),
        "ours_sr": f"{cell.loc[('ours', first), 'SR']:.0f}",
        "ours_cr": f"{cell.loc[('ours', first), 'CR']:.0f}",
        "oracle_sr": f"{cell.loc[('oracle', first), 'SR']:.0f}",
        "oracle_cr": f"{cell.loc[('oracle', first), 'CR']:.0f}",
    }


def _ablations(
    summary: pd.DataFrame | None,
    grids: tuple[Collection[str], int],
    budget: tuple[int, int] | None,
    at_table1: pd.DataFrame | None = None,
) -> dict[str, Any]:
    """Each judged finding with its verdict, whether its grid is complete (a verdict of a grid still running can
    move), its stress-room checks where one is resolved (:func:`_stress`, else None) and its verdict on Table I's runs
    ((verdict, checks, stress) or None), how many of the grids are complete, and their RL budget against Table I's
    (``steps``, ``table1_steps``, ``share`` in %; None when not given)."""
    grid_of = {finding: grid for finding, grid, _, _ in ABLATION_CLAIMS}
    complete = set(grids[0])
    again = {} if at_table1 is None else {str(r["finding"]): (r["verdict"], int(r["checks"]), _stress(r))
                                            for _, r in at_table1.iterrows()}  # fmt: skip
    rows = [] if summary is None else [(*str(r["finding"]).split(" ", 1), r["verdict"], int(r["checks"]),
                                        grid_of.get(str(r["finding"])) in complete, _stress(r),
                                        again.get(str(r["finding"]))) for _, r in summary.iterrows()]  # fmt: skip
    steps = None if budget is None else {"steps": f"{budget[0]:,}", "table1_steps": f"{budget[1]:,}",
                                          "share": f"{100 * budget[0] / budget[1]:.0f}"}  # fmt: skip
    return {"findings": rows, "complete": len(complete), "grids": grids[1], "budget": steps}


def _stress(row: pd.Series) -> str | None:
    """A finding's stress-room checks (judged apart from its verdict) in words when any of them held or was reversed,
    e.g. ``"1 of 3 holds, 1 reversed"``; None when all are undecided or none was flown. A reader of the verdict alone
    would otherwise not learn that furniture-v0 resolved a check."""
    # A frame without the counts (none evaluated in the stress room) reads as zeros.
    held, reversed_, undecided = (int(row.get(f"stress {k}", 0)) for k in ("holds", "reversed", "undecided"))
    if not held and not reversed_:
        return None
    return f"{held} of {held + reversed_ + undecided} holds, {reversed_} reversed"


def answer_block(facts: dict[str, Any], base: str = "docs/results.md") -> str:
    """The block: :func:`answer_facts` in words (``templates/answer_v2.md.j2``), its links to docs/results.md's
    sections written relative to the page it goes in (``base``: ``docs/results.md`` from the README, ``""`` within
    docs/results.md)."""
    return render("answer_v2.md.j2", base=base, **facts)
