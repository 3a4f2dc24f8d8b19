"""Sweeps: grid expansion, the local backend (failures, re-runs), Ray embedded and by address (slow)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from omcrl.config import ConfigError, load_config
from omcrl.pipeline import grids, sweep
from omcrl.pipeline import plan as planning
from omcrl.pipeline.grids import GRIDS, Variant
from omcrl.pipeline.plan import expand
from omcrl.pipeline.sweep import run_sweep
from omcrl.pretrain.train import PretrainResult
from omcrl.utils.progress import Progress


def _cfg(root, *extra):
    # Data under the run's own folder: a sweep collects it like any other job.
    return load_config("smoke", overrides=[f"results_dir={root}", f"data.file={root}/data/box.h5", *extra])


def test_expansion_has_the_right_jobs_and_dependencies(tmp_path):
    cfg = _cfg(tmp_path)
    jobs = {j.id: j for j in expand(cfg, "smoke", [0, 1])}
    kinds = pd.Series([j.kind for j in jobs.values()]).value_counts().to_dict()
    # one dataset; an OMC encoder per seed; ours-noOT and ppo trained and evaluated per seed
    assert kinds == {"collect": 1, "pretrain": 2, "train": 4, "evaluate": 4}
    for j in jobs.values():
        assert all(d in jobs for d in j.deps)
        if j.kind == "train" and j.method == "ours-noOT":
            assert [jobs[d].kind for d in j.deps] == ["pretrain"]
        if j.kind == "train" and j.method == "ppo":
            assert j.deps == ()  # end to end: needs neither data nor an oracle
        if j.kind == "evaluate":
            assert [jobs[d].kind for d in j.deps] == ["train"]
    order = list(jobs)
    assert all(order.index(d) < order.index(j.id) for j in jobs.values() for d in j.deps)
    # Variants that share an artifact share its job: one oracle per seed for all five masking probabilities,
    # one encoder per probability and seed.
    mask = expand(cfg, "mask-prob", [0])
    assert sum(j.kind == "train" and j.method == "oracle" for j in mask) == 1
    assert sum(j.kind == "pretrain" for j in mask) == 6  # five OMC encoders and CURL's
    # The decay ablation varies the student's schedule only: one oracle per seed teaches all three students.
    decay = expand(cfg, "decay", [0, 1])
    oracles = [j for j in decay if j.kind == "train" and j.method == "oracle"]
    students = [j for j in decay if j.kind == "train" and j.method == "ours"]
    assert len(oracles) == 2 and len(students) == 6
    # ... the oracle of the budgets alone (the variants' rl.alpha_* are not the oracle's guidance).
    from omcrl.pipeline.plan import budget_overrides, job_config
    from omcrl.rl.train import oracle_run

    teacher = {s: f"train:{oracle_run(job_config(cfg, budget_overrides(cfg), s)).dir}" for s in (0, 1)}
    assert {j.seed: j.id for j in oracles} == teacher
    assert all(any(o in j.deps for o in (x.id for x in oracles)) for j in students)
    with pytest.raises(ConfigError, match="known grids"):
        expand(cfg, "dropout", [0])


def test_notebook_06_runs_the_six_ablation_grids_by_default(repo_root):
    assert list(grids.ABLATION_GRIDS) == ["mask-prob", "sequential", "dual-transformer", "projection",
                                          "oracle-teacher", "decay"]  # fmt: skip
    text = (repo_root / "notebooks" / "06_ablations.ipynb").read_text()
    assert "else list(ABLATION_GRIDS))" in text


def test_local_sweep_reports_a_failure_finishes_the_rest_and_reruns_only_what_is_missing(tmp_path, monkeypatch):
    # A variant whose data cannot be written (a folder under a file): its collect job fails, its pretrain, train
    # and evaluate jobs are blocked, and PPO still trains and evaluates.
    (tmp_path / "blocker").write_text("a file, not a folder")
    bad = Variant("broken data", "ours-noOT", (f"data.file={tmp_path}/blocker/box.h5",))
    monkeypatch.setitem(GRIDS, "test", (bad, Variant("PPO", "ppo")))
    cfg = _cfg(tmp_path / "a")
    res = run_sweep(cfg, "test", [0], backend="local", progress=False)
    (failed,) = res.failed
    assert failed.kind == "collect" and "blocker" in res.errors[failed.id]
    assert res.logs[failed.id].exists() and "Traceback" in res.logs[failed.id].read_text()
    assert res.counts() == {"failed": 1, "blocked": 3, "done": 2}
    # Each job's own progress is in its log (status lines, whatever the caller's progress flag), not only the sweep's.
    for job in (j for j in res.jobs if res.status[j.id] == "done"):
        status = [x for x in res.logs[job.id].read_text().splitlines() if x.startswith("[omcrl] ") and " elapsed" in x]
        assert status and status[-1].endswith("elapsed, done") and "(100%)" in status[-1], (job.id, status)
    assert "FAILED collect" in repr(res)
    assert set(res.episodes.label) == {"PPO"} and len(res.episodes) == len(cfg.eval.scenes) * cfg.eval.episodes
    # Run again: the finished training is found, not redone, and evaluation gives the same rows.
    final = next(cfg.run_root.glob("runs/rl/ppo-*/seed0/final.pt"))
    stamp = final.stat().st_mtime_ns
    again = run_sweep(cfg, "test", [0], backend="local", progress=False)
    assert final.stat().st_mtime_ns == stamp
    train = next(j for j in again.jobs if j.kind == "train" and j.method == "ppo")
    assert again.status[train.id] == "skipped"
    pd.testing.assert_frame_equal(res.episodes, again.episodes)
    # Job times: the re-run's cache hit keeps the time the training took when it really ran.
    times = pd.read_csv(cfg.run_root / "sweeps" / "test" / "jobs.csv").set_index("id")
    assert times.loc[train.id, "status"] == "done"
    assert times.loc[train.id, "seconds"] == pytest.approx(res.seconds[train.id], abs=0.01)
    assert times.loc[train.id, "work"] == cfg.rl.total_steps
    # ... and so does a cached evaluation (it used to overwrite the time with the 0.05 s of reading its cache).
    ev = next(j for j in again.jobs if j.kind == "evaluate" and j.method == "ppo")
    assert again.status[ev.id] == "skipped" and res.status[ev.id] == "done"
    assert times.loc[ev.id, "seconds"] == pytest.approx(res.seconds[ev.id], abs=0.01)
    rates = planning.measured_rates(cfg).set_index("rate_key")
    assert rates.loc["train:pixel", "rate"] == pytest.approx(cfg.rl.total_steps / times.loc[train.id, "seconds"])
    assert failed.id not in times.index  # a failed job measured nothing
    # Scripts see it: the stage writes what finished and exits non-zero (SweepFailed: one line in the CLI).
    with pytest.raises(sweep.SweepFailed, match=r"test: 1 failed, 3 blocked"):
        sweep.sweep_stage(cfg, "test", seeds=[0], backend="local", progress=False)
    assert (cfg.run_root / "tables" / "ablation_test.md").exists()


def test_a_training_no_sweep_timed_is_rated_from_its_own_clock(tmp_path, monkeypatch):
    """An oracle laid out from kept weights was never timed by a sweep (its jobs.csv row is a 0.06 s skip): its
    recorded run's rollout_s + update_s rate train:oracle, so --plan no longer leaves the oracles out. A kind that a
    jobs.csv measured keeps that rate; a run recorded under two labels counts once."""
    import gzip
    import json

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    grid = tmp_path / "reference" / "smoke" / "g-v2"

    def record(label: str, method: str, key: str, rows: str) -> None:
        d = grid / label / "seed0" / "rl"
        d.mkdir(parents=True)
        (d / "run.json").write_text(json.dumps({"stage": "rl", "method": method, "seed": 0, "key": key}))
        (d / "metrics.csv.gz").write_bytes(gzip.compress(("step,metric,value\n" + rows).encode()))

    clock = "100,rollout_s,3\n100,update_s,1\n100,loss,9\n200,rollout_s,3\n200,update_s,1\n"
    record("oracle", "oracle", "k1", clock)
    record("oracle-again", "oracle", "k1", clock)
    record("ours", "ours", "k2", clock)
    pd.DataFrame([{"id": "train:ours", "kind": "train", "method": "ours", "seed": 0, "status": "done", "seconds": 2.0,
                   "rate_key": "train:frozen", "work": 200}]).to_csv(grid / "jobs.csv", index=False)  # fmt: skip
    rates = planning.measured_rates(load_config("smoke")).set_index("rate_key")
    assert rates.loc["train:oracle", "rate"] == pytest.approx(200 / 8) and rates.loc["train:oracle", "jobs"] == 1
    assert rates.loc["train:frozen", "rate"] == pytest.approx(100) and rates.loc["train:frozen", "jobs"] == 1


def test_a_plans_rates_are_kept_once_and_plan_the_same_again(tmp_path, monkeypatch):
    """--rates-out writes the rates a plan used, in --rates' format: planning again from that file prints the same
    hours, and an existing file is never overwritten (a grid's plan is set against its measured cost later)."""
    import json

    from omcrl.config import ConfigError
    from omcrl.pipeline.sweep import sweep_stage

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("smoke")
    given = tmp_path / "given.json"
    given.write_text(json.dumps({"collect": 2.0, "pretrain": 3.0, "train:frozen": 50.0, "train:pixel": 40.0,
                                 "train:oracle": 45.0, "evaluate": 1.5}))  # fmt: skip
    out = tmp_path / "kept" / "plan_rates.json"
    first = sweep_stage(cfg, "smoke", seeds=[0, 1], plan=True, rates=str(given), rates_out=str(out))
    assert json.loads(out.read_text()) == json.loads(given.read_text()) and "rates written to" in first
    again = sweep_stage(cfg, "smoke", seeds=[0, 1], plan=True, rates=str(out))
    hours = [x for x in first.splitlines() if "machine-hours" in x]
    assert hours and hours == [x for x in again.splitlines() if "machine-hours" in x]
    before = out.read_bytes()
    with pytest.raises(ConfigError, match="the file exists"):
        sweep_stage(cfg, "smoke", seeds=[0], plan=True, rates=str(given), rates_out=str(out))
    assert out.read_bytes() == before


def test_plan_counts_shared_jobs_once_and_knows_the_main_comparison(tmp_path):
    paper = load_config("paper", overrides=[f"results_dir={tmp_path}"])
    plan = planning.sweep_plan(paper, ["projection", "oracle-teacher"], [0])
    assert plan["id"].is_unique
    ours = plan[(plan.kind == "train") & (plan.method == "ours")]
    assert len(ours) == 1 and ours.iloc[0].grids == "projection,oracle-teacher"
    # At the paper's budgets ours' encoder and training are the main comparison's runs; ours w/o phi is new.
    assert bool(ours.iloc[0].table1)
    assert not plan[(plan.kind == "train") & (plan.method == "ours-noPhi")].iloc[0].table1
    assert ours.iloc[0].work == paper.rl.total_steps and ours.iloc[0].rate_key == "train:frozen"
    # The quick preset's sweep budgets differ from Table I's: no training is shared.
    quick = load_config("quick", overrides=[f"results_dir={tmp_path}"])
    qplan = planning.sweep_plan(quick, ["projection"], [0])
    assert not qplan[qplan.kind == "train"].table1.any()
    assert set(qplan[qplan.kind == "train"].work) == {quick.sweep.rl_steps}


def test_cost_schedules_jobs_after_their_dependencies():
    rows = [
        ("c", "collect", 10, ()),  # 10 s
        ("p1", "pretrain", 100, ("c",)),  # 100 s each
        ("p2", "pretrain", 100, ("c",)),
        ("t1", "train:frozen", 50, ("p1",)),  # 50 s each
        ("t2", "train:frozen", 50, ("p2",)),
    ]
    plan = pd.DataFrame([{"id": i, "rate_key": k, "work": w, "deps": d} for i, k, w, d in rows])
    rates = {"collect": 1.0, "pretrain": 1.0, "train:frozen": 1.0}
    one, two = planning.sweep_cost(plan, rates, 1), planning.sweep_cost(plan, rates, 2)
    assert one["machine_hours"] == pytest.approx(310 / 3600) == two["machine_hours"]
    assert one["wall_hours"] == pytest.approx(310 / 3600)
    assert two["wall_hours"] == pytest.approx(160 / 3600)  # c, then p1 | p2, then t1 | t2
    assert two["by_key"]["pretrain"] == (2, pytest.approx(200 / 3600))
    with pytest.raises(ConfigError, match="no rate for"):
        planning.sweep_cost(plan, {"collect": 1.0}, 1)


def test_planner_variants_and_bad_backends_are_refused(tmp_path, monkeypatch):
    monkeypatch.setitem(GRIDS, "planner", (Variant("apf", "hybrid-apf"),))
    with pytest.raises(ConfigError, match="planner"):
        expand(_cfg(tmp_path), "planner", [0])
    with pytest.raises(ConfigError, match="backend"):
        run_sweep(_cfg(tmp_path), "smoke", [0], backend="dask")


def _episodes(res):
    return res.episodes.sort_values(["label", "scene", "episode"]).reset_index(drop=True).drop(columns="checkpoint")


@pytest.mark.slow
def test_embedded_ray_gives_the_local_results(tmp_path):
    local = run_sweep(_cfg(tmp_path / "local"), "smoke", [0], backend="local", progress=False)
    ray_res = run_sweep(_cfg(tmp_path / "ray"), "smoke", [0], backend="ray", num_cpus=2, progress=False)
    assert ray_res.counts() == local.counts() and not ray_res.failed
    pd.testing.assert_frame_equal(_episodes(local), _episodes(ray_res))


@pytest.mark.slow
def test_sweep_on_a_separate_ray_head_by_address(tmp_path):
    ray_bin = shutil.which("ray", path=os.path.dirname(sys.executable))
    port = "6391"
    env = {**os.environ, "RAY_AUTH_MODE": "disabled"}
    subprocess.run([ray_bin, "start", "--head", "--port", port, "--num-cpus", "2", "--include-dashboard=false"],
                   check=True, capture_output=True, env=env)  # fmt: skip
    try:
        os.environ["RAY_AUTH_MODE"] = "disabled"
        res = run_sweep(_cfg(tmp_path), "smoke", [0], backend="ray", address=f"127.0.0.1:{port}", progress=False)
        c = _cfg(tmp_path)
        assert not res.failed and len(res.episodes) == 2 * len(c.eval.scenes) * c.eval.episodes
    finally:
        os.environ.pop("RAY_AUTH_MODE", None)
        subprocess.run([ray_bin, "stop", "--force"], capture_output=True, env=env)


@pytest.mark.slow
def test_killed_driver_resumes_without_redoing_finished_jobs(tmp_path, repo_root):
    root = tmp_path / "killed"
    cfg = _cfg(root)
    cmd = [sys.executable, "-m", "omcrl", "sweep", "smoke", "--preset", "smoke", "--backend", "local", "--seeds", "0",
           "--set", f"results_dir={root}", "--set", f"data.file={root}/data/box.h5"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=repo_root, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 600
    while not list(cfg.run_root.glob("runs/pretrain/*/seed0/encoder.pt")) and time.time() < deadline:
        time.sleep(0.2)
    proc.kill()  # kill -9 of the driver, after pretraining finished
    proc.wait()
    enc = next(cfg.run_root.glob("runs/pretrain/*/seed0/encoder.pt"))
    stamp = enc.stat().st_mtime_ns
    res = run_sweep(cfg, "smoke", [0], backend="local", progress=False)
    assert enc.stat().st_mtime_ns == stamp and not res.failed
    pre = next(j for j in res.jobs if j.kind == "pretrain")
    assert res.status[pre.id] == "skipped"
    clean = run_sweep(_cfg(tmp_path / "clean"), "smoke", [0], backend="local", progress=False)
    pd.testing.assert_frame_equal(_episodes(res), _episodes(clean))


def test_jobs_ask_for_a_gpu_only_when_their_stage_runs_on_cuda():
    mk = lambda kind: planning.Job("x", kind, "ours", 0, ())  # noqa: E731
    cpu = load_config("smoke")
    cuda = cpu.__class__(**{**cpu.__dict__})
    cuda.rl = cpu.rl.__class__(**{**cpu.rl.__dict__, "device": "cuda"})
    cuda.pretrain = cpu.pretrain.__class__(**{**cpu.pretrain.__dict__, "device": "cuda"})
    assert [planning.job_gpus(cpu, mk(k)) for k in ("train", "pretrain", "evaluate", "collect")] == [0, 0, 0, 0]
    assert [planning.job_gpus(cuda, mk(k)) for k in ("train", "pretrain", "evaluate", "collect")] == [1, 1, 0, 0]


def test_job_cpus_follow_what_a_job_keeps_busy():
    cfg = load_config("smoke", overrides=["rl.n_envs=3", "pretrain.num_threads=2", "eval.workers=1"])
    mk = lambda kind: planning.Job("x", kind, "ours", 0, ())  # noqa: E731
    assert [planning.job_cpus(cfg, mk(k)) for k in ("train", "pretrain", "evaluate")] == [3, 2, 1]


def _synthetic_episodes(labels, scenes=("box", "tree"), n=6, seeds=(0, 1)):
    rows = []
    for k, lab in enumerate(labels):
        for sc in scenes:
            for s in seeds:
                for i in range(n):
                    ok = (i + k) % 3 != 0
                    rows.append({"method": "ours", "label": lab, "scene": sc, "train_seed": s, "episode": i,
                                 "success": ok, "collision": not ok, "final_distance": 0.2 if ok else 3.0,
                                 "min_distance": 0.2 if ok else 2.0, "path_length": 6.0, "optimal_path_length": 5.0,
                                 "steps": 60})  # fmt: skip
    return pd.DataFrame(rows)


def test_ablation_tables_and_figures(tmp_path):
    from omcrl.eval.ablation import ablation_table, write_ablation
    from omcrl.viz.ablation import FIGURES, plot_ablation

    ep = _synthetic_episodes(["linear", "exp", "fixed"])
    paths = write_ablation(ep, tmp_path, "decay", reps=200)
    assert {"ablation_decay.md", "table3.md", "table3.tex", "table3.csv"} <= set(paths)
    long = pd.read_csv(paths["table3.csv"])
    sr = long[(long.metric == "SR") & (long.scene == "box")].set_index("method")["mean"]
    # success when (episode + variant index) % 3 != 0: 4 of 6 episodes for every variant
    assert sr.round(1).to_dict() == {"linear": 66.7, "exp": 66.7, "fixed": 66.7}
    assert "**" in paths["table3.md"].read_text() and "\\toprule" in paths["table3.tex"].read_text()
    table = ablation_table(_synthetic_episodes(["rho=0.1", "rho=0.5", "CURL"]), reps=100)
    for grid in (*FIGURES, "decay"):
        name, fig = plot_ablation(grid, table)
        assert fig.axes and name
        fig.canvas.draw()  # a legend, where there is one, clear of every panel (issue 78: legends clear of the data)
        for legend in [a.get_legend() for a in fig.axes if a.get_legend() is not None]:
            box = legend.get_window_extent()
            assert not any(box.overlaps(a.get_window_extent()) for a in fig.axes if a.name != "polar"), (grid, name)


def test_normalised_metrics_are_fractions_of_the_best_variant():
    from omcrl.viz.ablation import normalised

    idx = pd.MultiIndex.from_product([["a", "b"], ["box"]], names=["method", "scene"])
    table = pd.DataFrame({"SR": [40.0, 80.0], "SPL": [0.0, 0.0], "NE": [2.0, 1.0], "CR": [30.0, 0.0]}, index=idx)
    n = normalised(table)["box"]
    assert n.loc["a"].to_dict() == {"SR": 0.5, "SPL": 1.0, "NE": 0.5, "CR": 0.0}
    assert n.loc["b"].to_dict() == {"SR": 1.0, "SPL": 1.0, "NE": 1.0, "CR": 1.0}


def test_ablation_findings_give_verdicts_in_the_unseen_scenes():
    from omcrl.eval.ablation import ablation_findings, findings_summary

    ep = _synthetic_episodes(["linear", "exp", "fixed"], scenes=("box", "tree"), n=30)
    # exp always fails in tree: linear > exp holds there; linear and fixed are the same (undecided).
    ep.loc[(ep.label == "exp") & (ep.scene == "tree"), "success"] = False
    # fixed always succeeds in tree: linear > fixed is reversed there.
    ep.loc[(ep.label == "fixed") & (ep.scene == "tree"), "success"] = True
    f = ablation_findings({"decay": ep, "sequential": ep.iloc[:0]}, reps=300)
    assert set(f.scene) == {"tree"}  # box, the training scene, is not an evaluation scene
    v = f.set_index("claim")["verdict"].to_dict()
    assert v == {"linear > exp": "holds", "linear > fixed": "reversed"}
    s = findings_summary(f).iloc[0]
    assert (s.holds, s.reversed, s.verdict) == (1, 1, "partly")
    same = ablation_findings({"decay": _synthetic_episodes(["linear", "exp", "fixed"], n=30)}, reps=300)
    assert findings_summary(same).iloc[0].verdict == "undecided"


def test_stress_scenes_are_counted_apart_from_the_paper_suite():
    from omcrl.eval.ablation import ablation_findings, findings_summary

    ep = _synthetic_episodes(["linear", "exp"], scenes=("box", "tree-v0", "furniture-v0"), n=30)
    # In the stress room exp always fails (linear > exp holds there); in tree the two are equal.
    ep.loc[(ep.label == "exp") & (ep.scene == "furniture-v0"), "success"] = False
    f = ablation_findings({"decay": ep}, reps=300)
    assert set(f.scene) == {"tree-v0", "furniture-v0"}
    s = findings_summary(f).iloc[0]
    assert (s.checks, s.holds, s.verdict) == (1, 0, "undecided")  # the stress test does not decide the verdict
    assert (s.stress, s["stress verdict"]) == ("1 / 0 / 0", "holds")
    assert (s["stress holds"], s["stress reversed"], s["stress undecided"]) == (1, 0, 0)
    only = findings_summary(f[f.scene == "furniture-v0"]).iloc[0]
    assert (only.checks, only.verdict) == (0, "not checked")


def test_findings_are_written(tmp_path):
    from omcrl.eval.ablation import write_findings

    ep = _synthetic_episodes(["linear", "exp", "fixed"], n=30)
    f, s, paths = write_findings({"decay": ep}, tmp_path, reps=200)
    assert pd.read_csv(paths["csv"]).shape == f.shape
    md = paths["md"].read_text()
    assert "6 linear decay beats exponential and fixed" in md and "linear > exp" in md and "undecided" in md
    from omcrl.pipeline.summary import _section_ablations

    text = _section_ablations({}, tmp_path)
    assert "| 6 linear decay beats exponential and fixed | 2 |" in text
    write_findings({}, tmp_path / "none")
    assert "None of the paper's ablation grids has run" in _section_ablations({}, tmp_path / "none").splitlines()[0]


def test_scaled_overrides_multiply_the_value_before_them():
    from omcrl.pipeline.plan import _scaled, job_config

    cfg = load_config("smoke")
    n, it = cfg.data.episodes, cfg.pretrain.iterations
    assert _scaled(cfg, ["data.episodes*=3", "pretrain.iterations*=0.5", "seed=2"]) == [
        f"data.episodes={3 * n}",
        f"pretrain.iterations={round(it * 0.5)}",
        "seed=2",
    ]
    # Sequential: a scale applies to what the overrides before it set.
    assert job_config(cfg, ["data.episodes=10", "data.episodes*=2"], 0).data.episodes == 20
    for bad, msg in (
        ("data.epsiodes*=2", "does not exist"),
        ("data.episodes*=many", "expected a number"),
        ("data.look*=2", "numeric field"),
    ):
        with pytest.raises(ConfigError, match=msg):
            _scaled(cfg, [bad])


def test_remedy_grids_run_at_full_budget_beside_the_table1_student():
    from omcrl.pipeline.grids import ABLATION_GRIDS, REMEDY_GRIDS
    from omcrl.pretrain.train import pretrain_run
    from omcrl.rl.methods import encoder_config

    cfg = load_config("quick")  # its sweep budgets (50 k steps, 750 iterations) differ from its full ones
    assert not set(REMEDY_GRIDS) & set(ABLATION_GRIDS)  # `sweep all` stays the paper's six grids
    jobs = expand(cfg, "remedy-data", [0])
    pre = {j.label or j.overrides: j for j in jobs if j.kind == "pretrain"}
    ids = {j.id for j in jobs}
    # The default student is the Table I run: same encoder folder, no budget overrides anywhere.
    assert f"pretrain:{pretrain_run(encoder_config(cfg, 'ours')).dir}" in ids
    assert all(not any(o.startswith(("rl.total_steps", "pretrain.iterations")) for o in j.overrides) for j in jobs)
    (x3,) = [j for j in jobs if j.kind == "collect" and j.overrides]
    assert x3.id.endswith("box-x3-seed0.h5")
    assert len(pre) == 2 and sum(j.kind == "train" and j.method == "oracle" for j in jobs) == 1
    # The paper's d changes the oracle's width too: that remedy needs its own oracle.
    d = expand(cfg, "remedy-d", [0])
    assert sum(j.kind == "train" and j.method == "oracle" for j in d) == 2
    # Oracle-flown data: one file per seed, collected after that seed's (shared) oracle is trained.
    pol = expand(cfg, "remedy-policy", [0, 1])
    order = [j.id for j in pol]
    oracles = {j.seed: j.id for j in pol if j.kind == "train" and j.method == "oracle"}
    flown = [j for j in pol if j.kind == "collect" and j.overrides]
    assert len(oracles) == 2 and sorted(j.id.rsplit("/", 1)[1] for j in flown) == [
        "box-seed0-oracle.h5",
        "box-seed1-oracle.h5",
    ]
    for j in flown:
        assert j.deps == (oracles[j.seed],) and order.index(oracles[j.seed]) < order.index(j.id)
    # Both remedies together reuse remedy-policy's data files and pretrain an encoder of their own.
    both = expand(cfg, "remedy-budget6-policy", [0, 1])
    assert {j.id for j in both if j.kind == "collect"} == {j.id for j in pol if j.kind == "collect"}
    others = {j.id for g in ("remedy-policy", "remedy-budget6") for j in expand(cfg, g, [0, 1]) if j.overrides}
    mine = [j for j in both if j.kind == "pretrain" and j.overrides]
    assert len(mine) == 2 and not {j.id for j in mine} & others


def test_remedy_verdicts_compare_with_the_default_and_check_the_target(tmp_path):
    from omcrl.eval.ablation import remedy_verdicts, write_remedies

    ep = _synthetic_episodes(["default", "more data"], scenes=("box", "furniture", "tree"), n=30)
    ep.loc[(ep.label == "default") & (ep.scene == "furniture"), "success"] = False
    ep.loc[(ep.label == "more data") & (ep.scene == "tree"), "success"] = False
    checks, summary = remedy_verdicts(ep, reps=300)
    c = checks.set_index(["label", "scene"])
    assert c.loc[("more data", "furniture"), "change"] == "better" and c.loc[("more data", "furniture"), "diff"] > 60
    assert c.loc[("more data", "tree"), "change"] == "worse"
    assert c.loc[("more data", "box"), "change"] == "unresolved"
    s = summary.set_index("label")
    assert s.loc["default", "target"] == "not met" and s.loc["default", "in"] == "furniture"
    assert s.loc["more data", "target"] == "not met" and s.loc["more data", "lowest unseen SR"] == 0
    ok = _synthetic_episodes(["default", "more data"], scenes=("box", "tree"), n=30)
    met = remedy_verdicts(ok, reps=200)[1].set_index("label")
    assert met.loc["more data", "target"] == "met" and met.loc["more data", "seeds meeting it"] == "2/2"  # 67 % ≥ 50 %
    assert s.loc["default", "seeds meeting it"] == "0/2"
    # One seed fails tree: the pooled SR may still reach the target within its CI, but only 1 of 2 seeds meets it.
    ok.loc[(ok.label == "more data") & (ok.train_seed == 1) & (ok.scene == "tree"), "success"] = False
    assert remedy_verdicts(ok, reps=200)[1].set_index("label").loc["more data", "seeds meeting it"] == "1/2"
    _, _, paths = write_remedies(ep, tmp_path, "remedy-data", reps=200)
    md = paths["md"].read_text()
    assert "| more data |" in md and "not met" in md and "variant − default" in md
    with pytest.raises(KeyError, match="reference variant"):
        remedy_verdicts(ep[ep.label != "default"], reps=50)
    # The summary shows the remedies beside the transfer diagnosis.
    from omcrl.pipeline.summary import _section_transfer

    pd.DataFrame(
        [{"layout": "box", "look": "furniture", "own look": False, "seeds": 2, "SR": 3.0, "SR_lo": 0.0, "SR_hi": 8.0,
          "CR": 60.0, "NE": 4.0}]
    ).to_csv(tmp_path / "transfer_appearance.csv", index=False)  # fmt: skip
    text = _section_transfer({}, tmp_path)
    assert "| box | furniture | 2 | 3 [0, 8] |" in text and "Remedies, `remedy_remedy-data.md`" in text


def test_an_unreachable_cluster_fails_within_seconds_with_the_fix(tmp_path, repo_root):
    import socket

    with socket.socket() as s:  # a free port: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    r = subprocess.run(
        [sys.executable, "-m", "omcrl", "sweep", "smoke", "--preset", "smoke", "--address", f"127.0.0.1:{port}",
         "--set", f"results_dir={tmp_path}"], cwd=repo_root, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 1 and time.monotonic() - t0 < 30
    assert f"nothing answers at 127.0.0.1:{port}" in r.stderr and "ray start --head" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.slow
def test_two_nodes_that_see_different_results_folders_are_refused_before_any_job(tmp_path, repo_root):
    """Two Ray nodes on this machine whose jobs resolve different project roots (OMCRL_ROOT per node): the sweep
    refuses at once, naming the node, instead of failing jobs on files that are not there."""
    ray_bin = shutil.which("ray", path=os.path.dirname(sys.executable))
    port = "6393"
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    base = {**os.environ, "RAY_AUTH_MODE": "disabled"}
    start = [ray_bin, "start", "--num-cpus", "1"]
    head = [*start, "--head", "--port", port, "--include-dashboard=false"]
    subprocess.run(head, check=True, capture_output=True, env={**base, "OMCRL_ROOT": str(a)})
    try:
        subprocess.run([*start, "--address", f"127.0.0.1:{port}"], check=True, capture_output=True,
                       env={**base, "OMCRL_ROOT": str(b)})  # fmt: skip
        t0 = time.monotonic()
        r = subprocess.run(
            [sys.executable, "-m", "omcrl", "sweep", "smoke", "--preset", "smoke", "--address", f"127.0.0.1:{port}"],
            cwd=repo_root, capture_output=True, text=True, timeout=300, env={**base, "OMCRL_ROOT": str(a)},
        )  # fmt: skip
        assert r.returncode == 1, r.stderr[-2000:]
        assert "1 of 2 nodes do not see the driver's results folder" in r.stderr and f"looks in {b}" in r.stderr
        assert not list((a / "results").glob("smoke/runs/*")) and time.monotonic() - t0 < 120
    finally:
        subprocess.run([ray_bin, "stop", "--force"], capture_output=True, env=base)


@pytest.mark.slow
def test_a_job_no_node_can_run_is_one_line_not_a_hang(tmp_path):
    """On an embedded Ray without GPUs, a sweep whose training asks for CUDA stops at once naming the job."""
    cfg = _cfg(tmp_path, "rl.device=cuda")
    t0 = time.monotonic()
    with pytest.raises(sweep.ClusterError, match=r"job train .* asks for 1 GPU .* the cluster has 0 GPUs"):
        run_sweep(cfg, "smoke", [0], backend="ray", num_cpus=2, progress=False)
    assert time.monotonic() - t0 < 300


def _rows(root):
    """Episode rows of a smoke sweep as its evaluation caches under ``root`` hold them (one frame, sorted)."""
    files = sorted((root / "results" / "smoke" / "eval").glob("*/seed0/*/episodes.csv"))
    assert files, f"no evaluation rows under {root}"
    # By method and scene, not the cache key: a policy file records where its encoder was, so its digest (the key)
    # differs between roots while the weights and the episodes do not.
    df = pd.concat(
        [pd.read_csv(f).assign(file=f"{f.parents[2].name}/{f.parent.name.rsplit('-', 1)[0]}") for f in files]
    )
    return df.drop(columns=["checkpoint", "trajectory"], errors="ignore").reset_index(drop=True)


@pytest.mark.slow
def test_with_storage_a_second_root_finds_every_job_finished(tmp_path, monkeypatch):
    """Two project roots (two machines) and one storage folder: the second run pulls what the first pushed and
    skips every job, with the same rows."""
    store = tmp_path / "store"
    a, b = tmp_path / "a", tmp_path / "b"
    monkeypatch.setenv("OMCRL_ROOT", str(a))
    first = run_sweep(load_config("smoke", overrides=[f"sweep.storage={store}"]), "smoke", [0], backend="local",
                      progress=False)  # fmt: skip
    assert first.counts() == {"done": 6}
    monkeypatch.setenv("OMCRL_ROOT", str(b))
    second = run_sweep(load_config("smoke", overrides=[f"sweep.storage={store}"]), "smoke", [0], backend="local",
                       progress=False)  # fmt: skip
    assert second.counts() == {"skipped": 6}
    assert [j.id.replace(str(b), "") for j in second.jobs] == [j.id.replace(str(a), "") for j in first.jobs]
    pd.testing.assert_frame_equal(_episodes(first), _episodes(second))
    pd.testing.assert_frame_equal(_rows(a), _rows(b))
    assert len(list((b / "results" / "smoke" / "runs" / "rl").glob("*/seed0/final.pt"))) == 2


@pytest.mark.slow
def test_two_nodes_with_different_roots_sweep_through_storage(tmp_path, repo_root):
    """A head and a worker whose jobs see different project roots (OMCRL_ROOT per node), the driver a third, and
    storage in a fourth folder: the smoke grid completes and its rows and table equal the local backend's. Then the
    nodes' roots are wiped and a new driver runs it again: every job is found finished by pulling from storage."""
    ray_bin = shutil.which("ray", path=os.path.dirname(sys.executable))
    port = "6395"
    a, b, d, d2, c, store = (tmp_path / n for n in ("head", "worker", "driver", "driver2", "local", "store"))
    base = {**os.environ, "RAY_AUTH_MODE": "disabled"}
    base.pop("OMCRL_ROOT", None)
    cli = [sys.executable, "-m", "omcrl", "sweep", "smoke", "--preset", "smoke", "--seeds", "0"]
    local = subprocess.run([*cli, "--backend", "local"], cwd=repo_root, capture_output=True, text=True,
                           timeout=900, env={**base, "OMCRL_ROOT": str(c)})  # fmt: skip
    assert local.returncode == 0, local.stderr[-2000:]
    start = [ray_bin, "start", "--num-cpus", "1"]
    on_cluster = [*cli, "--address", f"127.0.0.1:{port}", "--set", f"sweep.storage={store}"]
    subprocess.run([*start, "--head", "--port", port, "--include-dashboard=false"], check=True, capture_output=True,
                   env={**base, "OMCRL_ROOT": str(a)})  # fmt: skip
    try:
        subprocess.run([*start, "--address", f"127.0.0.1:{port}"], check=True, capture_output=True,
                       env={**base, "OMCRL_ROOT": str(b)})  # fmt: skip
        first = subprocess.run(on_cluster, cwd=repo_root, capture_output=True, text=True, timeout=900,
                               env={**base, "OMCRL_ROOT": str(d)})  # fmt: skip
        assert first.returncode == 0, first.stderr[-3000:]
        shutil.rmtree(a, ignore_errors=True)
        shutil.rmtree(b, ignore_errors=True)
        second = subprocess.run(on_cluster, cwd=repo_root, capture_output=True, text=True, timeout=900,
                                env={**base, "OMCRL_ROOT": str(d2)})  # fmt: skip
        assert second.returncode == 0, second.stderr[-3000:]
    finally:
        subprocess.run([ray_bin, "stop", "--force"], capture_output=True, env=base)
    assert "6 jobs" in first.stdout and "{'skipped': 6}" in second.stdout, second.stdout[-2000:]
    table = Path("results/smoke/tables/ablation_smoke.csv")
    for driver in (d, d2):
        # The driver has the rows (its evaluation caches fetched from storage) and every job's log, wherever it ran.
        pd.testing.assert_frame_equal(_rows(c), _rows(driver))
        tables = [pd.read_csv(r / table).sort_values(["method", "scene", "metric"]).reset_index(drop=True)
                  for r in (c, driver)]  # fmt: skip
        pd.testing.assert_frame_equal(*tables)  # the same numbers (rows come in the order jobs finished)
        logs = sorted((driver / "results/smoke/sweeps/smoke/logs").glob("*.log"))
        assert len(logs) == 6 and all("[sweep] finished in" in f.read_text() for f in logs)
    pulls = [line for f in logs for line in f.read_text().splitlines() if "[sweep] from storage" in line]
    assert {p.split(" into ")[1].split(":")[0] for p in pulls} <= {str(a), str(b)}  # never the driver's root
    # Second run: each job's node had nothing, so every job fetched its files from storage.
    assert len(pulls) == 6 and all("'fetched': 0" not in p for p in pulls), pulls


def test_the_table1_grid_trains_the_learned_methods_of_table1_with_their_run_keys(tmp_path):
    from omcrl.rl.methods import TABLE1_METHODS, get_method

    assert [v.method for v in GRIDS["table1"]] == [m for m in TABLE1_METHODS if get_method(m).learned]
    assert "table1" not in grids.ABLATION_GRIDS and "table1" in grids.FULL_BUDGET_GRIDS
    cfg = _cfg(tmp_path)
    jobs = expand(cfg, "table1", [0])
    assert {j.method for j in jobs if j.kind == "train"} == {v.method for v in GRIDS["table1"]}
    assert not any("sweep" in o or "total_steps" in o for j in jobs for o in j.overrides)  # the preset's budgets


@pytest.mark.slow
def test_embedded_ray_starts_its_own_even_beside_a_running_cluster(tmp_path):
    """With a `ray start` cluster on the machine, a sweep without --address still starts a Ray of its own (plain
    ray.init() would join the running one and refuse num_cpus)."""
    ray_bin = shutil.which("ray", path=os.path.dirname(sys.executable))
    env = {**os.environ, "RAY_AUTH_MODE": "disabled"}
    subprocess.run([ray_bin, "start", "--head", "--port", "6401", "--num-cpus", "1", "--include-dashboard=false"],
                   check=True, capture_output=True, env=env)  # fmt: skip
    try:
        res = run_sweep(_cfg(tmp_path), "smoke", [0], backend="ray", num_cpus=2, progress=False)
        assert not res.failed and res.counts() == {"done": 6}
    finally:
        subprocess.run([ray_bin, "stop", "--force"], capture_output=True, env=env)


def test_sweep_episodes_list_variants_in_the_grid_order_not_the_finishing_order():
    from omcrl.pipeline.plan import Job
    from omcrl.pipeline.sweep import _in_grid_order

    jobs = [Job(f"evaluate:{lab}:t", "evaluate", "ours", 0, (), (), lab) for lab in ("rho=0.1", "rho=0.5", "CURL")]
    finished = _synthetic_episodes(["CURL", "rho=0.5", "rho=0.1"], seeds=(1, 0), n=2)
    out = _in_grid_order(finished, jobs)
    assert list(dict.fromkeys(out.label)) == ["rho=0.1", "rho=0.5", "CURL"]
    assert out[out.label == "CURL"].train_seed.tolist()[:4] == [0, 0, 0, 0]  # then by seed
    assert len(out) == len(finished) and _in_grid_order(finished.iloc[:0], jobs).empty


def test_a_sweep_of_some_variants_keeps_what_they_need_and_names_a_wrong_one():
    from omcrl.config import ConfigError, load_config
    from omcrl.pipeline.plan import expand
    from omcrl.pipeline.sweep import only_variants

    jobs = expand(load_config("smoke"), "table1", [0])
    some = only_variants(jobs, ["ours-lapf"], "table1")
    assert {(j.kind, j.method) for j in some} == {
        ("collect", "ours"),
        ("pretrain", "ours"),
        ("train", "ours-lapf"),
        ("evaluate", "ours-lapf"),
    }  # the OMC encoder it shares with ours, and no oracle: its guide is the local APF
    assert [j.id for j in jobs if j.id in {s.id for s in some}] == [s.id for s in some]  # the grid's order
    assert only_variants(jobs, None, "table1") == jobs
    with pytest.raises(ConfigError, match=r"variants \['ourz'\] are not in the grid; its variants are \['oracle'"):
        only_variants(jobs, ["ourz"], "table1")
    from omcrl.pipeline.sweep import sweep_stage

    plan = sweep_stage(load_config("smoke"), "table1", seeds=[0], plan=True, variants=["ours-lapf"])
    assert "grids ['table1']: 4 jobs" in plan and "train:oracle" not in plan


def test_the_budget_ladder_scales_pretraining_data_and_warmup_together_and_rl_with_its_decay():
    from omcrl.config import load_config
    from omcrl.pipeline.grids import FULL_BUDGET_GRIDS
    from omcrl.pipeline.plan import expand, job_config

    base = load_config("smoke")
    jobs = expand(base, "ladder-pretrain", [0])
    x16 = next(j for j in jobs if j.kind == "pretrain" and "curl" in j.id and any("x16" in o for o in j.overrides))
    cfg = job_config(base, x16.overrides, 0)
    assert cfg.pretrain.iterations == 16 * base.pretrain.iterations
    assert cfg.data.episodes == 16 * base.data.episodes and cfg.data_path.name == "box-x16-seed0.h5"
    assert cfg.pretrain.warmup_steps == 16 * base.pretrain.warmup_steps
    # Every ladder student trains at the preset's RL budget, and its oracle is Table I's (one oracle per seed).
    assert {j.id for j in jobs if j.method == "oracle"} == {j.id for j in expand(base, "table1", [0]) if
                                                           j.method == "oracle" and j.kind == "train"}  # fmt: skip
    rl = [j for j in expand(base, "ladder-rl", [0]) if j.kind == "train"]
    ours = next(j for j in rl if j.method == "ours")
    cfg = job_config(base, ours.overrides, 0)
    assert cfg.rl.total_steps == 3 * base.rl.total_steps and cfg.rl.alpha_decay_steps == 3 * base.rl.alpha_decay_steps
    assert {"ladder-pretrain", "ladder-rl"} <= set(FULL_BUDGET_GRIDS)


def test_a_resumed_training_is_timed_against_the_steps_it_trained(tmp_path):
    """jobs.csv sets a job's seconds against its work; a training resumed from a checkpoint at step s timed only the
    steps after s (before: the whole budget, which overstated the rate: npe-ot's 6,153 s row of the v2 grid)."""
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    jobs = expand(cfg, "smoke", [0])
    fresh, resumed = [j for j in jobs if j.kind == "train" and j.method != "oracle"][:2]
    res = sweep.SweepResult("smoke", jobs, {fresh.id: "done", resumed.id: "done"})
    res.seconds = {fresh.id: 10.0, resumed.id: 4.0}
    res.started = {resumed.id: 384}
    path = tmp_path / "jobs.csv"
    sweep._record_job_times(cfg, res, path)
    rows = pd.read_csv(path).set_index("id")
    assert rows.loc[fresh.id, "work"] == cfg.rl.total_steps and rows.loc[resumed.id, "work"] == cfg.rl.total_steps - 384
    assert rows.loc[fresh.id, "start"] == 0 and rows.loc[resumed.id, "start"] == 384  # where each began, kept


def test_a_resumed_pretraining_is_timed_against_the_iterations_it_ran(tmp_path, monkeypatch):
    """A pretraining resumed from its checkpoint reports where it began, and jobs.csv sets its seconds against the
    iterations after it (before: the whole budget, so ladder ×16 seed 1's 8,250 iterations were 24,000 in jobs.csv)."""
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    job = next(j for j in expand(cfg, "smoke", [0]) if j.kind == "pretrain")
    made = PretrainResult("omc", tmp_path, tmp_path / "encoder.pt", tmp_path / "m.csv", 20, 1.0, "fp", start=7)
    monkeypatch.setattr(sweep, "pretrain_method", lambda *a, **k: made)
    status, _, _, start = sweep._run_stage({"preset": "smoke", "overrides": [f"results_dir={tmp_path}"]}, job)
    assert (status, start) == ("done", 7)
    res = sweep.SweepResult("smoke", [job], {job.id: "done"})
    res.seconds, res.started = {job.id: 4.0}, {job.id: start}
    sweep._record_job_times(cfg, res, tmp_path / "jobs.csv")
    assert pd.read_csv(tmp_path / "jobs.csv").set_index("id").loc[job.id, "work"] == cfg.pretrain.iterations - 7


def test_a_job_a_stopped_session_finished_keeps_its_time_in_the_grid_record(tmp_path):
    """A session stopped mid-variant: its pretraining finished and was timed in the sweep's own jobs.csv, but the grid
    record's copy was reset with the worktree, and the next session finds the run finished. The record takes the
    measured row, not a zero-second skip (which the ablations' account drops: 108 s of projection's CURL seed 2)."""
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    job = next(j for j in expand(cfg, "smoke", [0]) if j.kind == "pretrain")
    first = sweep.SweepResult("smoke", [job], {job.id: "done"})
    first.seconds = {job.id: 107.7}
    local = tmp_path / "sweeps" / "jobs.csv"
    local.parent.mkdir(parents=True)
    sweep._record_job_times(cfg, first, local)
    again = sweep.SweepResult("smoke", [job], {job.id: "skipped"})
    again.seconds = {job.id: 0.1}
    sweep._record_job_times(cfg, again, local)  # the machine's own file keeps the time it took
    record = tmp_path / "record" / "jobs.csv"
    record.parent.mkdir()
    sweep._record_job_times(cfg, again, record, True, local)
    row = pd.read_csv(record).iloc[0]
    assert (row["status"], row["seconds"], row["work"]) == ("done", 107.7, cfg.pretrain.iterations)
    assert row["id"].startswith("pretrain:<results>")  # still the portable id
    bare = tmp_path / "bare" / "jobs.csv"
    bare.parent.mkdir()
    sweep._record_job_times(cfg, again, bare, True)  # without the machine's file: a skip, as before
    assert pd.read_csv(bare).iloc[0]["status"] == "skipped"


def test_the_plan_prices_a_machine_to_itself_at_the_upper_quartile_of_measured_rates(tmp_path, monkeypatch):
    """Jobs that shared the machine ran slower than jobs alone: the median rate prices the first, the upper quartile
    the second, and the plan says both (a range, not one figure)."""
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    grid = tmp_path / "reference" / "smoke" / "g-v2"
    grid.mkdir(parents=True)
    seconds = [10.0, 10.0, 20.0, 20.0, 20.0]
    rows = [{"id": f"train:{k}", "kind": "train", "method": "ours", "seed": 0, "status": "done", "seconds": s,
             "rate_key": "train:frozen", "work": 1000} for k, s in enumerate(seconds)]  # fmt: skip
    pd.DataFrame(rows).to_csv(grid / "jobs.csv", index=False)
    cfg = load_config("smoke")
    rates = planning.measured_rates(cfg).set_index("rate_key").loc["train:frozen"]
    assert rates["rate"] == pytest.approx(50) and rates["rate_fast"] == pytest.approx(100)
    median = {"collect": 1.0, "pretrain": 1.0, "train:frozen": 50.0, "train:oracle": 50.0, "train:pixel": 50.0,
              "evaluate": 1.0}  # fmt: skip
    fast = {k: 2 * v for k, v in median.items()}
    text = planning.describe_plan(cfg, ["smoke"], [0], median, fast_rates=fast)
    hours = [float(line.split(": ")[1].split(" machine-hours")[0]) for line in text.splitlines()
             if "on 1 machine(s)" in line or "upper quartile" in line]  # fmt: skip
    assert len(hours) == 2 and hours[1] == pytest.approx(hours[0] / 2, rel=0.02)
    assert "upper quartile" not in planning.describe_plan(cfg, ["smoke"], [0], median)


def test_table1s_confirmation_grid_reuses_its_training_and_flies_layouts_it_never_flew():
    from omcrl.config import load_config
    from omcrl.pipeline.plan import expand, job_config

    base = load_config("quick")
    table1, confirm = expand(base, "table1", [2]), expand(base, "table1-confirm", [2])
    # The controls (issue 75) were declared after the confirmation flew: it re-flies every other Table I run.
    table1 = [j for j in table1 if j.method not in ("ours-random", "ours-blind")]
    upstream = [j.id for j in table1 if j.kind != "evaluate"]
    assert [j.id for j in confirm if j.kind != "evaluate"] == upstream  # the same runs: nothing new to train
    assert [j.label for j in confirm if j.kind == "evaluate"] == [j.label for j in table1 if j.kind == "evaluate"]
    ev = next(j for j in confirm if j.kind == "evaluate")
    cfg, first = job_config(base, ev.overrides, 2), base.eval
    assert cfg.eval.episodes == 200 and cfg.eval.seed_offset >= first.seed_offset + first.episodes
    assert "table1-confirm" in grids.FULL_BUDGET_GRIDS and "table1-confirm" in grids.EVAL_ONLY_GRIDS


def test_the_retrain_grid_trains_table1s_jobs_once_and_flies_them_in_both_looks():
    """Issue 75's retrain grid: Table I's training jobs (the same ids: a run finished on this machine is found, not
    trained again), each flown in Table I's evaluation and in box-v2's look; a grid that keeps its runs' records
    (not one of the eval-only grids that re-fly Table I's own policies), at the preset's budgets, no oracle variant."""
    from omcrl.config import load_config
    from omcrl.pipeline.plan import expand, job_config

    base = load_config("quick")
    table1 = [j for j in expand(base, "table1", [0]) if j.method in ("curl", "ours-noOT")]
    retrain = [j for j in expand(base, "table1-retrain", [0]) if j.method in ("curl", "ours-noOT")]
    assert [j.id for j in retrain if j.kind != "evaluate"] == [j.id for j in table1 if j.kind != "evaluate"]
    flights = {j.label: job_config(base, j.overrides, 0).eval for j in retrain if j.kind == "evaluate"}
    assert list(flights) == ["ours-noOT", "ours-noOT box-look", "curl", "curl box-look"]
    assert flights["curl"] == base.eval  # Table I's evaluation, box-v2 included
    assert flights["curl box-look"].look == "box-v2" and "box-v2" not in flights["curl box-look"].scenes
    assert "table1-retrain" in grids.FULL_BUDGET_GRIDS and "table1-retrain" not in grids.EVAL_ONLY_GRIDS
    assert "table1-retrain" not in grids.ABLATION_GRIDS
    assert not any(v.method == "oracle" for v in grids.GRIDS["table1-retrain"])


def test_what_a_grid_still_costs_is_its_jobs_at_the_measured_rates_and_says_when_a_kind_has_none(tmp_path, monkeypatch):
    """rest_hours prices the jobs no record holds at the median and upper quartile of the rates the checkout's
    jobs.csv measured: by hand, each job's work / rate; a kind with no measured rate gives no hours (NaN), not a
    figure that leaves it out."""
    import math

    from omcrl.pipeline.sweep import rest_hours

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("smoke")
    plan = planning.sweep_plan(cfg, ["projection"], [0])
    plan = plan[~plan["table1"]]
    kinds = sorted(set(plan["rate_key"]))
    grid = tmp_path / "reference" / "smoke" / "g-v2"
    grid.mkdir(parents=True)
    # Per kind, jobs at 1 and 3 units/s: the median 2, the upper quartile 2.5.
    rows = [{"id": f"{k}:{r}", "kind": "x", "method": "m", "seed": 0, "status": "done", "seconds": 100.0 / r,
             "rate_key": k, "work": 100} for k in kinds[:-1] for r in (1.0, 3.0)]  # fmt: skip
    pd.DataFrame(rows).to_csv(grid / "jobs.csv", index=False)
    partial = rest_hours(cfg, ["projection"], [0])
    assert partial["jobs"] == len(plan) and math.isnan(partial["hours"]) and math.isnan(partial["hours_fast"])
    rows += [{**rows[0], "id": f"{kinds[-1]}:{r}", "seconds": 100.0 / r, "rate_key": kinds[-1]} for r in (1.0, 3.0)]
    pd.DataFrame(rows).to_csv(grid / "jobs.csv", index=False)
    got = rest_hours(cfg, ["projection"], [0])
    assert got["hours"] == pytest.approx(plan["work"].sum() / 2.0 / 3600)
    assert got["hours_fast"] == pytest.approx(plan["work"].sum() / 2.5 / 3600)


def test_a_sweeps_time_left_is_priced_per_kind_of_job_not_counted_in_jobs():
    """Five jobs, the first a 1-minute collection, then an hour's pretraining: counting jobs says 4 minutes left after
    the first; the planned seconds (work / measured rate) say about an hour and a half, and once a tenth of the
    planned work has run, at the pace it ran."""
    _time_left = sweep._time_left
    planned = {"collect": 60.0, "pretrain": 3600.0, "train": 1200.0, "eval": 60.0, "eval2": 60.0}
    ids = list(planned)
    assert _time_left(planned, ids, {}, 5.0) == pytest.approx(sum(planned.values()))  # the measured rates as they are
    # The collection took 1.5× its plan, but it is 1 % of the work: its pace is not taken.
    assert _time_left(planned, ids, {"collect": "done"}, 90.0) == pytest.approx(3600 + 1200 + 60 + 60)
    # The pretraining ran at half its plan's time: the rest is priced at that pace; a cached job adds none.
    status = {"collect": "skipped", "pretrain": "done"}
    assert _time_left(planned, ids, status, 1800.0) == pytest.approx(0.5 * (1200 + 60 + 60))
    # The pretraining resumed from its checkpoint at two thirds: its 1,800 s ran a third of its plan (1,200 s), so
    # the pace is 1.5, not 0.5 (ladder ×16 seed 1's bar said ~8 min left for a 26-minute training).
    assert _time_left(planned, ids, status, 1800.0, {"pretrain": 1 / 3}) == pytest.approx(1.5 * (1200 + 60 + 60))
    # A job with no measured rate gives no estimate (the bar counts jobs).
    assert _time_left({k: v for k, v in planned.items() if k != "train"}, ids, status, 1800.0) is None


def test_progress_takes_the_callers_time_left_and_falls_back_to_counting(capsys, monkeypatch):
    monkeypatch.delenv("OMCRL_STATUS_FILE", raising=False)
    answers = iter([None, None, 3600.0])
    bar = Progress(5, "sweep/x", unit="job", log_interval=0.0, time_left=lambda elapsed: next(answers))
    bar.update(1)
    bar.update(1)
    lines = [x for x in capsys.readouterr().err.splitlines() if x.startswith("[omcrl]")]
    assert "left" not in lines[0] and "left" in lines[1] and lines[-1].endswith("~1h00m00s left")


def test_a_job_two_grids_share_is_left_to_run_while_either_grid_still_needs_it(tmp_path, monkeypatch):
    """decay's linear and dual-transformer's Ours are one training run: recorded under decay alone, it is done for
    decay's plan, but a plan of both grids still counts it (a fresh machine trains it again for Ours)."""
    from omcrl.pipeline.griddata import GridData, grid_data_dir
    from omcrl.pipeline.sweep import recorded_jobs

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("smoke")
    ours = next(j for j in planning.expand(cfg, "dual-transformer", [0]) if j.kind == "evaluate" and j.label == "Ours")
    linear = next(j for j in planning.expand(cfg, "decay", [0]) if j.kind == "evaluate" and j.label == "linear")
    assert ours.deps[0] == linear.deps[0]  # the one shared training run
    GridData(grid_data_dir(cfg, "decay")).save_episodes("linear", 0, _synthetic_episodes(["linear"]))
    assert linear.deps[0] in recorded_jobs(cfg, ["decay"], [0])
    assert linear.deps[0] not in recorded_jobs(cfg, ["decay", "dual-transformer"], [0])
