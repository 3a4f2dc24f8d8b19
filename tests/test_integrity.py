"""Integrity of results (issue: nothing overwrites a table, nothing corrupt is trusted, nothing is left running)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import psutil
import pytest

# A parent that opens an evaluation pool, starts slow episodes in its workers, prints their PIDs and waits.
_PARENT = textwrap.dedent(
    """
    import os, sys, time
    from omcrl.eval.runner import EvalPool

    class Slow:
        def act(self, obs, info):
            time.sleep(0.05)
            return [0.0, 0.0, 0.0]

    import threading
    import psutil
    from omcrl.eval.runner import evaluate
    pool = EvalPool(2).__enter__()
    t = threading.Thread(target=evaluate, args=(Slow(), "box", 8), kwargs={"workers": pool, "image_size": 16},
                         daemon=True)
    t.start()
    me = psutil.Process()
    while len(me.children()) < 2:
        time.sleep(0.1)
    time.sleep(1.0)
    print(" ".join(str(c.pid) for c in me.children()), flush=True)
    time.sleep(600)
    """
)


def test_evaluation_workers_exit_with_a_killed_parent(repo_root):
    proc = subprocess.Popen([sys.executable, "-c", _PARENT], cwd=repo_root, stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        pids = [int(p) for p in line.split()]
        assert len(pids) >= 2, line
        assert all(psutil.pid_exists(p) for p in pids)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 5.0 and any(_alive(p) for p in pids):
            time.sleep(0.1)
        alive = [p for p in pids if _alive(p)]
        assert not alive, f"workers {alive} outlived their parent by 5 s"
    finally:
        if proc.poll() is None:
            proc.kill()


def _alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


_HOLDER = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from omcrl.runs import Run
    Run("rl", "ppo", 0, "k", {}, Path(sys.argv[1])).claim()
    print("claimed", flush=True)
    time.sleep(600)
    """
)


def test_a_second_process_on_one_run_folder_is_refused_naming_the_holder(tmp_path, repo_root):
    import pytest

    from omcrl.runs import Run, RunLocked

    run_dir = tmp_path / "runs" / "rl" / "ppo-k" / "seed0"
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(run_dir)], cwd=repo_root, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "claimed"
        run = Run("rl", "ppo", 0, "k", {}, run_dir)
        with pytest.raises(RunLocked, match=rf"{run_dir} is in use by another process \(PID {holder.pid}\)"):
            run.claim()
        # The holder is killed: its lock goes with it, and the next process takes the run over.
        holder.kill()
        holder.wait(10)
        run.claim()
        run.claim()  # re-entrant in one process
        run.release()
    finally:
        if holder.poll() is None:
            holder.kill()


def test_two_trainings_of_one_run_do_not_both_write_it(tmp_path, repo_root):
    """The reproduction: two CLI processes train the same smoke run; one trains, the other refuses in one line."""
    args = [sys.executable, "-m", "omcrl", "train", "--method", "ppo", "--preset", "smoke",
            "--set", f"results_dir={tmp_path}", "--set", "rl.total_steps=2048"]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    procs = [subprocess.Popen(args, cwd=repo_root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=env) for _ in range(2)]  # fmt: skip
    outs = [p.communicate(timeout=600) for p in procs]
    codes = sorted(p.returncode for p in procs)
    refused = [err for (_, err), p in zip(outs, procs) if p.returncode != 0]
    assert codes[0] == 0 and codes[1] != 0, outs
    assert len(refused) == 1 and "is in use by another process (PID" in refused[0]
    assert "Traceback" not in refused[0] and sum(ln.startswith("error:") for ln in refused[0].splitlines()) == 1
    (metrics,) = (tmp_path / "smoke" / "runs" / "rl").glob("ppo-*/seed0/metrics.csv")
    import pandas as pd

    m = pd.read_csv(metrics)
    assert not m.duplicated(["step", "metric"]).any()


def test_a_dataset_locked_by_a_writer_is_reported_as_locked_not_corrupt(tmp_path, repo_root):
    import h5py

    from omcrl.data.dataset import DatasetWriter

    path = tmp_path / "box.h5"
    with DatasetWriter(path, image_size=16, frame_stack=2, env_config={}):
        pass
    with h5py.File(path, "a"):  # a writer holds HDF5's file lock
        code = f"from omcrl.data.dataset import open_dataset\nopen_dataset({str(path)!r})"
        r = subprocess.run([sys.executable, "-c", code], cwd=repo_root, capture_output=True, text=True, timeout=120)
    assert r.returncode != 0
    assert f"dataset {path} is locked by another process" in r.stderr and "corrupt" not in r.stderr


