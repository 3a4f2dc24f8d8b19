"""Ledger verdicts (omcrl.eval.verdicts): contrasts signed in the paper's direction, Holm within families, the
power line, and the training metrics of Fig. 5 from metrics files."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from omcrl.eval.verdicts import (
    _detectable,
    _holm,
    holm_verdicts,
    layouts_to_decide,
    ledger_verdicts,
    seeds_to_decide,
    training_values,
    verdict_counts,
    verdicts_markdown,
)

SCENES = ("box-v2", "furniture-v2", "barrier-v2", "tree-v2")


def _episodes(sr: dict[str, float], seeds=range(5), layouts=50, rng=None) -> pd.DataFrame:
    rng = rng or np.random.default_rng(0)
    rows = []
    for m, p in sr.items():
        for s in seeds if m not in ("hybrid-apf",) else [0]:
            for scene in SCENES:
                ok = rng.random(layouts) < p
                for j in range(layouts):
                    rows.append({"method": m, "scene": scene, "train_seed": s, "seed": j, "success": bool(ok[j]),
                                 "collision": not ok[j], "final_distance": 0.1 if ok[j] else 3.0,
                                 "min_distance": 0.1 if ok[j] else 2.0, "path_length": 8.0,
                                 "optimal_path_length": 7.0, "steps": 80})  # fmt: skip
    return pd.DataFrame(rows)


def test_a_clear_ordering_holds_a_reversed_one_is_reversed_and_missing_methods_are_not_run():
    ep = _episodes({"ours": 0.85, "npe": 0.2, "curl": 0.55, "ppo": 0.5, "hybrid-apf": 0.3})
    v = ledger_verdicts(ep, reps=300).set_index("hypothesis")
    assert v.loc["ours > npe on SR in tree-v2", "verdict"] == "holds"
    assert v.loc["ours > npe on SR in tree-v2", "estimate"] > 50
    # CR is better lower: ours collides less, so the signed estimate is positive too.
    assert v.loc["ours > npe on CR in tree-v2", "estimate"] > 0
    # The paper's "CURL above NPE" holds here; "NPE above PPO" (E4) is reversed (0.2 vs 0.5).
    assert v.loc["npe > ppo on SR in furniture-v2", "verdict"] == "reversed"
    assert v.loc["ours > ours-noOT on SR in tree-v2", "verdict"] == "not run"
    counts = verdict_counts(ledger_verdicts(ep, reps=300)).set_index("claim")
    assert counts.loc["E9", "verdict"] == "not run" and counts.loc["E4", "verdict"] == "reversed"


def test_an_equal_pair_is_undecided_with_a_power_line():
    ep = _episodes({"ours": 0.6, "curl": 0.55}, rng=np.random.default_rng(4))
    v = ledger_verdicts(ep, reps=300).set_index("hypothesis")
    row = v.loc["ours > curl on SR in barrier-v2"]
    assert row["verdict"] == "undecided" and row["lo"] < 0 < row["hi"]
    assert row["seeds_to_decide"] >= 5 or math.isinf(row["seeds_to_decide"])


def test_holm_is_monotone_and_never_below_the_raw_p():
    p = np.array([0.01, 0.04, 0.03, math.nan, 0.005])
    adj = _holm(p)
    assert math.isnan(adj[3])
    np.testing.assert_allclose(adj[[4, 0, 2, 1]], [0.02, 0.03, 0.06, 0.06])
    assert (adj[np.isfinite(p)] >= p[np.isfinite(p)]).all()


def test_seeds_to_decide():
    # d = 10, layout part 4, seed part 9 at 5 seeds. A normal approximation would say 6: (10 / 2.80)^2 - 4 = 8.76,
    # ceil(45 / 8.76) = 6. The t test the verdicts use has Satterthwaite's degrees of freedom (about 12 at 6 seeds),
    # so it needs 7: the returned n clears the test's 80 % power and n - 1 does not.
    n = seeds_to_decide(10.0, 9.0, 4.0, 5)
    assert n == 7
    assert _detectable(10.0, 45.0, 4.0, n, math.inf, 0.05) and not _detectable(10.0, 45.0, 4.0, n - 1, math.inf, 0.05)
    # At a Bonferroni level of 38 rows: more seeds, each the first that clears it.
    strict = seeds_to_decide(10.0, 9.0, 4.0, 5, alpha=0.05 / 38)
    assert strict == 24 and not _detectable(10.0, 45.0, 4.0, strict - 1, math.inf, 0.05 / 38)
    # 50 layouts (49 degrees of freedom in the layout part) never need fewer seeds than infinitely many.
    assert seeds_to_decide(10.0, 9.0, 4.0, 5, layouts=50) >= n
    assert math.isinf(seeds_to_decide(1.0, 9.0, 4.0, 5))  # the layout part alone is wider than the effect
    assert math.isnan(seeds_to_decide(0.0, 9.0, 4.0, 5))
    assert seeds_to_decide(10.0, 0.0, 1.0, 5) == 5  # no seed spread: the seeds it has
    assert math.isinf(seeds_to_decide(4.0, 0.0, 8.0, 1, layouts=50))  # a planner's row: only layouts would help


def test_layouts_to_decide_where_no_number_of_seeds_would():
    # A paired SR difference of 10 points whose layout part is 72 (SE 8.5 points at 50 layouts): no number of
    # seeds decides it at a Bonferroni level of 38 rows; with the seed part gone, the layouts that would are the
    # first n that clear the test (the layout part at 72 * 50 / n, n - 1 degrees of freedom) where n - 1 does not.
    a = 0.05 / 38
    assert math.isinf(seeds_to_decide(10.0, 20.0, 72.0, 4, a, layouts=50))
    n = layouts_to_decide(10.0, 72.0, 50, a)
    assert 50 < n < math.inf
    assert _detectable(10.0, 0.0, 3600 / n, math.inf, n - 1, a) and not _detectable(
        10.0, 0.0, 3600 / (n - 1), math.inf, n - 2, a
    )
    # Half the effect wants about four times the layouts; an effect the 50 layouts already resolve wants no more.
    assert layouts_to_decide(5.0, 72.0, 50, a) / n == pytest.approx(4, rel=0.05)
    assert layouts_to_decide(40.0, 72.0, 50, a) == 50
    assert math.isnan(layouts_to_decide(0.0, 72.0, 50, a)) and math.isnan(layouts_to_decide(10.0, 72.0, None, a))
    assert math.isnan(layouts_to_decide(10.0, 0.0, 50, a))


def test_the_power_line_names_the_layouts_a_layout_bound_row_would_need():
    row = {"claim": "E9", "family": "primary", "hypothesis": "ours > x on SR in tree-v2", "metric": "SR",
           "scene": "tree-v2", "versus_scene": None, "a": "ours", "b": "x", "estimate": 10.0, "lo": -7.0, "hi": 27.0,
           "p": 0.2, "seeds": 4, "layouts": 50, "var_seed": 20.0, "var_layout": 72.0, "_few": False}  # fmt: skip
    decided = dict(row, hypothesis="ours > y on SR in tree-v2", estimate=60.0, lo=40.0, hi=80.0, p=1e-6)
    df = holm_verdicts(pd.DataFrame([row, decided]), "family")
    assert df["verdict"].tolist() == ["undecided", "holds"]
    want = layouts_to_decide(10.0, 72.0, 50, 0.05 / 2)  # the family's Bonferroni level: two rows
    assert df["layouts_to_decide"].iloc[0] == want and math.isnan(df["layouts_to_decide"].iloc[1])
    assert f"none at these layouts; ≥ {int(want):,} layouts |" in verdicts_markdown(df)


def test_the_power_line_counts_the_family_a_row_is_judged_in():
    # 40 rows of one family; the first is significant at 5 % alone (p 0.01) but not after Holm (40 x 0.01). At 3
    # seeds with all its variance in the seed part and d = 2.58 standard errors, 5 % unadjusted would want 6 seeds;
    # the family's level (0.05 / 40) wants 13, and the line must say 13: at 6 seeds it would still be undecided.
    rows = [{"family": "primary", "p": 0.01, "estimate": 2.58, "var_seed": 1.0, "var_layout": 0.0, "seeds": 3}]
    rows += [{"family": "primary", "p": 0.5, "estimate": 0.1, "var_seed": 1.0, "var_layout": 0.0, "seeds": 3}] * 39
    rows += [{"family": "secondary", "p": 0.01, "estimate": 2.58, "var_seed": 1.0, "var_layout": 0.0, "seeds": 3}]
    v = holm_verdicts(pd.DataFrame(rows).assign(_few=False), "family")
    assert v.loc[0, "verdict"] == "undecided" and seeds_to_decide(2.58, 1.0, 0.0, 3) == 6
    assert v.loc[0, "seeds_to_decide"] == seeds_to_decide(2.58, 1.0, 0.0, 3, alpha=0.05 / 40) == 13
    # Alone in its family, the same row is decided at 5 %: nothing to add.
    assert v.loc[40, "verdict"] == "holds" and math.isnan(v.loc[40, "seeds_to_decide"])


def test_training_values_read_the_return_curve(tmp_path):
    rows = [{"step": s, "metric": "episodic_return", "value": float(s)} for s in range(0, 101, 10)]
    p = tmp_path / "metrics.csv.gz"
    pd.DataFrame(rows).to_csv(p, index=False)
    out = {k: training_values({"ours": {0: p}}, k)["ours"][0] for k in ("return_auc", "return_final")}
    assert out["return_auc"] == pytest.approx(50.0) and out["return_final"] == pytest.approx(95.0)


def test_a_learned_method_of_one_seed_is_shown_not_judged():
    ep = _episodes({"ours": 0.9, "npe": 0.1}, seeds=[0])
    v = ledger_verdicts(ep, reps=200).set_index("hypothesis")
    row = v.loc["ours > npe on SR in tree-v2"]
    assert row["verdict"] == "one seed" and row["estimate"] > 50 and math.isnan(row["p_holm"])
    counts = verdict_counts(ledger_verdicts(ep, reps=200)).set_index("claim")
    assert counts.loc["E8", "verdict"] == "one seed"


def test_changes_from_v1_pairs_each_ordering_with_the_same_hypothesis_on_v2():
    import pandas as pd

    from omcrl.eval.verdicts import changes_from_v1

    cols = ["claim", "scene", "diff", "lo", "hi", "verdict"]
    v1 = pd.DataFrame(
        [
            ("ours > npe", "tree-v0", -27.0, -45.0, -10.0, "reversed"),
            ("ours > npe", "box-v0", -1.0, -6.0, 5.0, "undecided"),
            ("curl > ppo", "barrier-v0", 0.0, -12.0, 11.0, "undecided"),
        ],
        columns=cols,
    )
    nan = float("nan")
    v2 = pd.DataFrame(
        [
            {"metric": "SR", "versus_scene": "", "a": "ours", "b": "npe", "scene": "tree-v2", "estimate": 8.0,
             "lo": 1.0, "hi": 15.0, "verdict": "holds"},
            {"metric": "SR", "versus_scene": "", "a": "curl", "b": "ppo", "scene": "barrier-v2", "estimate": nan,
             "lo": nan, "hi": nan, "verdict": "not run"},
            {"metric": "SR", "versus_scene": "barrier-v2", "a": "npe", "b": "npe", "scene": "box-v2", "estimate": 5.0,
             "lo": 1.0, "hi": 9.0, "verdict": "holds"},
        ]
    )  # fmt: skip
    ch = changes_from_v1(v1, v2)
    # box has no paper scene family (the training room is not a claim's scene): two rows, not three.
    assert list(ch["ordering"]) == ["ours > npe", "curl > ppo"]
    tree = ch.iloc[0]
    assert (tree.v1_verdict, tree.v2_verdict, tree.changed) == ("reversed", "holds", True)
    assert tree.v1 == "-27 [-45, -10]" and tree.v2 == "+8 [+1, +15]"
    assert ch.iloc[1].changed is None and ch.iloc[1].v2 == "–"  # not judged on v2: no verdict change claimed


def test_an_interval_keeps_to_the_values_a_contrast_can_take():
    """A difference of two SRs lies in [-100, 100] pp: its interval is cut there (near the bound the t interval
    spills over, as the oracle against a one-seed student did at -98 [-102, -94]); its estimate and p stay."""
    from omcrl.eval.stats import Term, contrast

    layouts = tuple(range(50))
    a = Term(np.where(np.arange(50) < 49, 100.0, 0.0)[None, :], None, layouts, "tree-v2", 1.0)
    b = Term(np.where(np.arange(50) < 1, 100.0, 0.0)[None, :], None, layouts, "tree-v2", -1.0)
    free = contrast([a, b], 400, rng=np.random.default_rng(0))
    cut = contrast([a, b], 400, rng=np.random.default_rng(0), bounded=100.0)
    assert free.hi > 100.0  # what the cut is for
    assert cut.hi == 100.0 and cut.lo == free.lo and (cut.estimate, cut.p) == (free.estimate, free.p)


def test_two_readings_of_the_ledger_are_compared_hypothesis_by_hypothesis():
    from omcrl.eval.verdicts import compare_readings, readings_markdown

    def reading(verdicts, estimates):
        n = len(verdicts)
        return pd.DataFrame({"claim": [f"E{i}" for i in range(n)], "family": "primary",
                             "hypothesis": [f"h{i}" for i in range(n)], "estimate": estimates,
                             "lo": [e - 5 for e in estimates], "hi": [e + 5 for e in estimates],
                             "verdict": verdicts})  # fmt: skip

    first = reading(["holds", "undecided", "reversed", "holds", "undecided", "one seed", "undecided"],
                    [10, 2, -9, 8, 1, 3, 0])  # fmt: skip
    second = reading(["holds", "reversed", "undecided", "reversed", "undecided", "holds", "not run"],
                     [12, -7, -2, -6, 0, 9, float("nan")])  # fmt: skip
    both = compare_readings(first, second)
    # The rows of one seed or not run in either reading are left out; the others ordered by agreement.
    assert list(both["hypothesis"]) == ["h0", "h3", "h1", "h2", "h4"]
    assert list(both["agreement"]) == ["alike", "opposite", "second only", "first only", "undecided in both"]
    assert both.loc[0, "estimate_second"] == 12 and both.loc[0, "verdict_first"] == "holds"
    md = readings_markdown(both)
    assert md.startswith("Of 5 hypotheses judged in both readings: decided alike 1; decided in opposite directions 1")
    assert "| E1 | h1 | +2 [-3, +7] | undecided | -7 [-12, -2] | reversed | second only |" in md
    assert "h4" not in md  # undecided in both: counted, not listed
