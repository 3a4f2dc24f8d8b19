"""A grid's data kept in the checkout (omcrl.pipeline.griddata): recorded as jobs finish, a restarted grid trains
only what has no data, and Table I, the ledger's verdicts and Fig. 5 rebuild from those files alone."""

from __future__ import annotations

import gzip

import pandas as pd
import pytest

from omcrl.__main__ import main
from omcrl.config import load_config
from omcrl.pipeline.griddata import GridData, grid_data_dir, tables_from_reference
from omcrl.pipeline.sweep import record_planners, run_sweep, sweep_stage


@pytest.mark.stage  # runs smoke sweeps end to end
def test_a_grid_is_recorded_resumed_from_its_records_and_rebuilt_without_training(tmp_path, monkeypatch):
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-a"))
    cfg = load_config("smoke")
    record = GridData(grid_data_dir(cfg, "smoke"))
    assert record.root == tmp_path / "machine-a" / "reference" / "smoke" / "smoke-v2"
    first = run_sweep(cfg, "smoke", [0], backend="local", progress=False, record=record)
    assert first.counts() == {"done": 6}
    assert record_planners(cfg, record, ("blind",)) == ["blind"] and record_planners(cfg, record, ("blind",)) == []
    labels = {p.parent.parent.name for p in record.root.glob("*/seed0/episodes.csv.gz")}
    assert labels == {"Ours_w_o_OT", "PPO", "blind"}
    # The runs' records, small and portable: no weights, metrics compressed, no machine path in the episodes.
    files = {p.relative_to(record.root).as_posix() for p in record.root.rglob("*") if p.is_file()}
    assert "PPO/seed0/rl/metrics.csv.gz" in files and "Ours_w_o_OT/seed0/pretrain/run.json" in files
    # What its encoder learned travels too (the budget ladder's encoder table reads it).
    assert "Ours_w_o_OT/seed0/pretrain/report.json" in files
    assert not [f for f in files if f.endswith(".pt")]
    text = gzip.decompress((record.root / "PPO" / "seed0" / "episodes.csv.gz").read_bytes()).decode()
    assert str(tmp_path) not in text
    # The measured wall times travel too (the plan's rates on a fresh checkout), with portable job ids.
    times = pd.read_csv(record.root / "jobs.csv")
    assert len(times) == 6 and (times["seconds"] > 0).all() and not times["id"].str.contains(str(tmp_path)).any()
    assert times["id"].str.contains("<results>/smoke/runs/").any()
    # How each recorded run was trained: its logged training time, its stretches, its machine, what it was made of.
    acc = record.account()
    rl, pre = acc[acc["stage"] == "rl"].set_index("label"), acc[acc["stage"] == "pretrain"]
    assert set(rl.index) == {"Ours_w_o_OT", "PPO"} and (rl["train_s"] > 0).all() and (rl["segments"] == 1).all()
    assert (
        len(pre) == 1 and rl.loc["Ours_w_o_OT", "encoder"] == pre["artifact"].iloc[0] and pre["dataset"].notna().all()
    )
    assert rl["encoder"].isna()["PPO"] and (rl["cpu"] != "").all()
    # A second machine with the checkout's records only: nothing to run, the same rows read back.
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-b"))
    (tmp_path / "machine-b" / "reference").mkdir(parents=True)
    (tmp_path / "machine-b" / "reference" / "smoke").symlink_to(record.root.parent)
    again = run_sweep(load_config("smoke"), "smoke", [0], backend="local", progress=False, record=record)
    assert again.counts() == {"recorded": 6}
    plan = sweep_stage(load_config("smoke"), "smoke", seeds=[0], plan=True, to_reference=True)
    assert ": 0 jobs" in plan and "6 more jobs are recorded in the checkout" in plan
    cols = ["label", "scene", "seed", "success", "final_distance"]
    pd.testing.assert_frame_equal(first.episodes[cols].reset_index(drop=True), again.episodes[cols])
    # One variant's episodes lost: only it (and its upstream jobs) runs again, trained afresh on this machine.
    record.remove("PPO", 0)
    third = run_sweep(load_config("smoke"), "smoke", [0], backend="local", progress=False, record=record)
    ran = {j.method for j in third.jobs if third.status[j.id] == "done"}
    assert ran == {"ppo"} and third.counts() == {"recorded": 4, "done": 2}
    assert record.has_episodes("PPO", 0)
    # A grid that flies the same runs in other layouts (Table I's confirmation on fresh layouts): nothing trains,
    # and its record keeps episodes alone (the runs' records and teachers are the first grid's).
    from omcrl.pipeline import grids, sweep

    fresh = ("eval.episodes=3", "eval.seed_offset=1000050")
    monkeypatch.setitem(grids.GRIDS, "smoke-fresh", tuple(grids.Variant(v.label, v.method, fresh)
                                                          for v in grids.GRIDS["smoke"]))  # fmt: skip
    monkeypatch.setattr(sweep, "EVAL_ONLY_GRIDS", ("smoke-fresh",))
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-a"))  # the machine that holds both runs
    confirm = GridData(grid_data_dir(cfg, "smoke-fresh"))
    fourth = run_sweep(load_config("smoke"), "smoke-fresh", [0], backend="local", progress=False, record=confirm)
    ran = {(j.kind, fourth.status[j.id]) for j in fourth.jobs}
    assert ran == {("collect", "skipped"), ("pretrain", "skipped"), ("train", "skipped"), ("evaluate", "done")}
    files = {p.relative_to(confirm.root).as_posix() for p in confirm.root.rglob("*") if p.is_file()}
    assert files == {"jobs.csv", "Ours_w_o_OT/seed0/episodes.csv.gz", "PPO/seed0/episodes.csv.gz"}
    seeds = confirm.episodes().groupby("scene")["eval_seed"].agg(["min", "max", "count"])
    flown = record.episodes()
    assert (seeds["min"] == 1000050).all() and (seeds["max"] == 1000052).all()
    assert seeds["min"].min() > flown["eval_seed"].max()  # layouts the first grid never flew


