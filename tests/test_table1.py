"""Aggregation with CIs, SR significance, Table I files and the paper's values; the perceptive Hybrid APF."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from omcrl.config import load_config
from omcrl.eval import aggregate, compare_sr, mean_ci, paper_table1, summarize, write_table1
from omcrl.eval.stats import Term, contrast


def _episodes(method, scene, sr_by_seed, n=50, rng=None):
    """Synthetic episodes: per seed, the first round(sr·n) succeed."""
    rows = []
    for seed, sr in enumerate(sr_by_seed):
        k = round(sr * n)
        for i in range(n):
            ok = i < k
            rows.append(
                {
                    "method": method,
                    "scene": scene,
                    "train_seed": seed,
                    "final_distance": 0.2 if ok else 3.0,
                    "min_distance": 0.2 if ok else 1.0,
                    "success": ok,
                    "collision": not ok,
                    "path_length": 6.0,
                    "optimal_path_length": 5.0,
                    "steps": 50 + i,
                }
            )
    return pd.DataFrame(rows)


def test_bootstrap_ci_collapses_for_constant_values_and_covers_the_truth():
    m, lo, hi = mean_ci([np.full(20, 3.0), np.full(30, 3.0)])
    assert m == lo == hi == 3.0
    rng = np.random.default_rng(1)
    groups = [rng.binomial(1, 0.6, 50) * 100.0 for _ in range(3)]
    m, lo, hi = mean_ci(groups, reps=2000)
    assert lo < m < hi and lo < 60.0 < hi and (hi - lo) < 30.0
    # More episodes per seed -> a narrower interval.
    wide = mean_ci([g[:10] for g in groups], reps=2000)
    assert (wide[2] - wide[1]) > (hi - lo)
    # NaNs (TTS of failures) are left out; all-NaN gives NaN.
    assert math.isnan(mean_ci([np.full(5, np.nan)])[0])
    assert mean_ci([np.array([1.0, np.nan, 3.0])])[0] == 2.0
    # Between-seed spread widens the interval beyond what the episodes alone give: three seeds at 20, 50 and 80 %
    # (the same 50 layouts) against one seed's 150 episodes at the same 50 %.
    rng = np.random.default_rng(0)
    spread = np.stack([(rng.random(50) < p) * 100.0 for p in (0.2, 0.5, 0.8)])
    crossed = contrast([Term(spread, (0, 1, 2), tuple(range(50)), "s")])
    pooled = contrast([Term(spread.reshape(1, -1), None, tuple(range(150)), "s")])
    assert crossed.var_seed > 0 and pooled.var_seed == 0
    assert crossed.hi - crossed.lo > 3 * (pooled.hi - pooled.lo)


def test_aggregate_matches_summarize_and_reports_seeds():
    df = pd.concat([_episodes("ours", "box", [0.8, 0.6]), _episodes("ppo", "box", [0.1, 0.3])], ignore_index=True)
    agg = aggregate(df, reps=300)
    for m in ("ours", "ppo"):
        ref = summarize(df[df.method == m])
        for metric in ("NE", "OS", "SR", "SPL", "CR", "TTS"):
            assert agg.loc[(m, "box"), metric] == pytest.approx(ref[metric])
            assert agg.loc[(m, "box"), f"{metric}_lo"] <= ref[metric] <= agg.loc[(m, "box"), f"{metric}_hi"]
    assert agg.loc[("ours", "box"), "seeds"] == 2 and agg.loc[("ours", "box"), "episodes"] == 100


def test_compare_sr_detects_a_real_difference_and_not_a_null_one():
    df = pd.concat(
        [
            _episodes("ours", "tree", [0.8, 0.85, 0.75]),
            _episodes("ppo", "tree", [0.1, 0.2, 0.15]),
            _episodes("curl", "tree", [0.8, 0.85, 0.75]),
        ],
        ignore_index=True,
    )
    sig = compare_sr(df, "ours", reps=1000).set_index("method")
    assert sig.loc["ppo", "significant"] and sig.loc["ppo", "diff"] == pytest.approx(120 / 1.5 - 23 / 1.5)
    assert sig.loc["ppo", "lo"] > 0 and sig.loc["ppo", "p"] < 0.01
    assert not sig.loc["curl", "significant"] and sig.loc["curl", "diff"] == 0.0
    assert "ours > ppo" in sig.loc["ppo", "statement"] and "≈" in sig.loc["curl", "statement"]


def _written(tmp_path, scene: str, sr: dict[str, float]) -> tuple[dict[str, str], dict]:
    """Write Table I for one seed of the given methods' SR in ``scene``; markdown rows by label, and the paths."""
    df = pd.concat([_episodes(m, scene, [v]) for m, v in sr.items()], ignore_index=True)
    _, _, paths = write_table1(df, tmp_path, reps=200)
    md = paths["md"].read_text()
    return {line.split("|")[1].strip(): line for line in md.splitlines() if line.startswith("| ")}, paths


