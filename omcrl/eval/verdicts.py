"""Verdicts on the claim ledger (:mod:`omcrl.eval.ledger`) from evaluation episodes and training metrics.

Each hypothesis becomes a contrast (:func:`omcrl.eval.stats.contrast`) signed so that a positive estimate is the
paper's direction (``a`` better than ``b``: higher SR, lower CR, ...):

* ``order``: ``a − b`` in one scene, paired layout by layout and seed by seed;
* ``drop``: ``a`` in the first scene minus ``a`` in another (seeds paired, layouts of two scenes independent);
* ``gap``: ``(a − b)`` in the first scene minus ``(a − b)`` in the second;
* training metrics (``return_auc``, ``return_final``): one value per training run, seeds paired.

The two-sided p-values are Holm–Bonferroni adjusted within each family (primary, secondary, controls) over the rows that
could be computed. Verdict: ``holds`` (adjusted p < 0.05, estimate > 0), ``reversed`` (adjusted p < 0.05,
estimate < 0), ``undecided`` otherwise, ``not run`` when a method or scene has no data, ``one seed`` when a learned
method of the row has a single training seed (its estimate and interval over layouts are shown, not judged, and
the row is left out of Holm). For an undecided row the
*power line* says how many training seeds would decide it at the measured effect and variance components, under
the family's multiplicity rule and by the test the verdict uses: 80 % power at the Bonferroni level ``α / m`` of its
family of ``m`` judged rows (the strictest step of Holm's, so a row with that power is decided whatever the others
give), two-sided, on the t distribution with the contrast's Satterthwaite degrees of freedom at that many seeds (the
seed part shrinking as ``1 / n``, the layout part fixed: the same layouts are flown). With 3 seeds and the seed part
alone, that t has 2 degrees of freedom: a normal approximation would promise decisions the test cannot give. When
the layout part alone is too wide, no number of seeds does at these layouts: the line says so, with the layouts it
would take if the seed part were gone (a lower bound).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats as sps

from omcrl.eval.ledger import TRAINING_METRICS, hypotheses
from omcrl.eval.metrics import episode_values
from omcrl.eval.stats import BOUNDED, DEFAULT_REPS, Term, cell_rng, contrast, satterthwaite_df, term
from omcrl.rl.methods import METHODS
from omcrl.runs import metric_series
from omcrl.scenes import scene_spec
from omcrl.utils.io import atomic_write_text

ALPHA = 0.05
POWER = 0.80
MAX_SEEDS = 1_000_000  # a power line beyond this says "no number" as the layout-bound case does
COLUMNS = ["claim", "family", "hypothesis", "metric", "scene", "versus_scene", "a", "b", "estimate", "lo", "hi",
           "p", "p_holm", "verdict", "seeds", "seeds_to_decide", "layouts_to_decide", "var_seed",
           "var_layout"]  # fmt: skip


def training_values(runs: Mapping[str, Mapping[int, str | Path]], metric: str) -> dict[str, dict[int, float]]:
    """``{method: {seed: value}}`` of a training metric (:data:`omcrl.eval.ledger.TRAINING_METRICS`) from each
    run's ``episodic_return`` over env steps: ``return_auc`` its mean over the run, ``return_final`` its mean over
    the last 10 % of the steps. ``runs``: ``{method: {seed: metrics.csv(.gz) or run folder}}``."""
    out: dict[str, dict[int, float]] = {}
    for method, seeds in runs.items():
        for seed, path in seeds.items():
            m = metric_series(path)
            if "episodic_return" not in m or not len(m["episodic_return"][0]):
                continue
            steps, vals = m["episodic_return"]
            ok = np.isfinite(vals)
            steps, vals = steps[ok], vals[ok]
            if metric == "return_final":
                vals = vals[steps >= steps[0] + 0.9 * (steps[-1] - steps[0])]
            out.setdefault(method, {})[int(seed)] = float(np.mean(vals))
    return out


def _holm(p: np.ndarray) -> np.ndarray:
    """Holm–Bonferroni adjusted p-values (NaN stays NaN and is not counted)."""
    out = np.full(len(p), math.nan)
    idx = np.flatnonzero(np.isfinite(p))
    order = idx[np.argsort(p[idx], kind="stable")]
    m, running = len(order), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out


def _detectable(estimate: float, var_seed: float, var_layout: float, n: float, df_layout: float, alpha: float) -> bool:
    """Whether ``|estimate|`` clears the t test's two-sided level ``alpha`` with 80 % power at ``n`` seeds (the seed
    part at ``var_seed / n`` per seed, the layout part fixed), with the contrast's Satterthwaite degrees of freedom."""
    vs = var_seed / n
    var = vs + var_layout
    df = satterthwaite_df([(vs, n - 1), (var_layout, df_layout)])
    q = float(sps.t.ppf(1 - alpha / 2, df) + sps.t.ppf(POWER, df))
    return abs(estimate) >= q * math.sqrt(var)