def _episode(rng, image_size: int = 16, steps: int = 5) -> dict:
    return {
        "rgb": rng.integers(0, 255, (steps, 3, image_size, image_size), dtype=np.uint8),
        "depth": rng.random((steps, image_size, image_size), dtype=np.float32),
        "state": np.zeros((steps, 12), np.float32),
        "privileged": np.zeros((steps, 6), np.float32),
        "action": np.zeros((steps, 3), np.float32),
        "reward": np.zeros(steps, np.float32),
        "done": np.eye(1, steps, steps - 1, dtype=bool)[0],
        "scene": "box-v0",
        "seed": 0,
        "source": "pilot",
    }


def test_a_writer_that_crashes_inside_hdf5_is_one_error_and_the_file_stays_appendable(tmp_path):
    """Collection's HDF5 writer runs in its own process: a segfault there (what a full disk inside HDF5 caused in
    the collector itself) is one DatasetError naming the file; the complete episodes stay readable and a new
    writer appends after them."""
    from omcrl.data.dataset import DatasetError, WriterProcess, open_dataset

    rng = np.random.default_rng(0)
    path = tmp_path / "box.h5"
    with pytest.raises(DatasetError) as err, WriterProcess(path, 16, 2, {"scene": "box-v0"}) as w:
        assert w.add_episode(**_episode(rng)) == 0 and w.add_episode(**_episode(rng)) == 1
        os.kill(w.pid, signal.SIGSEGV)
        w.add_episode(**_episode(rng))
    msg = str(err.value)
    assert "\n" not in msg and f"dataset {path}: the writer process died (signal 11)" in msg
    assert "keeps its 2 complete episodes" in msg
    with open_dataset(path) as ds:
        assert len(ds) == 2
    with WriterProcess(path, 16, 2, {"scene": "box-v0"}) as w:
        assert not w.created and w.add_episode(**_episode(rng)) == 2
    with open_dataset(path) as ds:
        assert len(ds) == 3


def test_a_writer_process_reports_bad_episodes_and_bad_files_as_the_writer_does(tmp_path):
    from omcrl.data.dataset import DatasetError, WriterProcess

    rng = np.random.default_rng(0)
    path = tmp_path / "box.h5"
    with WriterProcess(path, 16, 2, {}) as w:
        bad = _episode(rng) | {"state": np.zeros((5, 11), np.float32)}
        with pytest.raises(ValueError, match=r"episode field 'state': got shape \(5, 11\), expected \(5, 12\)"):
            w.add_episode(**bad)
    with pytest.raises(DatasetError, match=r"cannot append, field 'image_size' is 16 in the file but the writer"):
        WriterProcess(path, 32, 2, {})


def _tmpfs(path, size: str):
    path.mkdir(exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.decode().strip() or r.returncode}); needs root")


def test_collect_on_a_disk_that_fills_exits_with_one_line_and_appends_after(tmp_path, repo_root):
    """A real full disk (a 3 MiB tmpfs) during `python -m omcrl collect`: exit 1, one line naming the file, no
    segfault; the dataset keeps its complete episodes, and after the disk grows a rerun appends to it."""
    from omcrl.data.dataset import open_dataset

    disk = tmp_path / "disk"
    _tmpfs(disk, "3m")
    try:
        data = disk / "box.h5"
        args = [
            sys.executable,
            "-m",
            "omcrl",
            "collect",
            "--preset",
            "smoke",
            "--set",
            f"data.file={data}",
            "--set",
            f"results_dir={tmp_path}/results",
            "--set",
            "data.episodes=40",
            "--set",
            "data.n_envs=1",
        ]
        r = subprocess.run(args, cwd=repo_root, capture_output=True, text=True, timeout=600)
        assert r.returncode == 1, r.stderr[-2000:]
        err = [ln for ln in r.stderr.splitlines() if ln.startswith("error")]
        assert len(err) == 1 and f"dataset {data}: the disk is full" in err[0], r.stderr[-2000:]
        assert "Segmentation" not in r.stderr and "Exception ignored" not in r.stderr
        with open_dataset(data) as ds:
            kept = len(ds)
        assert 0 < kept < 40
        subprocess.run(["mount", "-o", "remount,size=64m", str(disk)], check=True)
        r = subprocess.run(args, cwd=repo_root, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-2000:]
        with open_dataset(data) as ds:
            assert len(ds) == 40
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def _garble(path, n: int = 64) -> None:
    """Overwrite ``n`` bytes in the middle of a file (a zip-based torch file stays loadable)."""
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid : mid + n] = bytes((b + 101) % 256 for b in data[mid : mid + n])
    path.write_bytes(bytes(data))