@pytest.mark.stage  # runs smoke sweeps end to end
def test_tables_rebuild_from_the_records_alone(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("smoke")
    record = GridData(grid_data_dir(cfg, "table1"))
    with pytest.raises(FileNotFoundError, match="no recorded episodes"):
        tables_from_reference(cfg)
    run_sweep(cfg, "smoke", [0, 1], backend="local", progress=False, record=GridData(tmp_path / "scratch"))
    # Lay the two methods out as Table I's grid would (label = method name).
    for label, method in (("Ours w/o OT", "ours-noOT"), ("PPO", "ppo")):
        for s in (0, 1):
            src = GridData(tmp_path / "scratch")
            record.save_episodes(method, s, pd.read_csv(src.folder(label, s) / "episodes.csv.gz"))
            (run,) = cfg.run_root.glob(f"runs/rl/{method}-*/seed{s}")
            record.save_run(method, s, "rl", run)
    out = tmp_path / "fresh"
    assert main(["tables", "--preset", "smoke", "--from-reference", "--set", f"results_dir={out}"]) == 0
    tables = out / "smoke" / "tables"
    t1 = pd.read_csv(tables / "table1.csv")
    ep = record.episodes()
    sr = t1[(t1.metric == "SR") & (t1.method == "ppo") & (t1.scene == "box-v2")].iloc[0]
    assert sr["mean"] == pytest.approx(100 * ep[(ep.method == "ppo") & (ep.scene == "box-v2")].success.mean())
    assert sr["seeds"] == 2
    v = pd.read_csv(tables / "ledger_verdicts.csv")
    assert len(v) == 106 and set(v.verdict) <= {"holds", "reversed", "undecided", "not run"}
    assert (out / "smoke" / "figures" / "fig5_training_curves.png").stat().st_size > 10_000
    assert "claim ledger:" in capsys.readouterr().out


@pytest.mark.stage  # runs smoke sweeps end to end
def test_a_teachers_weights_travel_so_a_new_machine_trains_its_students_without_it(tmp_path, monkeypatch):
    from omcrl.pipeline.grids import GRIDS, Variant
    from omcrl.runs import CorruptFile

    monkeypatch.setitem(GRIDS, "teach", (Variant("oracle", "oracle"), Variant("ours", "ours")))
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-a"))
    record = GridData(tmp_path / "record")
    first = run_sweep(load_config("smoke"), "teach", [0], backend="local", progress=False, record=record)
    assert set(first.status.values()) == {"done"}
    kept = record.folder("oracle", 0) / "rl" / "final.pt"
    (oracle_run,) = (tmp_path / "machine-a" / "results").glob("smoke/runs/rl/oracle-*/seed0")
    assert kept.read_bytes() == (oracle_run / "final.pt").read_bytes()
    assert not list(record.folder("ours", 0).rglob("*.pt"))  # a student's weights are not kept
    # A new machine, the student's data lost: the oracle is laid out from the record (a skip), the student trains.
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-b"))
    record.remove("ours", 0)
    again = run_sweep(load_config("smoke"), "teach", [0], backend="local", progress=False, record=record)
    by_kind = {(j.kind, j.method): again.status[j.id] for j in again.jobs}
    assert by_kind[("train", "oracle")] == "skipped" and by_kind[("train", "ours")] == "done"
    assert by_kind[("evaluate", "oracle")] == "recorded"
    (restored,) = (tmp_path / "machine-b" / "results").glob("smoke/runs/rl/oracle-*/seed0")
    assert restored.name == oracle_run.name and restored.parent.name == oracle_run.parent.name
    assert (restored / "final.pt").read_bytes() == kept.read_bytes() and (restored / "metrics.csv").is_file()
    # The same with only the student asked for (--variants ours): the teacher's own variant is left out, and its
    # kept weights are still laid out (they were not: the oracle trained again).
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-b2"))
    record.remove("ours", 0)
    only = run_sweep(
        load_config("smoke"), "teach", [0], backend="local", progress=False, record=record, variants=["ours"]
    )
    by_kind = {(j.kind, j.method): only.status[j.id] for j in only.jobs}
    assert by_kind[("train", "oracle")] == "skipped" and by_kind[("evaluate", "ours")] == "done"
    assert ("evaluate", "oracle") not in by_kind
    # Another grid whose variants need that oracle but do not record it (the budget ladder's students): its own
    # record keeps no teacher, and the oracle is laid out from the grid that keeps it, found by run key and seed.
    import shutil

    monkeypatch.setitem(GRIDS, "pupils", (Variant("ours", "ours"),))
    shutil.copytree(tmp_path / "machine-b2", tmp_path / "machine-b3")
    (copied,) = (tmp_path / "machine-b3" / "results").glob("smoke/runs/rl/oracle-*/seed0")
    shutil.rmtree(copied)
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-b3"))
    other = GridData(tmp_path / "pupils-record")
    pupils = run_sweep(load_config("smoke"), "pupils", [0], backend="local", progress=False, record=other)
    by_kind = {(j.kind, j.method): pupils.status[j.id] for j in pupils.jobs}
    assert by_kind[("train", "oracle")] == "skipped" and by_kind[("train", "ours")] == "skipped"
    assert (copied / "final.pt").read_bytes() == kept.read_bytes()
    assert not list(other.root.rglob("*.pt"))
    # Damaged kept weights are refused before any job runs, naming the file; nothing is written.
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-c"))
    record.remove("ours", 0)
    kept.write_bytes(kept.read_bytes()[:-10] + b"0123456789")
    with pytest.raises(CorruptFile, match="kept teacher weights .*final.pt"):
        run_sweep(load_config("smoke"), "teach", [0], backend="local", progress=False, record=record)
    assert not list((tmp_path / "machine-c").rglob("final.pt"))


@pytest.mark.stage  # runs smoke sweeps end to end
def test_a_teacher_no_variant_evaluates_is_kept_under_its_student_and_travels(tmp_path, monkeypatch):
    """The RL ladder's oracle x3 is no variant of any grid: its grid keeps it (``oracle for <student>``) as soon as
    it finishes, so a session that ends during the student loses no teacher; a new machine lays it out."""
    from omcrl.pipeline.grids import GRIDS, Variant

    monkeypatch.setitem(GRIDS, "solo", (Variant("ours x", "ours"),))
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-a"))
    record = GridData(tmp_path / "refs" / "solo")
    first = run_sweep(load_config("smoke"), "solo", [0], backend="local", progress=False, record=record)
    assert set(first.status.values()) == {"done"}
    kept = record.folder("oracle for ours x", 0) / "rl" / "final.pt"
    (oracle_run,) = (tmp_path / "machine-a" / "results").glob("smoke/runs/rl/oracle-*/seed0")
    assert kept.read_bytes() == (oracle_run / "final.pt").read_bytes()
    assert record.episodes()["label"].unique().tolist() == ["ours x"]  # the teacher flies nothing
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "machine-b"))
    record.remove("ours x", 0)
    again = run_sweep(load_config("smoke"), "solo", [0], backend="local", progress=False, record=record)
    by_kind = {(j.kind, j.method): again.status[j.id] for j in again.jobs}
    assert by_kind[("train", "oracle")] == "skipped" and by_kind[("train", "ours")] == "done"