def seeds_to_decide(
    estimate: float,
    var_seed: float,
    var_layout: float,
    seeds: int,
    alpha: float = ALPHA,
    layouts: int | None = None,
) -> float:
    """Training seeds at which ``estimate`` would be significant at two-sided level ``alpha`` with 80 % power, by
    the t test the verdicts use (module docstring; :func:`holm_verdicts` passes its family's Bonferroni level);
    ``inf`` when the layout part alone forbids it, NaN when there is no effect to detect.

    ``var_seed`` and ``var_layout`` are the estimate's variance parts at ``seeds`` training seeds (squared units of
    the metric); the seed part shrinks as 1 / seeds, the layout part does not (the ``layouts`` are fixed; ``None``:
    its degrees of freedom taken as infinite)."""
    if not math.isfinite(estimate) or estimate == 0:
        return math.nan
    df_layout = layouts - 1 if layouts is not None and layouts > 1 else math.inf
    if not _detectable(estimate, 0.0, var_layout, math.inf, df_layout, alpha):
        return math.inf  # even infinitely many seeds leave the layout part too wide
    if var_seed <= 0:
        return float(seeds)
    per_seed = var_seed * seeds
    # The variance falls as 1/n, and the t quantile moves little once the seeds' degrees of freedom pass the
    # layouts' (49 at 50 layouts), so detectability is monotone in n in practice.
    return _first_passing(lambda n: _detectable(estimate, per_seed, var_layout, n, df_layout, alpha), seeds)


def _first_passing(ok: Callable[[int], bool], start: int) -> float:
    """The smallest n >= max(2, start) with ``ok(n)``, for a test that stays passed once it passes (doubling, then
    bisection); ``inf`` when n would pass ``MAX_SEEDS``."""
    lo = hi = max(2, start)
    while not ok(hi):
        lo, hi = hi + 1, hi * 2
        if hi > MAX_SEEDS:
            return math.inf
    while lo < hi:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if ok(mid) else (mid + 1, hi)
    return float(lo)


def layouts_to_decide(estimate: float, var_layout: float, layouts: int | None, alpha: float = ALPHA) -> float:
    """Evaluation layouts at which ``estimate`` would be significant at two-sided level ``alpha`` with 80 % power if
    the seed part were gone (many training seeds): the layout part shrinks as 1 / layouts. A lower bound, since
    finite seeds add their part back; for a row whose :func:`seeds_to_decide` is ``inf``, it says how far the
    layouts fall short. NaN when there is no effect, no layout part or no layout count; ``inf`` beyond
    ``MAX_SEEDS`` layouts.

    ``var_layout`` is the estimate's layout part at ``layouts`` layouts (squared units of the metric)."""
    if not math.isfinite(estimate) or estimate == 0 or not layouts or not var_layout > 0:
        return math.nan
    per_layout = var_layout * layouts
    # The variance falls as 1/n and the t quantile with it: monotone.
    return _first_passing(lambda n: _detectable(estimate, 0.0, per_layout / n, math.inf, n - 1, alpha), layouts)