def test_a_damaged_oracle_is_refused_before_a_student_trains_on_it(tmp_path, repo_root):
    import pytest

    from omcrl.config import load_config
    from omcrl.pipeline import train_method
    from omcrl.rl import load_policy
    from omcrl.runs import ArtifactMismatch
    from omcrl.utils.io import file_digest

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    oracle = train_method(cfg, "oracle", progress=False)
    load_policy(oracle.final_path)  # intact: loads
    _garble(oracle.final_path)
    with pytest.raises(ArtifactMismatch, match="re-run: python -m omcrl train --method oracle --preset smoke --seed 0"):
        load_policy(oracle.final_path)
    before = {p: file_digest(p) for p in tmp_path.rglob("*") if p.is_file()}
    r = subprocess.run(
        [sys.executable, "-m", "omcrl", "train", "--method", "npe-ot", "--preset", "smoke", "--set",
         f"results_dir={tmp_path}"], cwd=repo_root, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert sum(ln.startswith("error:") for ln in r.stderr.splitlines()) == 1
    assert f"{oracle.final_path} does not match the digest recorded" in r.stderr
    assert not list((tmp_path / "smoke" / "runs" / "rl").glob("npe-ot-*"))  # nothing downstream written
    assert {p: file_digest(p) for p in before} == before


def test_a_damaged_pretraining_checkpoint_is_not_resumed(tmp_path):
    import pytest

    from omcrl.config import load_config
    from omcrl.data.collect import collect_dataset as collect
    from omcrl.pretrain.train import pretrain_encoder as pretrain
    from omcrl.runs import ArtifactMismatch

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}", f"data.file={tmp_path}/box.h5"])
    collect(cfg, progress=False)
    res = pretrain(cfg, progress=False, stop_after=10)
    ck = res.run_dir / "checkpoint.pt"
    assert ck.is_file() and not (res.run_dir / "encoder.pt").exists()
    _garble(ck)
    with pytest.raises(ArtifactMismatch, match="pretraining checkpoint .*checkpoint.pt does not match"):
        pretrain(cfg, progress=False)
    assert not (res.run_dir / "encoder.pt").exists()


def test_a_truncated_evaluation_cache_is_evaluated_again(tmp_path):
    import warnings

    import pytest

    from omcrl.config import load_config
    from omcrl.eval.stage import evaluate_methods

    cfg = load_config("smoke", overrides={"results_dir": str(tmp_path), "eval": {"workers": 1}})
    first = evaluate_methods(cfg, {"hybrid-apf": "hybrid-apf"}, ["box"], 3)
    (csv,) = (tmp_path / "smoke" / "eval" / "hybrid-apf" / "seed0").glob("box-v2-*/episodes.csv")
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:2]) + "\n")  # header and one episode
    with pytest.warns(UserWarning, match=r"does not match the digest recorded .*damaged evaluation cache; evaluating"):
        again = evaluate_methods(cfg, {"hybrid-apf": "hybrid-apf"}, ["box"], 3)
    assert len(again) == 3 and list(again.success) == list(first.success)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # rewritten whole: read back without a warning
        assert len(evaluate_methods(cfg, {"hybrid-apf": "hybrid-apf"}, ["box"], 3)) == 3


