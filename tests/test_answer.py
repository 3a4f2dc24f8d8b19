"""The answer first (issue 78): the README's and docs/results.md's opening sentences are what the data give, their
links land on headings of docs/results.md, and each sentence follows the verdicts it reports."""

from __future__ import annotations

import math
import re

import pandas as pd

from omcrl.eval.ledger import hypotheses
from omcrl.pipeline.answer import ANCHORS, ANSWER_END, ANSWER_START, answer_block, answer_facts, claim_words
from omcrl.rl.methods import TABLE1_METHODS
from omcrl.scenes import SUITES


def _verdicts(overrides: dict[tuple[str, str, str], tuple[float, str]] | None = None) -> pd.DataFrame:
    """Every hypothesis of the ledger on v2, undecided at +1 point unless ``overrides[(claim, b, scene)]`` gives
    (estimate, verdict)."""
    rows = []
    for h in hypotheses("v2"):
        est, verdict = (overrides or {}).get((h["claim"], h["b"], h["scene"]), (1.0, "undecided"))
        rows.append({**h, "estimate": est, "lo": est - 5, "hi": est + 5, "p": 0.5, "p_holm": 1.0, "verdict": verdict,
                     "seeds": 5, "seeds_to_decide": math.inf, "layouts_to_decide": 900.0, "var_seed": 1.0,
                     "var_layout": 2.0})  # fmt: skip
    return pd.DataFrame(rows)


def _table(sr: float = 50.0) -> pd.DataFrame:
    idx = pd.MultiIndex.from_product([[*TABLE1_METHODS, "hybrid-apf"], SUITES["v2"]], names=["method", "scene"])
    return pd.DataFrame({"SR": sr}, index=idx)


def _said(*args, **kwargs) -> str:
    """The block's words on one line (the page wraps them at 120 characters)."""
    return " ".join(answer_block(answer_facts(*args, **kwargs)).split())


def test_a_claim_is_said_in_plain_words_from_its_fields():
    assert claim_words("T1") == "Ours above PPO, CURL and NPE in return over training"
    assert claim_words("E8") == "NPE's success rate lower in furniture, barrier and tree than in box"
    assert claim_words("E7") == "Ours' lead over CURL in success rate larger in tree than in furniture"


def test_the_sentences_follow_the_verdicts_they_report():
    """All undecided: "none of ours' 9 … is decided"; one E1 hypothesis holding makes it "1 of ours' 9 … are
    decided" and moves E1 out of the undecided claims; the privileged planner's reversals are counted as its."""
    text = _said(_verdicts(), _table())
    assert "none of ours' 9 success-rate hypotheses against NPE, CURL and PPO" in text
    assert "all its 55 hypotheses against them" in text
    assert "*undecided*: T1, T2, T3, T4, T5, T6, T7, T8" in text
    assert "*undecided*: E2, E3, E4, E5, E6, E7, E8, E9" in text
    assert "C1 undecided in 4 of 4 scenes" in text
    assert "Layouts or look" not in text and "teacher's ceiling" not in text  # not flown / not made: not said

    v = _verdicts(
        {
            ("E1", "npe", "barrier-v2"): (12.0, "holds"),
            ("E1", "hybrid-apf", "tree-v2"): (-60.0, "reversed"),
            ("C1", "ours-random", "box-v2"): (9.0, "holds"),
            ("T1", "ppo", "box-v2"): (3.0, "holds"),
        }
    )
    text = _said(v, _table())
    assert "1 of ours' 9 success-rate hypotheses" in text and "are decided (E1; ours minus them +1 to +12" in text
    assert "Hybrid APF, which plans on the true map, is above ours in 1 of the 3 unseen scenes" in text
    assert "1 of the ledger's 1 reversed hypotheses are ours against it" in text
    assert "*mixed*: Ours above PPO, CURL and NPE in return over training (T1: holds in box)" in text
    assert "adds to the student in 1 of 4 scenes" in text


def test_the_ablations_sentence_names_each_judged_finding():
    finding = "6 linear decay beats exponential and fixed"
    summary = pd.DataFrame([{"finding": finding, "checks": 6, "verdict": "undecided"}])
    text = _said(
        _verdicts(), _table(), ablations=summary, ablation_grids=(["decay"], 6), ablation_budget=(50_000, 450_560)
    )
    assert "each variant trained for 50,000 RL env steps (11 % of Table I's 450,560);" in text
    assert "1 of 6 grids complete" in text
    assert "finding 6 (linear decay beats exponential and fixed) *undecided* in 6 checks." in text
    # a finding judged on a grid still running says so: its verdict can move
    running = _said(_verdicts(), _table(), ablations=summary, ablation_grids=(["mask-prob"], 6))
    assert "*undecided* in 6 checks (so far: its grid is still running)." in running
    # judged again on Table I's runs: said beside the sweep budget's verdict
    again = pd.DataFrame([{"finding": finding, "checks": 3, "verdict": "holds"}])
    both = _said(_verdicts(), _table(), ablations=summary, ablation_grids=(["decay"], 6), ablations_table1=again)
    assert "*undecided* in 6 checks (on Table I's runs, full budget: *holds* in 3)." in both
    # the stress room is judged apart; a resolved check there is said, all-undecided ones are not
    stressed = summary.assign(**{"stress holds": 0, "stress reversed": 1, "stress undecided": 1})
    again_stressed = again.assign(**{"stress holds": 0, "stress reversed": 0, "stress undecided": 2})
    text = _said(
        _verdicts(), _table(), ablations=stressed, ablation_grids=(["decay"], 6), ablations_table1=again_stressed
    )
    assert (
        "*undecided* in 6 checks (in the stress room, judged apart: 0 of 2 holds, 1 reversed; on Table I's runs, "
        "full budget: *holds* in 3)." in text
    )
    assert "no finding judged yet" in _said(_verdicts(), _table())


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def test_every_link_of_the_answer_lands_on_a_heading_of_results_md(repo_root):
    page = (repo_root / "docs" / "results.md").read_text(encoding="utf-8")
    slugs = {_slug(line.lstrip("#")) for line in page.splitlines() if line.startswith("#")}
    assert set(ANCHORS.values()) <= slugs, set(ANCHORS.values()) - slugs


def test_the_pages_answers_are_what_the_committed_runs_give(repo_root, pages):
    """README.md and docs/results.md open with the answer rebuilt from reference/quick/ (summary --readme): a
    hand-edited number or verdict fails here."""
    from omcrl.pipeline.glance import current_block

    readme_block, results_block = pages["README.md"][ANSWER_START], pages["docs/results.md"][ANSWER_START]
    readme = (repo_root / "README.md").read_text(encoding="utf-8")
    results = (repo_root / "docs" / "results.md").read_text(encoding="utf-8")
    assert current_block(readme, "README.md", ANSWER_START, ANSWER_END) == readme_block
    assert current_block(results, "docs/results.md", ANSWER_START, ANSWER_END) == results_block
    # the answer comes first: before Table I in the README, before the list of sections in docs/results.md
    assert readme.index(ANSWER_START) < readme.index("| method | box-v2 (training)")
    assert results.index(ANSWER_START) < results.index("- [The claim ledger]")
    assert "](docs/results.md#" in readme_block and "](#" in results_block