def ledger_verdicts(
    episodes: pd.DataFrame,
    training: Mapping[str, Mapping[int, str | Path]] | None = None,
    suite: str = "v2",
    reps: int = DEFAULT_REPS,
    seed: int = 0,
    os_threshold: float = 0.5,
) -> pd.DataFrame:
    """Every hypothesis of the ledger in ``suite`` judged on ``episodes`` (one row per episode with ``method``,
    ``scene``, ``train_seed`` and the layout ``seed``) and the training runs ``training`` (``{method: {seed:
    metrics}}``, for Fig. 5's rows). Returns one row per hypothesis (:data:`COLUMNS`)."""
    values = episode_values(episodes, os_threshold) if len(episodes) else pd.DataFrame()
    train_cache: dict[str, dict] = {}
    rows = []
    for h in hypotheses(suite):
        specs = _term_specs(h)
        if h["metric"] in TRAINING_METRICS:
            tv = train_cache.setdefault(h["metric"], training_values(training or {}, h["metric"]))
            terms = [_run_term(tv, m, c) for m, _, c in specs]
        else:
            terms = [cell(episodes, values, h["metric"], m, s, c) for m, s, c in specs]
        row = {k: h[k] for k in ("claim", "family", "hypothesis", "metric", "scene", "versus_scene", "a", "b")}
        learned = [m in METHODS and METHODS[m].learned for m, _, _ in specs]
        rng = cell_rng(seed, h["claim"], h["hypothesis"])
        rows.append({**row, **judge(terms, learned, reps, rng, BOUNDED.get(h["metric"]))})
    return holm_verdicts(pd.DataFrame(rows), "family")[COLUMNS]


def judge(
    terms: list[Term | None],
    learned: list[bool],
    reps: int,
    rng: np.random.Generator,
    bounded: float | None = None,
) -> dict:
    """One contrast (:func:`omcrl.eval.stats.contrast`) as a row's fields: ``estimate, lo, hi, p, seeds, layouts,
    var_seed, var_layout`` and ``_few``. A missing term (a method not evaluated) gives NaN throughout, 0 seeds.
    ``learned`` says which terms are of a learned method: one of a single training seed shows no seed spread, so its
    interval is over layouts alone and says nothing about another training run; the row is then reported but not
    judged (``p`` NaN, ``_few`` True: :func:`holm_verdicts` calls it ``one seed``). ``bounded``: the metric's upper
    bound (:data:`omcrl.eval.stats.BOUNDED`), so the interval keeps to the values the contrast can take."""
    if any(t is None for t in terms):
        return {"estimate": math.nan, "lo": math.nan, "hi": math.nan, "p": math.nan, "seeds": 0, "layouts": 0,
                "var_seed": math.nan, "var_layout": math.nan, "_few": False}  # fmt: skip
    e = contrast([t for t in terms if t is not None], reps, rng=rng, bounded=bounded)
    few = any(t is not None and t.seeds is None and is_learned for t, is_learned in zip(terms, learned))
    return {"estimate": e.estimate, "lo": e.lo, "hi": e.hi, "p": math.nan if few else e.p, "seeds": e.seeds or 1,
            "layouts": e.layouts, "var_seed": e.var_seed, "var_layout": e.var_layout, "_few": few}  # fmt: skip


def holm_verdicts(df: pd.DataFrame, family: str) -> pd.DataFrame:
    """``df`` (rows of :func:`judge`) with ``p_holm`` (Holm–Bonferroni within each value of the column ``family``),
    ``verdict`` (holds / reversed / undecided at 5 %, one seed, not run), ``seeds_to_decide`` (undecided rows,
    at the family's Bonferroni level: :func:`seeds_to_decide`) and, where no number of seeds would do,
    ``layouts_to_decide`` (:func:`layouts_to_decide`, the same level)."""
    df = df.copy()
    df["p_holm"] = math.nan
    level = pd.Series(ALPHA, index=df.index)
    for fam in dict.fromkeys(df[family]) if len(df) else ():
        sel = (df[family] == fam).to_numpy()
        p = df.loc[sel, "p"].to_numpy(float)
        df.loc[sel, "p_holm"] = _holm(p)
        level[sel] = ALPHA / max(1, int(np.isfinite(p).sum()))
    few = df["_few"].fillna(False).astype(bool) if "_few" in df else pd.Series(False, index=df.index)
    df["verdict"] = [
        "one seed" if f else _verdict(r.estimate, r.p_holm) for f, r in zip(few, df.itertuples(), strict=True)
    ]
    df["seeds_to_decide"] = [
        seeds_to_decide(r.estimate, r.var_seed, r.var_layout, r.seeds, a, getattr(r, "layouts", None))
        if r.verdict == "undecided"
        else math.nan
        for r, a in zip(df.itertuples(), level, strict=True)
    ]
    df["layouts_to_decide"] = [
        layouts_to_decide(r.estimate, r.var_layout, getattr(r, "layouts", None), a)
        if r.seeds_to_decide == math.inf
        else math.nan
        for r, a in zip(df.itertuples(), level, strict=True)
    ]
    return df.drop(columns=["_few"], errors="ignore")