def test_write_table1_layout_bold_and_dashes(tmp_path):
    rows, paths = _written(tmp_path, "furniture", {"oracle": 1.0, "ours": 0.7, "ppo": 0.0})
    # The oracle is privileged: its 100% is not the bold best; ours is, and the best learned method too (italics).
    assert "**_70.0 ±" in rows["Ours"] and "**" not in rows["Oracle"].split("|")[3]
    assert rows["PPO"].rstrip(" |").endswith("–")  # no success -> no TTS
    long = pd.read_csv(paths["csv"])
    assert set(long.metric) == {"NE", "OS", "SR", "SPL", "CR", "TTS"} and (long.seeds == 1).all()
    tex = paths["tex"].read_text()
    assert "\\textbf{" in tex and "\\toprule" in tex and "$\\pm$" in tex
    vs = pd.read_csv(paths["vs_paper_csv"])
    ours_sr = vs[(vs.method == "ours") & (vs.scene == "furniture") & (vs.metric == "SR")].iloc[0]
    assert ours_sr.paper == 91.5 and ours_sr.kit == pytest.approx(70.0)


def test_best_learned_method_is_marked_beside_a_better_planner(tmp_path):
    rows, paths = _written(tmp_path, "tree", {"hybrid-apf-perceptive": 1.0, "ours": 0.5, "ppo": 0.8})
    sr = {m: row.split("|")[4].strip() for m, row in rows.items()}
    # The (non-privileged) perceptive planner is best: bold, not italic; PPO is the best learned method: italic.
    assert sr["Hybrid APF (perceptive)"].startswith("**100.0") and "_" not in sr["Hybrid APF (perceptive)"]
    assert sr["PPO"].startswith("_80.0") and sr["PPO"].endswith("_") and "**" not in sr["PPO"]
    assert "_" not in sr["Ours"] and "**" not in sr["Ours"]
    tex = paths["tex"].read_text()
    assert "\\underline{80.0" in tex and "\\textbf{100.0" in tex


def test_paper_table1_file_is_the_papers_values():
    p = paper_table1()
    assert len(p) == 15 and set(p.method) == {"ours", "npe", "curl", "ppo", "hybrid-apf"}
    row = p[(p.method == "hybrid-apf") & (p.scene == "barrier")].iloc[0]
    assert (row.NE, row.SR, row.CR, row.TTS) == (5.23, 28.5, 17.5, 789)
    assert math.isnan(p[(p.method == "ppo") & (p.scene == "tree")].TTS.iloc[0])


def test_perceptive_apf_sees_only_what_its_camera_shows():
    from omcrl.envs import make_env
    from omcrl.planners import PerceptiveHybridAPF

    cfg = load_config("smoke", overrides=["env.image_size=48", "env.max_steps=200"]).env
    wall = [{"kind": "box", "position": (2.0, 0.0), "size": (0.3, 3.0, 3.0)}]
    env = make_env("box", seed=0, config=cfg, layout=wall)
    try:
        obs, info = env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (4.0, 0.0)})
        pilot = PerceptiveHybridAPF(cfg).bind(env)
        assert not hasattr(pilot, "_env") or pilot._env is None  # never takes the true map
        pilot.reset(info)
        assert pilot.known[1:-1, 1:-1].sum() == 0  # nothing seen yet: straight line to the goal
        assert len(pilot.path) == 2
        pilot.act(obs, info)
        # The wall 2 m ahead is now on the map, where it really is, and the path goes around it.
        xs = pilot._grid.to_world(np.argwhere(pilot.known[1:-1, 1:-1]) + 1)
        assert len(xs) > 5 and np.all(np.abs(xs[:, 0] - 2.0) < 0.35)
        assert len(pilot.path) > 2 and np.abs(pilot.path[1:-1, 1]).max() > 1.4
        done, steps = False, 0
        while not done:
            obs, _, term, trunc, info = env.step(pilot.act(obs, info))
            done, steps = term or trunc, steps + 1
        assert info["metrics"]["success"], info["metrics"]
    finally:
        env.close()