def _git(repo, *args):
    import subprocess

    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True).stdout.strip()


def test_a_teachers_weights_leave_the_checkout_once_its_students_are_recorded_and_come_back_from_git(
    tmp_path, monkeypatch
):
    """Five seeds of oracles would not fit reference/'s 60 MB: a teacher's committed weights give way to a pointer
    to their git blob when nothing left to train needs them, and a later run reads them back from history."""
    import hashlib
    import json

    from omcrl.pipeline.griddata import WEIGHTS_POINTER
    from omcrl.pipeline.grids import GRIDS, Variant
    from omcrl.pipeline.sweep import release_teachers
    from omcrl.runs import ArtifactMismatch, Run

    monkeypatch.setitem(GRIDS, "teach", (Variant("oracle", "oracle"), Variant("ours", "ours")))
    repo = tmp_path / "repo"
    repo.mkdir()
    _git(repo, "init", "-q")
    _git(repo, "config", "user.email", "t@example.org")
    _git(repo, "config", "user.name", "t")
    record = GridData(repo / "reference" / "smoke" / "teach-v2")
    rl = record.folder("oracle", 0) / "rl"
    rl.mkdir(parents=True)
    weights = bytes(range(256)) * 4096  # 1 MiB standing in for an oracle's final.pt
    (rl / "final.pt").write_bytes(weights)
    (rl / "run.json").write_text(
        json.dumps({"key": "abc", "seed": 0, "artifact_digest": hashlib.sha1(weights).hexdigest()[:16]})
    )
    cfg = load_config("smoke")
    episodes = pd.DataFrame({"scene": ["box-v2"], "success": [True]})
    # Every evaluation recorded, but the weights are in no commit yet: kept (a pointer must name a kept blob).
    record.save_episodes("oracle", 0, episodes)
    record.save_episodes("ours", 0, episodes)
    assert release_teachers(cfg, "teach", None, record) == [] and (rl / "final.pt").is_file()
    record.remove("ours", 0)
    _git(repo, "add", "-A")
    _git(repo, "commit", "-qm", "oracle recorded")
    # Committed, but the student that needs it is not recorded yet: kept.
    assert release_teachers(cfg, "teach", None, record) == [] and (rl / "final.pt").is_file()
    record.save_episodes("ours", 0, episodes)
    (pointer,) = release_teachers(cfg, "teach", None, record)
    assert pointer == rl / WEIGHTS_POINTER and not (rl / "final.pt").exists()
    assert (
        json.loads(pointer.read_text())["git_blob"]
        == _git(repo, "ls-files", "-s", "--", str(rl / "final.pt")).split()[1]
    )
    _git(repo, "add", "-A")
    _git(repo, "commit", "-qm", "weights released")
    assert _git(repo, "ls-files", "--", str(rl / "final.pt")) == ""
    # A later grid needing the same teacher reads it back from history, bit for bit.
    assert record.has_weights("oracle", 0, "rl") and record.kept_weights("oracle", 0, "rl") == weights
    dest = tmp_path / "results" / "oracle-abc" / "seed0"
    assert record.restore_run("oracle", "rl", Run("rl", "oracle", 0, "abc", {}, dest))
    assert (dest / "final.pt").read_bytes() == weights and not (dest / WEIGHTS_POINTER).exists()
    # A copy without the history (a shallow clone, a tarball): not kept; the teacher would be trained again.
    bare = GridData(tmp_path / "no-git" / "teach-v2")
    import shutil

    shutil.copytree(record.root, bare.root)
    assert not bare.has_weights("oracle", 0, "rl")
    with pytest.warns(UserWarning, match="git blob .* is not in this repository"):
        assert bare.kept_weights("oracle", 0, "rl") is None
    # A pointer whose blob holds other bytes than the run recorded is refused, naming the pointer.
    other = tmp_path / "other.bin"
    other.write_bytes(b"not the oracle")
    blob = _git(repo, "hash-object", "-w", str(other))
    pointer.write_text(json.dumps({"git_blob": blob}))
    with pytest.raises(ArtifactMismatch, match="kept teacher weights .*final.pt.git.json"):
        record.kept_weights("oracle", 0, "rl")