def _term_specs(h: dict) -> list[tuple[str, str, float]]:
    """``[(method, scene, coefficient)]`` of the contrast of hypothesis ``h``, signed so that a positive value is
    the paper's direction (module docstring); training metrics live in the training scene."""
    sign = 1.0 if h["better"] == "higher" else -1.0
    a, b, s, v = h["a"], h["b"], h["scene"], h["versus_scene"]
    if h["metric"] in TRAINING_METRICS or h["kind"] == "order":
        return [(a, s, sign), (b, s, -sign)]
    if h["kind"] == "drop":
        return [(a, s, sign), (a, v, -sign)]
    return [(a, s, sign), (b, s, -sign), (a, v, -sign), (b, v, sign)]


def _verdict(estimate: float, p_holm: float) -> str:
    if not math.isfinite(p_holm):
        return "not run"
    if p_holm < ALPHA:
        return "holds" if estimate > 0 else "reversed"
    return "undecided"


def cell(
    episodes: pd.DataFrame, values: pd.DataFrame, metric: str, method: str, scene: str, coef: float
) -> Term | None:
    """The :class:`omcrl.eval.stats.Term` of ``method``'s ``metric`` in ``scene`` (``values``: the episodes'
    :func:`omcrl.eval.metrics.episode_values`, same index), weighted ``coef``; None when it was not evaluated."""
    if episodes.empty:
        return None
    g = episodes[(episodes["method"] == method) & (episodes["scene"] == scene)]
    if g.empty:
        return None
    return term(g, values.loc[g.index, metric].to_numpy(), scene, coef)


def _run_term(values: dict[str, dict[int, float]], method: str, coef: float) -> Term | None:
    v = values.get(method)
    if not v:
        return None
    seeds = tuple(sorted(v))
    return Term(np.array([[v[s]] for s in seeds]), seeds if len(seeds) > 1 else None, ("run",), "training", coef)


def verdict_counts(verdicts: pd.DataFrame) -> pd.DataFrame:
    """Per claim: how many of its hypotheses hold, are reversed, undecided, not run or of one seed, and the
    claim's verdict (``holds`` when every judged hypothesis holds, ``reversed`` when any is reversed and none
    holds, ``undecided`` when none is decided, else ``mixed``; ``one seed`` / ``not run`` when none was judged)."""
    out = []
    for claim, g in verdicts.groupby("claim", sort=False):
        n = g["verdict"].value_counts()
        h, r, u, x, one = (int(n.get(k, 0)) for k in ("holds", "reversed", "undecided", "not run", "one seed"))
        run = len(g) - x - one
        if run == 0:
            v = "one seed" if one else "not run"
        elif h == run:
            v = "holds"
        elif r and not h:
            v = "reversed"
        elif h == 0 and r == 0:
            v = "undecided"
        else:
            v = "mixed"
        out.append({"claim": claim, "family": g["family"].iloc[0], "hypotheses": len(g), "holds": h, "reversed": r,
                    "undecided": u, "not run": x, "one seed": one, "verdict": v})  # fmt: skip
    return pd.DataFrame(out)


