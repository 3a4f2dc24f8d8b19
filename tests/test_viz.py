"""Figures: Fig. 5's learning curves from runs' metrics files, one colour per method, and figure files on disk."""

from __future__ import annotations

import matplotlib.colors as mcolors
import numpy as np

from omcrl.rl.methods import TABLE1_METHODS
from omcrl.viz import METHOD_COLORS, method_color, save_figure
from omcrl.viz.compare import plot_learning_curves, seed_curves


def _run(folder, rng, level: float):
    folder.mkdir(parents=True)
    rows = ["step,metric,value"]
    for k, step in enumerate(range(2048, 40960, 2048)):
        rows.append(f"{step},success_rate,{min(1.0, level * k / 18 + rng.normal(0, 0.02)):.4f}")
        rows.append(f"{step},episodic_return,{10 * level * k / 18:.4f}")
    (folder / "metrics.csv").write_text("\n".join(rows) + "\n")
    return folder


def test_learning_curves_average_seeds_with_a_band_and_keep_each_methods_colour(tmp_path):
    rng = np.random.default_rng(0)
    runs = {
        "ours": {s: _run(tmp_path / f"ours{s}", rng, 0.9) for s in (0, 1, 2)},
        "ppo": {s: _run(tmp_path / f"ppo{s}", rng, 0.5) for s in (0, 1)},
        "a variant": {0: _run(tmp_path / "v0", rng, 0.7)},
    }
    x, mean, lo, hi = seed_curves(runs["ours"], "success_rate")
    assert len(x) == len(mean) and np.all(lo <= mean + 1e-12) and np.all(mean <= hi + 1e-12)
    assert 0.7 < mean[-1] < 0.9 and np.any(hi > lo)  # a trailing 5-update mean of a ramp to 0.9
    fig = plot_learning_curves(runs)
    ax = fig.axes[1]  # success rate
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    assert set(lines) == {"Ours (3 seeds)", "PPO (2 seeds)", "a variant (1 seed)"}
    assert mcolors.same_color(lines["Ours (3 seeds)"].get_color(), METHOD_COLORS["ours"])
    assert mcolors.same_color(lines["PPO (2 seeds)"].get_color(), METHOD_COLORS["ppo"])
    assert ax.get_ylim() == (-0.02, 1.02) and ax.get_xlabel() == "env steps"
    fig.canvas.draw()  # the legend clear of the data: outside every panel, inside the figure (issue 78)
    legend = ax.get_legend().get_window_extent()
    assert not any(legend.overlaps(a.get_window_extent()) for a in fig.axes)
    assert fig.bbox.contains(legend.x1 - 1, legend.y0 + 1) and fig.bbox.contains(legend.x0, legend.y1 - 1)
    png = save_figure(fig, tmp_path / "figures", "fig5")
    assert png.suffix == ".png" and png.stat().st_size > 10_000


def test_a_method_has_one_colour_by_name_or_by_label():
    assert method_color("ours-noOT") == method_color("Ours w/o OT") == METHOD_COLORS["ours-noOT"]
    assert method_color("HybridAPF") == method_color("hybrid-apf")
    assert len({METHOD_COLORS[m] for m in METHOD_COLORS if m != "HybridAPF"}) == len(METHOD_COLORS) - 1
    assert method_color("something else") == "#4c72b0"
    # Table I's rows, the controls among them, each in a colour of its own.
    assert len({method_color(m) for m in TABLE1_METHODS}) == len(TABLE1_METHODS)
    assert "#4c72b0" not in {method_color(m) for m in TABLE1_METHODS}


def test_the_ledger_figure_stacks_each_claims_hypotheses_by_verdict():
    import pandas as pd

    from omcrl.viz.compare import VERDICT_COLORS, plot_ledger_verdicts

    v = pd.DataFrame(
        {
            "claim": ["E1", "E1", "E1", "T1"],
            "family": ["primary"] * 3 + ["secondary"],
            "verdict": ["holds", "reversed", "one seed", "not run"],
        }
    )
    fig = plot_ledger_verdicts(v)
    ax = fig.axes[0]
    bars = [(round(p.get_width()), p.get_facecolor()) for p in ax.patches]
    assert len(bars) == 4 and all(w == 1 for w, _ in bars)  # one hypothesis per verdict, none drawn twice
    texts = [t.get_text() for t in ax.texts]
    assert texts == ["mixed", "not run"]  # E1 holds and is reversed: mixed
    assert [t.get_text() for t in ax.get_yticklabels()] == ["E1 (p)", "T1 (s)"]
    assert set(VERDICT_COLORS) == {"holds", "reversed", "undecided", "one seed", "not run"}