def _policy(run_dir):
    import torch

    return torch.load(run_dir / "final.pt", weights_only=True)["model"]


@pytest.mark.stage  # trains the smoke oracle four times
def test_a_grid_that_reflies_table1_trains_a_run_in_its_stretches_and_refuses_another_policy(tmp_path, monkeypatch):
    """Issue 75's attribution re-flies Table I's policies from runs retrained here. Table I's run was stopped at a
    checkpoint and resumed (its envs restarted with a seed of their own): trained again in those stretches it is
    the same policy, bit for bit; trained in one stretch it is another, which `not_table1_run` names; a checkpoint
    from an interrupted attempt at another step is moved aside, not resumed."""
    import torch

    from omcrl.pipeline.plan import Job
    from omcrl.pipeline.recipes import train_method
    from omcrl.pipeline.sweep import _run_stage, not_table1_run
    from omcrl.runs import StopAfter

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "table1"))
    cfg = load_config("smoke")
    train_method(cfg, "oracle", progress=False, callbacks=(StopAfter(256),))  # Table I's run, stopped at 256
    first = train_method(cfg, "oracle", progress=False)
    table1 = GridData(grid_data_dir(cfg, "table1"))
    table1.save_run("oracle", 0, "rl", first.run.dir)
    job = Job(id="train/oracle/0", kind="train", method="oracle", seed=0, overrides=())
    base = {"preset": "smoke", "overrides": [], "as_table1": True}

    def machine(name: str):
        monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / name))
        (tmp_path / name).mkdir()
        (tmp_path / name / "reference").symlink_to(tmp_path / "table1" / "reference")
        return load_config("smoke")

    machine("again")
    _, _, (run_dir,), start = _run_stage(base, job)
    assert start == 0 and not_table1_run(base, job, table1) is None
    same = _policy(run_dir)
    assert all(torch.equal(same[k], v) for k, v in _policy(first.run.dir).items())

    cfg = machine("one-stretch")
    other = train_method(cfg, "oracle", progress=False)
    why = not_table1_run(base, job, table1)
    assert why is not None and "[(0, 0)]" in why and "[(0, 0), (256, 100)]" in why
    assert not all(torch.equal(_policy(other.run.dir)[k], v) for k, v in same.items())

    # Table I's seed 1 trained in one stretch; here an attempt was interrupted at its checkpoint at 256: the
    # checkpoint is moved aside and the run trained from the start, as Table I's was.
    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path / "table1"))
    whole = train_method(load_config("smoke").with_seed(1), "oracle", progress=False)
    table1.save_run("oracle", 1, "rl", whole.run.dir)
    cfg = machine("interrupted").with_seed(1)
    cut = train_method(cfg, "oracle", progress=False, callbacks=(StopAfter(256),))
    assert cut.run.checkpoint_path.exists()
    job1 = Job(id="train/oracle/1", kind="train", method="oracle", seed=1, overrides=())
    _, _, (run_dir,), start = _run_stage(base, job1)
    assert start == 0 and (run_dir / "checkpoint.pt.diverges").exists() and not_table1_run(base, job1, table1) is None
    assert all(torch.equal(_policy(run_dir)[k], v) for k, v in _policy(whole.run.dir).items())