def verdicts_markdown(verdicts: pd.DataFrame) -> str:
    """The verdicts as Markdown: one line per claim (counts and verdict), then every hypothesis with its signed
    estimate (the paper's direction positive), 95 % interval, Holm-adjusted p and, where undecided, the seeds
    that would decide it (or, where no number of seeds would, the layouts it would take with many seeds)."""
    c = verdict_counts(verdicts)
    lines = [
        "| claim | family | hypotheses | holds | reversed | undecided | not run | one seed | verdict |",
        "|---" * 9 + "|",
    ]
    lines += [f"| {r.claim} | {r.family} | {r.hypotheses} | {r.holds} | {r.reversed} | {r.undecided} | {r[7]} | "
              f"{r[8]} | **{r.verdict}** |" for r in c.itertuples()]  # fmt: skip
    lines += ["", "| claim | hypothesis | estimate [95 % CI] | p (Holm) | verdict | seeds to decide |",
              "|---|---|---|---|---|---|"]  # fmt: skip
    for r in verdicts.itertuples():
        if r.verdict == "not run":
            cell, p = "–", "–"
        elif not math.isfinite(r.estimate):  # e.g. TTS where a method never succeeds: nothing to compare
            cell, p = "– (no value on one side)", "–"
        elif r.verdict == "one seed":
            cell, p = f"{r.estimate:+.3g} [{r.lo:+.3g}, {r.hi:+.3g}] (layouts only)", "–"
        else:
            cell, p = f"{r.estimate:+.3g} [{r.lo:+.3g}, {r.hi:+.3g}]", f"{r.p_holm:.3g}"
        need = "" if not math.isfinite(r.seeds_to_decide) else f"{int(r.seeds_to_decide)}"
        if r.verdict == "undecided" and r.seeds_to_decide == math.inf:
            more = getattr(r, "layouts_to_decide", math.nan)
            need = "none at these layouts" + (f"; ≥ {int(more):,} layouts" if math.isfinite(more) else "")
        lines.append(f"| {r.claim} | {r.hypothesis} | {cell} | {p} | {r.verdict} | {need} |")
    return "\n".join(lines) + "\n"


