"""The run registry: identity, claim/check, metrics I/O, RNG state; the CLI's method stages."""

from __future__ import annotations

import io
import json
import random
import subprocess
import sys

import numpy as np
import pytest
import torch

from omcrl.config import load_config
from omcrl.runs import (
    MetricsLog,
    Run,
    RunConfigMismatch,
    find_runs,
    make_run,
    metric_series,
    read_metrics,
    rng_state,
    set_rng_state,
)


def test_identity_decides_the_folder_and_claim_refuses_another(tmp_path):
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    a = make_run(cfg, "rl", "m", {"x": 1, "y": [1, 2]})
    assert make_run(cfg, "rl", "m", {"y": (1, 2), "x": 1}).dir == a.dir  # order, tuple vs list: same identity
    b = make_run(cfg, "rl", "m", {"x": 2, "y": [1, 2]})
    assert b.dir != a.dir and b.dir.parent.name.startswith("m-")
    assert make_run(cfg.with_seed(4), "rl", "m", {"x": 1, "y": [1, 2]}).dir == a.dir.parent / "seed4"
    a.claim()
    rec = json.loads((a.dir / "run.json").read_text())
    assert rec["key"] == a.key and rec["identity"]["x"] == 1 and rec["seed"] == 0
    # A folder holding another identity's record is refused, and only replaced on request.
    impostor = type(a)(a.stage, a.method, a.seed, "ffffffffff", {}, a.dir)
    with pytest.raises(RunConfigMismatch, match="key"):
        impostor.check()
    with pytest.raises(RunConfigMismatch):
        impostor.claim()
    (a.dir / "keep.txt").write_text("x")
    impostor.claim(overwrite=True)
    assert not (a.dir / "keep.txt").exists()
    assert [r["key"] for r in find_runs(tmp_path / "smoke", "rl")] == ["ffffffffff"]


def test_run_json_names_every_machine_that_trained_the_run(tmp_path, monkeypatch):
    """Same seed, same result holds per CPU and torch build: a run resumed on another host says so."""
    import omcrl.runs as runs

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    run = make_run(cfg, "rl", "m", {"x": 1})
    run.claim()
    run.release()
    first = json.loads((run.dir / "run.json").read_text())["machines"]
    assert len(first) == 1 and first[0]["cpu_model"] and first[0]["cpu_capability"] and first[0]["torch"]
    run.claim()  # a resume on the same machine adds nothing
    run.release()
    assert json.loads((run.dir / "run.json").read_text())["machines"] == first
    other = {**first[0], "cpu_model": "Another CPU", "cpu_capability": "AVX512"}
    monkeypatch.setattr(runs, "machine_info", lambda: other)
    run.claim()
    run.release()
    rec = json.loads((run.dir / "run.json").read_text())
    assert rec["machines"] == [*first, other] and rec["key"] == run.key


def test_metrics_log_resume_drops_rows_past_the_checkpoint(tmp_path):
    log = MetricsLog(tmp_path, None, tensorboard=False)
    for step in (10, 20, 30):
        log.log(step, {"a": step / 10, "b": float("nan")})
    log.close()
    assert list(read_metrics(tmp_path).step) == [10, 20, 30]
    MetricsLog(tmp_path, 20, tensorboard=False).close()
    steps, values = metric_series(tmp_path / "metrics.csv")["a"]
    assert list(steps) == [10, 20] and list(values) == [1.0, 2.0]
    assert read_metrics(tmp_path / "nothing").empty


def test_rng_state_round_trips_through_a_weights_only_checkpoint():
    torch.manual_seed(3)
    np.random.seed(3)  # noqa: NPY002
    random.seed(3)
    state = rng_state()
    buf = io.BytesIO()
    torch.save({"rng": state}, buf)
    first = (torch.rand(3), np.random.rand(3), random.random())  # noqa: NPY002
    buf.seek(0)
    set_rng_state(torch.load(buf, weights_only=True)["rng"])
    again = (torch.rand(3), np.random.rand(3), random.random())  # noqa: NPY002
    assert torch.equal(first[0], again[0]) and np.array_equal(first[1], again[1]) and first[2] == again[2]


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "omcrl", *args], cwd=cwd, capture_output=True, text=True)


def test_cli_method_stages(tmp_path, repo_root):
    r = _cli("--help", cwd=repo_root)
    assert r.returncode == 0 and "methods (--method):" in r.stdout and "npe-ot" in r.stdout
    r = _cli("train", "--method", "nope", "--preset", "smoke", cwd=repo_root)
    assert r.returncode == 2 and "known methods" in r.stderr
    r = _cli(
        "train",
        "--method",
        "curl",
        "--preset",
        "smoke",
        "--seed",
        "2",
        "--set",
        f"results_dir={tmp_path}",
        cwd=repo_root,
    )
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert "pretrain --method curl --preset smoke --seed 2" in r.stderr
    r = _cli("evaluate", "--method", "curl", "--preset", "smoke", cwd=repo_root)
    assert r.returncode == 2 and "--method applies" in r.stderr


class _Recorder:
    """A lifecycle callback that writes down what it sees (SB3-style hooks)."""

    def __init__(self):
        self.events = []

    def on_start(self, run, step):
        assert isinstance(run, Run)
        self.events.append(("start", step))

    def on_step(self, run, step, metrics):
        assert "loss" in metrics
        self.events.append(("step", step))
        return True

    def on_checkpoint(self, run, step, path):
        assert path.exists()
        self.events.append(("checkpoint", step))

    def on_end(self, run, step, finished):
        self.events.append(("end", step, finished))


def test_one_lifecycle_stops_on_a_callback_and_resumes_from_its_checkpoint(tmp_path):
    """Every training loop calls the same hooks (:class:`omcrl.runs.Callback`): start, steps, checkpoints and the end;
    StopAfter interrupts a run after its checkpoint, and the next call resumes there and finishes the run. (A
    resumed RL run does not repeat the uninterrupted run's weights: its envs restart with a new seed, since an
    episode in flight cannot be checkpointed; pretraining resumes bit for bit, tests/test_pretrain.py.)"""
    from omcrl.pipeline.recipes import train_method
    from omcrl.runs import Callback, StopAfter

    assert issubclass(StopAfter, Callback)
    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    rec = _Recorder()
    cut = train_method(cfg, "ppo", progress=False, callbacks=(rec, StopAfter(384)))
    assert cut.steps == 384 and not (cut.run_dir / "final.pt").exists() and cut.final_path.name == "checkpoint.pt"
    assert rec.events == [("start", 0), ("step", 128), ("checkpoint", 256), ("step", 256), ("step", 384),
                          ("end", 384, False)]  # fmt: skip
    ckpt = torch.load(cut.final_path, weights_only=True)
    assert ckpt["step"] == 256 and ckpt["update"] == 2
    rec2 = _Recorder()
    done = train_method(cfg, "ppo", progress=False, callbacks=(rec2,))
    assert rec2.events[0] == ("start", 256) and rec2.events[-1] == ("end", 512, True)
    assert done.steps == 512 and (done.run_dir / "final.pt").exists() and not (done.run_dir / "checkpoint.pt").exists()
    assert (cut.start, done.start) == (0, 256)  # a sweep sets the resumed call's time against 256 steps, not 512
    rows = read_metrics(done.run_dir)
    assert sorted(set(rows["step"])) == [128, 256, 384, 512] and rows.groupby("step").size().nunique() == 1
    # Finished: a third call skips it, and the callbacks are not run.
    rec3 = _Recorder()
    assert train_method(cfg, "ppo", progress=False, callbacks=(rec3,)).skipped and rec3.events == []