def test_a_cached_evaluation_is_a_run_recorded_and_locked_like_a_training(tmp_path, repo_root, monkeypatch):
    """One lifecycle for evaluations: run.json names the evaluation's identity, its rows and the CSV's digest; a
    second process flying the same evaluation is refused while the first holds it; a bumped behaviour version of a
    component it depends on makes it a new run, flown again."""
    import pytest

    import omcrl.runs as runs
    from omcrl.config import load_config
    from omcrl.eval.stage import evaluate_methods
    from omcrl.runs import RunLocked, read_identity
    from omcrl.utils.io import file_digest

    cfg = load_config("smoke", overrides={"results_dir": str(tmp_path), "eval": {"workers": 1}})
    evaluate_methods(cfg, {"hybrid-apf": "hybrid-apf"}, ["box"], 2)
    seed0 = tmp_path / "smoke" / "eval" / "hybrid-apf" / "seed0"
    (run_dir,) = (p for p in seed0.glob("box-v2-*") if p.is_dir())  # beside it: its lock file
    rec = read_identity(run_dir)
    assert rec["stage"] == "eval" and rec["rows"] == 2 and run_dir.name == f"box-v2-{rec['key']}"
    assert rec["identity"]["policy"] == "hybrid-apf" and rec["identity"]["versions"]["planners"] >= 1
    assert rec["artifact_digest"] == file_digest(run_dir / "episodes.csv") and rec["machines"]
    # Another process holds the run that is to be flown (furniture has no cache yet): refused, naming its PID.
    evaluate_methods(cfg, {"hybrid-apf": "hybrid-apf"}, ["furniture"], 2)
    (other,) = (p for p in seed0.glob("furniture-v2-*") if p.is_dir())
    import shutil

    shutil.rmtree(other)
    holder = subprocess.Popen(
        [sys.executable, "-c", f"from pathlib import Path\nfrom omcrl.runs import acquire_lock\n"
         f"acquire_lock(Path({str(other)!r}))\nprint('held', flush=True)\nimport time\ntime.sleep(120)"],
        cwd=repo_root, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(RunLocked, match=rf"in use by another process \(PID {holder.pid}\)"):
            evaluate_methods(cfg, {"hybrid-apf": "hybrid-apf"}, ["furniture"], 2)
    finally:
        holder.kill()
        holder.wait()
    assert not (other / "episodes.csv").exists()
    # A planners' behaviour bump: the box evaluation is another run, and flown again beside the old one.
    monkeypatch.setitem(runs.BEHAVIOUR, "planners", runs.BEHAVIOUR["planners"] + 1)
    stats: dict[str, int] = {}
    evaluate_methods(cfg, {"hybrid-apf": "hybrid-apf"}, ["box"], 2, stats=stats)
    assert stats == {"evaluated": 1} and len(list(seed0.glob("box-v2-*/episodes.csv"))) == 2


# ---------------------------------------------------------------- every file kind, damaged three ways
CORRUPTIONS = {
    "garbled": lambda p: _garble(p, 256),
    "truncated": lambda p: p.write_bytes(p.read_bytes()[: max(1, p.stat().st_size // 2)]),
    "empty": lambda p: p.write_bytes(b""),
}


def _smoke_artifacts(root):
    """Every kind of file the kit writes and reads back, from a tiny real chain (smoke preset)."""
    from omcrl.config import load_config
    from omcrl.data.collect import collect_dataset as collect
    from omcrl.eval.stage import evaluate_methods
    from omcrl.pipeline import train_method
    from omcrl.pretrain.train import pretrain_encoder as pretrain

    cfg = load_config("smoke", overrides={"results_dir": str(root), "data": {"file": f"{root}/box.h5"},
                                          "eval": {"workers": 1}})  # fmt: skip
    collect(cfg, progress=False)
    enc = pretrain(cfg, progress=False)
    part = pretrain(cfg.with_seed(1), progress=False, stop_after=10)
    ppo = train_method(cfg, "ppo", progress=False)
    evaluate_methods(cfg, {"ppo": ppo.final_path}, ["box"], 2)
    (cache,) = (root / "smoke" / "eval" / "ppo" / "seed0").glob("box-v2-*/episodes.csv")
    return cfg, {
        "policy final.pt": ppo.final_path,
        "run.json": ppo.run_dir / "run.json",
        "run config.yaml": ppo.run_dir / "config.yaml",
        "metrics.csv": ppo.run_dir / "metrics.csv",
        "encoder.pt": enc.run_dir / "encoder.pt",
        "pretraining run.json": enc.run_dir / "run.json",
        "pretraining checkpoint.pt": part.run_dir / "checkpoint.pt",
        "dataset .h5": root / "box.h5",
        "evaluation cache episodes.csv": cache,
        "evaluation cache run.json": cache.with_name("run.json"),
    }


def _consume(kind, cfg, files):
    """Read ``kind`` as the kit does; returns what the reader returned (or raises)."""
    from omcrl.data.dataset import open_dataset
    from omcrl.deploy.export import export_onnx
    from omcrl.eval.stage import evaluate_methods
    from omcrl.models.artifact import load_encoder
    from omcrl.pretrain.train import pretrain_encoder as pretrain
    from omcrl.rl import load_policy
    from omcrl.runs import read_identity, read_metrics

    if kind == "policy final.pt":
        return load_policy(files[kind])
    if kind == "run.json":
        return read_identity(files[kind].parent)
    if kind == "run config.yaml":
        return export_onnx(files["policy final.pt"].parent, out=files[kind].parent / "x.onnx")
    if kind == "metrics.csv":
        return read_metrics(files[kind])
    if kind == "encoder.pt":
        return load_encoder(files[kind])
    if kind in ("pretraining run.json", "pretraining checkpoint.pt"):
        return pretrain(cfg if kind == "pretraining run.json" else cfg.with_seed(1), progress=False)
    if kind == "dataset .h5":  # as pretraining reads it: every episode's frames
        with open_dataset(files[kind]) as ds:
            return [ds.read(i, f) for i in range(len(ds)) for f in ("rgb", "depth", "state")]
    return evaluate_methods(cfg, {"ppo": files["policy final.pt"]}, ["box"], 2)  # the evaluation cache


def test_every_damaged_file_is_one_line_or_rebuilt_and_leaves_the_others_alone(tmp_path):
    """Each kind of file the kit writes, garbled, truncated and emptied: the reader either refuses with one line
    naming the file (an error the CLI prints as one line) or, for a cache, warns and evaluates again; no other file
    changes. 10 kinds x 3 corruptions."""
    import shutil
    import warnings

    from omcrl.__main__ import _expected_errors
    from omcrl.utils.io import file_digest

    src = tmp_path / "src"
    cfg0, files0 = _smoke_artifacts(src)
    expected = _expected_errors()
    outcomes = {}
    for kind in files0:
        for how, damage in CORRUPTIONS.items():
            root = tmp_path / f"{len(outcomes)}"
            shutil.copytree(src, root)
            cfg = cfg0.__class__(**{**cfg0.__dict__, "results_dir": str(root)})
            cfg.data.file = f"{root}/box.h5"
            files = {k: root / p.relative_to(src) for k, p in files0.items()}
            damage(files[kind])
            before = {p: file_digest(p) for p in root.rglob("*") if p.is_file() and p != files[kind]}
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    _consume(kind, cfg, files)
                    outcome = "rebuilt" if any("damaged" in str(w.message) or "rebuild" in str(w.message)
                                               for w in caught) else "accepted"  # fmt: skip
                except expected as e:
                    msg = str(e)
                    assert "\n" not in msg.strip(), (kind, how, msg)
                    assert files[kind].name in msg or str(files[kind].parent) in msg, (kind, how, msg)
                    outcome = "refused"
            # Nothing but the damaged file (and what a rebuild legitimately rewrites) changed.
            rewritable = {
                "evaluation cache episodes.csv",
                "evaluation cache run.json",
                "pretraining run.json",
                "encoder.pt",
            }
            changed = [p for p, d in before.items() if p.exists() and file_digest(p) != d and p.suffix != ".lock"]
            if kind not in rewritable:
                assert not changed, (kind, how, changed)
            outcomes[(kind, how)] = outcome
    assert len(outcomes) == 30
    accepted = [k for k, v in outcomes.items() if v == "accepted"]
    assert not accepted, f"damaged files used as if intact: {accepted}"


def test_smaller_refusals_are_one_line(tmp_path):
    import numpy as np
    import pytest

    from omcrl.__main__ import describe
    from omcrl.config import ConfigError, load_config
    from omcrl.data.collect import CollectResult
    from omcrl.envs import make_env

    with pytest.raises(ConfigError, match="'results_dir': got ''"):
        load_config("smoke", overrides=["results_dir="])
    bad = tmp_path / "bad.yaml"
    bad.write_text("env:\n  image_size: [1,\n")
    with pytest.raises(ConfigError, match=r"not valid YAML at line 3, column 1: expected the node content") as e:
        load_config("smoke", path=bad)
    assert "\n" not in str(e.value)
    env = make_env("box", seed=0, image_size=16)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="complex"):
        env.step(np.array([0.5 + 1j, 0, 0]))
    env.close()
    text = describe(CollectResult(tmp_path / "box.h5", 6, 0, 0, {"pilot": 4}, {}, 0.5, True))
    assert "CollectResult(" not in text and f"path: {tmp_path / 'box.h5'}" in text