def write_verdicts(
    episodes: pd.DataFrame,
    training: Mapping[str, Mapping[int, str | Path]] | None,
    directory: str | Path,
    suite: str = "v2",
    reps: int = DEFAULT_REPS,
) -> tuple[pd.DataFrame, dict[str, Path]]:
    """:func:`ledger_verdicts` written as ``ledger_verdicts.csv`` (every hypothesis) and ``ledger_verdicts.md``
    (:func:`verdicts_markdown`) in ``directory``; returns the verdicts and the paths."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    v = ledger_verdicts(episodes, training, suite, reps)
    paths = {"verdicts_csv": d / "ledger_verdicts.csv", "verdicts_md": d / "ledger_verdicts.md"}
    atomic_write_text(paths["verdicts_csv"], v.to_csv(index=False))
    atomic_write_text(paths["verdicts_md"], verdicts_markdown(v))
    return v, paths


def changes_from_v1(v1_claims: pd.DataFrame, verdicts: pd.DataFrame) -> pd.DataFrame:
    """Which verdicts changed from the v1 suite: each ordering the v1 reference checked (``a > b`` on SR in one of
    the paper's unseen scenes) beside the ledger hypothesis on v2 that tests the same ordering in the same scene
    family (furniture, barrier, tree).

    Parameters
    ----------
    v1_claims : the v1 reference's rows ``claim`` (``"a > b"``), ``scene``, ``diff``, ``lo``, ``hi`` (SR points),
        ``verdict`` (:class:`omcrl.pipeline.records.Table1Record` ``claims``).
    verdicts : :func:`ledger_verdicts` on v2.

    Returns
    -------
    One row per matched pair: ``ordering``, ``family``, ``v1_scene``, ``v1`` (difference [CI] in points),
    ``v1_verdict``, ``v2_scene``, ``v2`` (estimate [CI]), ``v2_verdict``, ``changed`` (both judged and different;
    None while v2 has no judged verdict: ``one seed`` / ``not run``).
    """
    v2 = verdicts[(verdicts["metric"] == "SR") & (verdicts["versus_scene"].fillna("") == "")]
    by = {(r.a, r.b, scene_spec(r.scene).paper_scene): r for r in v2.itertuples()}
    rows = []
    for c in v1_claims.itertuples():
        a, _, b = str(c.claim).partition(" > ")
        fam = scene_spec(c.scene).paper_scene
        r = by.get((a, b, fam))
        if fam is None or r is None:
            continue
        judged = r.verdict in ("holds", "reversed", "undecided")
        rows.append({
            "ordering": c.claim,
            "family": fam,
            "v1_scene": c.scene,
            "v1": f"{c.diff:+.0f} [{c.lo:+.0f}, {c.hi:+.0f}]",
            "v1_verdict": c.verdict,
            "v2_scene": r.scene,
            "v2": "–" if not math.isfinite(r.estimate) else f"{r.estimate:+.0f} [{r.lo:+.0f}, {r.hi:+.0f}]",
            "v2_verdict": r.verdict,
            "changed": (r.verdict != c.verdict) if judged else None,
        })  # fmt: skip
    return pd.DataFrame(rows)


JUDGED = ("holds", "reversed", "undecided")
DECIDED = ("holds", "reversed")
# How two readings of one hypothesis relate, in the order a reader wants them.
AGREEMENT = ("alike", "opposite", "second only", "first only", "undecided in both")


def compare_readings(first: pd.DataFrame, second: pd.DataFrame) -> pd.DataFrame:
    """Two readings of the ledger on separate data, hypothesis by hypothesis: the grid's pre-declared verdicts
    (``first``) and a confirmation's (``second``: other layouts, or other runs).

    Parameters
    ----------
    first, second : :func:`ledger_verdicts` rows (``claim``, ``family``, ``hypothesis``, ``estimate``, ``lo``,
        ``hi``, ``verdict``), each Holm-adjusted within its own families.

    Returns
    -------
    One row per hypothesis judged in both (holds / reversed / undecided; a row of one seed or not run in either is
    left out): the two readings' ``estimate_*``, ``lo_*``, ``hi_*``, ``verdict_*`` (suffixes ``_first`` and
    ``_second``) and ``agreement``: ``alike`` (decided the same way in both), ``opposite`` (decided both ways),
    ``second only`` / ``first only`` (decided in one, undecided in the other), ``undecided in both``. Ordered by
    :data:`AGREEMENT`, then the ledger's order.
    """
    cols = ["claim", "family", "hypothesis", "estimate", "lo", "hi", "verdict"]
    key = ["claim", "family", "hypothesis"]
    a, b = first[cols].reset_index(names="order"), second[cols]
    m = a.merge(b, on=key, suffixes=("_first", "_second"))
    m = m[m["verdict_first"].isin(JUDGED) & m["verdict_second"].isin(JUDGED)].copy()

    def relation(x: str, y: str) -> str:
        if x in DECIDED and y in DECIDED:
            return "alike" if x == y else "opposite"
        if y in DECIDED:
            return "second only"
        return "first only" if x in DECIDED else "undecided in both"

    m["agreement"] = [relation(x, y) for x, y in zip(m["verdict_first"], m["verdict_second"], strict=True)]
    rank = {k: i for i, k in enumerate(AGREEMENT)}
    m = m.sort_values(["agreement", "order"], key=lambda s: s.map(rank) if s.name == "agreement" else s)
    return m.drop(columns="order").reset_index(drop=True)


def readings_markdown(both: pd.DataFrame, first: str = "grid", second: str = "confirmation") -> str:
    """:func:`compare_readings` as Markdown: the count of each agreement, then every hypothesis decided in at least
    one reading with both estimates [95 % CI] and verdicts (rows undecided in both are counted, not listed)."""
    n = both["agreement"].value_counts()
    words = {"alike": "decided alike", "opposite": "decided in opposite directions",
             "second only": f"decided by the {second} only", "first only": f"decided by the {first} only",
             "undecided in both": "undecided in both"}  # fmt: skip
    tally = "; ".join(f"{words[k]} {int(n.get(k, 0))}" for k in AGREEMENT)
    lines = [f"Of {len(both)} hypotheses judged in both readings: {tally}.", ""]
    shown = both[both["agreement"] != "undecided in both"]
    if shown.empty:
        return "\n".join(lines) + "\n"

    def cell(r: Any, s: str) -> str:
        e, lo, hi = getattr(r, f"estimate_{s}"), getattr(r, f"lo_{s}"), getattr(r, f"hi_{s}")
        return "–" if not math.isfinite(e) else f"{e:+.3g} [{lo:+.3g}, {hi:+.3g}]"

    lines += [
        f"| claim | hypothesis | {first} | {first} verdict | {second} | {second} verdict | agreement |",
        "|---|---|---|---|---|---|---|",
    ]
    lines += [f"| {r.claim} | {r.hypothesis} | {cell(r, 'first')} | {r.verdict_first} | {cell(r, 'second')} | "
              f"{r.verdict_second} | {r.agreement} |" for r in shown.itertuples()]  # fmt: skip
    return "\n".join(lines) + "\n"
