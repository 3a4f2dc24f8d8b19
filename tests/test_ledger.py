"""The claim ledger (issue 44): well formed, expanded in every suite, and the docs show exactly what the code holds."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from omcrl.eval import ledger as L


def test_every_claim_names_known_methods_metrics_and_scenes_in_every_suite():
    for suite in ("v1", "v2"):
        rows = L.hypotheses(suite)
        assert len(rows) == 106 and sum(r["family"] == "primary" for r in rows) == 38
        assert sum(r["family"] == "controls" for r in rows) == 8
        assert len({r["hypothesis"] for r in rows}) == len(rows)  # no hypothesis twice
        assert {r["scene"] for r in rows if r["claim"].startswith("E")} >= {f"tree-v{2 if suite == 'v2' else 0}"}
    training = [r for r in L.hypotheses("v2") if r["metric"] in L.TRAINING_METRICS]
    assert {r["scene"] for r in training} == {"box-v2"} and len(training) == 12
    with pytest.raises(ValueError, match="suite"):
        L.hypotheses("v9")


@pytest.mark.parametrize(
    "bad, match",
    [
        (dict(metric="SRR"), "not a Table I or training metric"),
        (dict(a="ourz"), "not one of the kit's methods"),
        (dict(kind="gap"), "gap claim names one other method"),
        (dict(metric="return_auc"), "training metrics exist in the training scene only"),
    ],
)
def test_a_malformed_claim_is_refused_by_name(monkeypatch, bad, match):
    import dataclasses

    claim = dataclasses.replace(L.LEDGER[8], **bad)
    monkeypatch.setattr(L, "LEDGER", (claim,))
    with pytest.raises(ValueError, match=f"claim E1: .*{match}"):
        L.hypotheses("v2")


def test_docs_show_the_ledger_the_code_holds():
    text = (Path(__file__).parents[1] / "docs" / "results.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- ledger:begin.*?-->\n(.*?)<!-- ledger:end -->", text, re.S)
    assert block is not None and block.group(1) == L.ledger_markdown()


def test_the_controls_are_their_own_family_in_box_and_every_unseen_scene():
    """Issue 75: ours > ours-random and ours-random > ours-blind on SR in box-v2 and each unseen v2 scene, Holm within
    a family of their own (the paper's families keep their 38 + 60 hypotheses)."""
    rows = [r for r in L.hypotheses("v2") if r["family"] == "controls"]
    got = {(r["a"], r["b"], r["scene"]) for r in rows}
    scenes = ("box-v2", "furniture-v2", "barrier-v2", "tree-v2")
    assert got == {(a, b, s) for a, b in (("ours", "ours-random"), ("ours-random", "ours-blind")) for s in scenes}
    assert {r["metric"] for r in rows} == {"SR"} and {r["kind"] for r in rows} == {"order"}