def test_a_grid_that_reflies_table1_refuses_a_run_it_cannot_learn_here(tmp_path, monkeypatch):
    """Same seed, same result holds on one CPU only: a Table I run trained on another CPU model, or on inputs with
    another key (an encoder pretrained again elsewhere), cannot be learned again here. The training job is refused
    before its first step, naming both, and a run trained anyway is not recorded as Table I's."""
    import json

    from omcrl.pipeline.plan import Job
    from omcrl.pipeline.sweep import _cpu, _run_stage, _train_run, not_table1_inputs, not_table1_run
    from omcrl.utils.runtime import machine_info

    monkeypatch.setenv("OMCRL_ROOT", str(tmp_path))
    cfg = load_config("smoke")
    job = Job(id="train/oracle/0", kind="train", method="oracle", seed=0, overrides=())
    base = {"preset": "smoke", "overrides": [], "as_table1": True}
    table1 = GridData(grid_data_dir(cfg, "table1"))
    run = _train_run(base, job)
    folder = table1.folder("oracle", 0) / "rl"
    folder.mkdir(parents=True)

    def record(path, **fields):
        path.mkdir(parents=True, exist_ok=True)
        rec = {"stage": "rl", "method": "oracle", "seed": 0, "key": run.key, "machines": [machine_info()]}
        (path / "run.json").write_text(json.dumps({**rec, **fields}))

    record(folder)
    assert not_table1_inputs(base, job, table1) is None
    # the same model with kernels of another width (AVX2 where this torch picks AVX512, or the reverse) is another CPU
    other_isa = {**machine_info(), "cpu_capability": "another ISA"}
    record(folder, machines=[other_isa])
    assert "another ISA" in (not_table1_inputs(base, job, table1) or "")
    record(folder, machines=[{"cpu_model": "Another CPU"}])
    with pytest.raises(RuntimeError, match=f"Another CPU, the run here on {_cpu(machine_info())}"):
        _run_stage(base, job)
    assert not (run.dir / "final.pt").exists()  # refused before training
    record(folder, key="0123456789", identity={"encoder_digest": "abcdef"})
    why = not_table1_inputs(base, job, table1)
    assert why is not None and f"key {run.key} where Table I's has 0123456789" in why and "abcdef" in why
    record(folder, machines=[])  # a record older than the machines field: not judged on them
    assert not_table1_inputs(base, job, table1) is None
    # after the fact: a run here that says it trained on another CPU than Table I's is not recorded
    record(folder)
    record(run.dir, machines=[{"cpu_model": "Another CPU"}])
    why = not_table1_run(base, job, table1)
    assert why is not None and "episodes are not recorded" in why and "the run here on Another CPU" in why


def test_a_run_that_learned_otherwise_than_table1s_record_is_not_recorded(tmp_path):
    """A retrained run's training metrics must reproduce its record's bit for bit (timings aside): the check that
    tells a run trained on another machine where the record is older than its machines field (CURL seed 0 did)."""
    import gzip

    from omcrl.pipeline.sweep import _learning_differs

    rows = "step,metric,value\n2048,loss,0.0301849\n2048,steps_per_s,275.068\n4096,loss,0.0183403\n"
    record, here = tmp_path / "metrics.csv.gz", tmp_path / "metrics.csv"
    record.write_bytes(gzip.compress(rows.encode()))
    here.write_text(rows.replace("275.068", "299.017") + "4096,new_metric,1.0\n")  # another timing, a newer metric
    assert _learning_differs(record, here) is None
    here.write_text(rows.replace("0.0183403", "0.0182672"))
    assert _learning_differs(record, here) == "loss at step 4,096: 0.0183403 recorded, 0.0182672 here"
    here.write_text(rows.replace("4096,loss,0.0183403\n", ""))  # a recorded value the run never logged
    assert "loss at step 4,096" in (_learning_differs(record, here) or "")
    assert _learning_differs(tmp_path / "none.csv.gz", here) is None
