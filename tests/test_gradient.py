"""The scenes' gradient of difficulty, measured with nothing learned (issue: scenes on the paper's gradient)."""

from __future__ import annotations

import numpy as np
import pytest

from omcrl.config import load_config
from omcrl.interpret.gradient import (
    colour_histogram,
    gradient_order,
    gradient_samples,
    js_divergence,
    order_verdicts,
    perceptual_table,
    pixel_features,
)
from omcrl.models.artifact import random_encoder
from omcrl.rl.methods import encoder_config


def test_network_free_measures_are_zero_for_the_same_frames_and_grow_with_a_shift():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 120, (20, 9, 16, 16), dtype=np.uint8)
    b = a.copy()
    b[:, -3:] += 100  # the newest frame brighter
    assert js_divergence(colour_histogram(a), colour_histogram(a)) == 0.0
    assert 0.5 < js_divergence(colour_histogram(a), colour_histogram(b)) <= 1.0
    assert pixel_features(a).shape == (20, 3 * 8 * 8) and pixel_features(a).max() <= 1.0
    older = a.copy()
    older[:, :6] = 0  # only the newest frame of a stack counts
    np.testing.assert_array_equal(pixel_features(a), pixel_features(older))


@pytest.fixture(scope="module")
def quick_shift():
    """The perceptual shift at the quick preset's image size and encoder shape, from 6 pilot episodes each, for
    the v1 and the v2 suite (each from its own box)."""
    cfg = load_config("quick")
    encoders = {i: random_encoder(encoder_config(cfg, "ours"), seed=i) for i in (0, 1, 2)}
    return {s: perceptual_table(gradient_samples(cfg, episodes=6, suite=s), encoders) for s in ("v1", "v2")}


@pytest.mark.stage  # flies quick-preset pilots and planners: minutes
@pytest.mark.parametrize("suite", ["v1", "v2"])
def test_suite_orders_box_furniture_barrier_tree_on_every_measure(quick_shift, suite):
    """The criterion fixed by the issues: on random encoders (each of three inits) and on network-free pixel
    statistics, the shift from box rises box (other layouts) < furniture < barrier < tree, in v1 and in v2."""
    verdicts = order_verdicts(quick_shift[suite], suite)
    assert {"random_mmd_0", "random_mmd_1", "random_mmd_2", "pixel_mmd", "colour_js"} <= set(verdicts.measure)
    assert verdicts.holds.all(), verdicts.to_string()
    want = {"v1": ("furniture-v1", "barrier-v0", "tree-v0"), "v2": ("furniture-v2", "barrier-v2", "tree-v2")}
    assert gradient_order(suite) == ("box, other layouts", *want[suite])


@pytest.mark.stage  # flies quick-preset pilots and planners: minutes
def test_furniture_v0_room_is_the_shift_v1_removes(quick_shift):
    t = quick_shift["v1"].set_index("setting")
    for m in ("pixel_mmd", "colour_js", "random_mmd"):
        assert t.loc["furniture-v0", m] > 2 * t.loc["furniture-v1", m], m
    # v0's unseen room moves the pixels more than the barrier hall does (the diagnosis of docs/generalization.md).
    assert t.loc["furniture-v0", "pixel_mmd"] > t.loc["barrier-v0", "pixel_mmd"]


# Layouts of the fast check of the suite criteria: the first of the criteria's own layouts (the gradient stage
# measures them on 100 and more). box-v2 sits within 2-6 points of three bounds (docs/DEVIATIONS.md: 18.0 / 25.5 /
# 33.0 % on 200 layouts), and 30 layouts have a standard error of 7-9 points: its first 30 give the local APF
# 16.7 %, so box-v2 is checked on 100 (17 / 24 / 32 %); the unseen scenes, 5-60 points from theirs, on 30.
FAST_LAYOUTS, BOX_LAYOUTS = 30, 100


# 3.5 min on 2 cores (570 flown episodes), a third of the default suite's budget: slow. The default suite keeps the
# v2 layouts it measured pinned (tests/test_scenes.py::test_published_scenes_are_todays_scenes, seconds), so a scene
# edited in place still fails there; this measures the criteria again (./reproduce.sh --test -m slow).
@pytest.mark.slow
@pytest.mark.stage
def test_v2_suite_meets_its_criteria_with_nothing_learned():
    """Scenes v2, fixed before any learned method flew them: the blind pilot <= 20 % SR everywhere, the privileged
    Hybrid APF >= 90 %, the local APF <= 70 % (and >= 20 % in box-v2), >= 30 % of box-v2's layouts bend by more
    than 10 %. The perceptual order is test_suite_orders_box_furniture_barrier_tree_on_every_measure's."""
    import pandas as pd

    from omcrl.interpret.gradient import CRITERIA, criteria_table

    cfg = load_config("quick")
    box = criteria_table(cfg, ("v2",), BOX_LAYOUTS, scenes=["box-v2"])
    unseen = criteria_table(cfg, ("v2",), FAST_LAYOUTS, scenes=["furniture-v2", "barrier-v2", "tree-v2"])
    crit = pd.concat([box, unseen], ignore_index=True)
    assert len(crit) == 3 * 4 + 2 and set(crit.criterion) == {c.name for c in CRITERIA}
    assert crit.holds.all(), crit.round(1).to_string()
    assert (crit.lo <= crit.value).all() and (crit.value <= crit.hi).all()


@pytest.mark.stage  # flies quick-preset pilots and planners: minutes
def test_v1_suite_is_flown_blind_which_v2_was_built_against():
    """The reason v2 exists, measured the same way: in v1's box and tree a pilot that senses nothing reaches more
    than 20 % of the goals (criteria layouts, as above)."""
    from omcrl.eval.runner import evaluate
    from omcrl.interpret.gradient import CRITERIA_SEED_OFFSET
    from omcrl.planners import make_planner

    for scene in ("box-v0", "tree-v0"):
        ep = evaluate(make_planner("blind"), scene, FAST_LAYOUTS, 0, seed_offset=CRITERIA_SEED_OFFSET, workers=2)
        assert ep.success.mean() > 0.2, scene


def test_wilson_interval():
    from omcrl.interpret.gradient import wilson

    lo, hi = wilson(0, 20)
    assert lo == 0.0 and 10 < hi < 20
    lo, hi = wilson(10, 20)
    assert lo == pytest.approx(100 - hi) and 25 < lo < 35
