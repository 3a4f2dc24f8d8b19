"""The kit as a user meets it: progress, paths that resolve from anywhere, the CLI's habits (the summary:
tests/test_summary.py)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest

from omcrl.config import load_config, project_root
from omcrl.utils.progress import Progress, format_duration


# ---------------------------------------------------------------- progress
def test_format_duration():
    assert format_duration(9.4) == "9s"
    assert format_duration(75) == "1m15s"
    assert format_duration(3725) == "1h02m05s"


def test_progress_log_lines_and_time_left(capsys, monkeypatch):
    monkeypatch.delenv("OMCRL_STATUS_FILE", raising=False)
    bar = Progress(100, "rl/ours seed0", unit="step", initial=20, log_interval=0.0)
    for _ in range(4):
        bar.update(20, sr="0.50")
    bar.close()
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[omcrl]")]
    assert len(lines) == 6  # start, four updates, close
    assert "20/100 step (20%)" in lines[0]
    assert "60/100 step (60%) | sr 0.50" in lines[2] and "left" in lines[2]
    assert lines[-1].endswith("elapsed, done")


def test_progress_in_a_kernel_writes_log_lines_inside_log_lines(capsys, monkeypatch):
    """A sweep's local backend runs each job in the caller's process, a notebook's kernel in notebook 06: inside
    log_lines() its loops write status lines to stderr (the job's log), not a display in the notebook."""
    from omcrl.utils import progress

    monkeypatch.delenv("OMCRL_STATUS_FILE", raising=False)
    monkeypatch.setattr(progress, "_in_kernel", lambda: True)
    shown = []
    monkeypatch.setattr(Progress, "_text_object", lambda self, final=False: shown.append(final))
    with progress.log_lines(), Progress(10, "rl/ours seed0", log_interval=0.0) as bar:
        bar.update(10)
    assert not shown and capsys.readouterr().err.splitlines()[-1].endswith("elapsed, done")
    assert not progress._LOG_LINES.get()  # after the block, a kernel's loops show in the notebook again


def test_progress_disabled_writes_nothing(capsys, tmp_path, monkeypatch):
    status = tmp_path / "status.log"
    monkeypatch.setenv("OMCRL_STATUS_FILE", str(status))
    with Progress(10, "x", enabled=False, log_interval=0.0) as bar:
        bar.update(10)
    assert capsys.readouterr().err == "" and not status.exists()


def test_progress_status_file_is_throttled(tmp_path, monkeypatch):
    status = tmp_path / "status.log"
    monkeypatch.setenv("OMCRL_STATUS_FILE", str(status))
    with Progress(1000, "pretrain/omc seed0", unit="it", status_interval=3600.0, log_interval=3600.0) as bar:
        for _ in range(1000):
            bar.update(1, loss=2.5)
    lines = status.read_text().splitlines()
    assert len(lines) == 2  # the first line and the final one; nothing in between at a 1 h interval
    assert lines[-1].startswith("pretrain/omc seed0 | 1000/1000 it (100%) | loss 2.5 |")


_PROGRESS_NB = """
from omcrl.utils.progress import Progress

with Progress(300, "demo", unit="it", notebook_interval=0.0) as bar:
    for i in range(300):
        bar.update(1, i=i)
"""


@pytest.mark.notebooks
def test_notebook_progress_is_one_output_and_console_gets_status(tmp_path, capfd, monkeypatch):
    from omcrl.pipeline.notebooks import run_chain

    nb = nbformat.v4.new_notebook()
    p = nbformat.v4.new_code_cell('preset = "smoke"')
    p.metadata["tags"] = ["parameters"]
    nb.cells = [p, nbformat.v4.new_code_cell(_PROGRESS_NB)]
    src = tmp_path / "90_progress.ipynb"
    nbformat.write(nb, src)
    monkeypatch.setenv("OMCRL_STATUS_INTERVAL", "0")
    (out,) = run_chain("smoke", [str(src)], results_dir=tmp_path / "res", cwd=tmp_path)
    executed = nbformat.read(out, as_version=4)
    outputs = executed.cells[-1].outputs  # papermill inserts its injected-parameters cell before it
    # 300 refreshes at interval 0, yet one output, showing the final state.
    assert len(outputs) == 1, [o.output_type for o in outputs]
    assert "300/300 it (100%)" in outputs[0]["data"]["text/plain"] and "done" in outputs[0]["data"]["text/plain"]
    console = capfd.readouterr()
    fed = [ln for ln in console.out.splitlines() if "| demo |" in ln]
    assert fed and "300/300 it" in fed[-1]
    # The kernel's start-up warnings stay off the console.
    assert "without encryption" not in console.err + console.out
    times = json.loads((out.parent / "wall_times.json").read_text())
    assert str(src) in times
    # The kernel's memory was sampled while it ran (a Python kernel with numpy holds well over 20 MB).
    assert json.loads((out.parent / "peak_rss_mb.json").read_text())[str(src)] > 20


# ---------------------------------------------------------------- paths
_PATHS = "from omcrl.config import load_config; c = load_config('smoke'); print(c.run_root); print(c.data_path)"


def test_paths_resolve_from_the_repository_root_wherever_the_kernel_runs(repo_root, tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "OMCRL_ROOT"}
    outs = [
        subprocess.run([sys.executable, "-c", _PATHS], cwd=cwd, capture_output=True, text=True, env=env).stdout
        for cwd in (repo_root, repo_root / "notebooks", tmp_path)
    ]
    assert outs[0] == outs[1] == outs[2]
    run_root, data = (Path(x) for x in outs[0].split())
    assert run_root == repo_root.resolve() / "results" / "smoke"
    assert data == repo_root.resolve() / "data" / "smoke" / "box-seed0.h5"
    moved = subprocess.run(
        [sys.executable, "-c", _PATHS],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**env, "OMCRL_ROOT": str(tmp_path)},
    ).stdout.split()
    assert Path(moved[0]) == tmp_path.resolve() / "results" / "smoke"
    # An absolute results_dir is kept as given.
    assert load_config("smoke", overrides=[f"results_dir={tmp_path}"]).run_root == tmp_path / "smoke"


# ---------------------------------------------------------------- CLI
def test_every_stage_has_its_own_help(capsys):
    from omcrl.__main__ import STAGES, main
    from omcrl.pipeline.registry import NO_PRESET_STAGES

    for stage in STAGES:
        with pytest.raises(SystemExit) as e:
            main([stage, "--help"])
        assert e.value.code == 0
        out = capsys.readouterr().out
        assert f"python -m omcrl {stage}: " in out, stage
        assert ("--preset" in out) == (stage not in NO_PRESET_STAGES), stage
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    out = capsys.readouterr().out  # the methods are listed where --method is taken: those it can take
    assert "\n  npe-expert " in out and "\n  ppo " in out and "\n  hybrid-apf-perceptive " not in out
    with pytest.raises(SystemExit):
        main(["pretrain", "--help"])
    out = capsys.readouterr().out
    assert "\n  curl-phi " in out and "\n  ppo " not in out and "\n  oracle " not in out


def test_a_stage_without_preset_is_refused_before_any_work(repo_root, tmp_path):
    r = subprocess.run([sys.executable, "-m", "omcrl", "collect"], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 2 and "required: --preset" in r.stderr
    assert not any(tmp_path.iterdir())


def test_reproduce_refuses_a_contradictory_preset(repo_root):
    r = subprocess.run(
        ["bash", str(repo_root / "reproduce.sh"), "--smoke", "--preset", "quick"], capture_output=True, text=True
    )
    assert r.returncode == 2
    assert "--smoke already chooses the preset" in r.stderr
    assert "installing" not in r.stdout  # refused before the venv check or any install


def test_reproduce_takes_from_reference_only_with_a_chain_mode(repo_root):
    r = subprocess.run(
        ["bash", str(repo_root / "reproduce.sh"), "--test", "--from-reference"], capture_output=True, text=True
    )
    assert r.returncode == 2 and "--from-reference goes with a chain mode" in r.stderr
    assert "installing" not in r.stdout


def test_project_root_is_the_checkout(repo_root):
    assert project_root() == repo_root.resolve()


def test_the_chain_prints_its_plan_with_each_notebooks_estimate_and_the_total():
    """Speed issue, item 4: before the first notebook, each notebook of the chain with its estimate (a training
    notebook's scaled by the run's env steps against the budget it was measured at) and the total."""
    from omcrl.pipeline.expected import EXPECTED_WALL_S, MEASURED_RL_STEPS, chain_plan

    chain = ["00_scenes", "03_train_oracle", "99_new"]
    same = chain_plan("quick", chain, MEASURED_RL_STEPS["quick"])
    assert same[0].startswith("plan, preset quick") and "99_new" in same[3] and "not measured" in same[3]
    tripled = chain_plan("quick", chain, 3 * MEASURED_RL_STEPS["quick"])
    assert "scaled to 454,656" in tripled[2] and "scaled" not in tripled[1]
    from omcrl.utils.progress import format_duration

    want = EXPECTED_WALL_S["quick"]["00_scenes"] + 3 * EXPECTED_WALL_S["quick"]["03_train_oracle"]
    assert tripled[-1].split("~")[1] == f"{format_duration(want)} + 1 not measured"
    # With the grid's measured training times, a training notebook's estimate is its methods' sum.
    grid = chain_plan("quick", ["03_train_oracle", "04_train_student"], 450_000, {"oracle": 100.0, "ours": 60.0})
    assert "~1m40s" in grid[1] and "grid's measured" in grid[1]  # oracle: its measured time
    assert "scaled" in grid[2]  # ours-noOT has no measured time: 04 falls back to its wall time, scaled


def test_ctrl_c_says_what_is_kept_and_that_the_same_command_resumes(monkeypatch, capsys):
    """Ctrl-C in any stage ends with one line: what was kept and that running the command again goes on (exit 130)."""
    import omcrl.__main__ as cli

    def interrupted(cfg, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "load_stage", lambda name: interrupted)
    assert cli.main(["collect", "--preset", "smoke"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("interrupted: stage collect; what finished is kept") and "again to resume" in err[-1]


def test_a_notebook_number_may_drop_its_zero_and_a_wrong_one_is_refused_before_any_work(capsys):
    """``--only 7`` is ``07``; ``reproduce.sh`` checks --only and --skip (check_choice) before it unpacks or runs."""
    from omcrl.pipeline.notebooks import check_choice, select_notebooks

    assert select_notebooks(["7", "08"]) == ["07_tables", "08_interpretability"]
    assert select_notebooks(skip=["6"]) == [n for n in select_notebooks() if n != "06_ablations"]
    assert check_choice(["--set", "x=1", "--only", "7,9"]) == 0
    assert check_choice(["--only", "7", "--skip=77"]) == 2
    assert "--skip 77" in capsys.readouterr().err


def test_the_choice_check_loads_neither_torch_nor_the_evaluation_stack():
    """reproduce.sh runs check_choice before any work: the module it imports must not pull in torch (it did through
    the summary, 8 s of a refusal under load); checked in a fresh interpreter, whose modules this process cannot see."""
    code = "import sys; import omcrl.pipeline.notebooks; print(sorted({'torch', 'omcrl.eval'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"


def test_every_page_quotes_performance_mds_estimate_of_the_v2_chain():
    """The v2 ``--skip 06`` chain's wall time, not measured end to end: performance.md's table row is the estimate,
    and the README's quick start, usage.md and the quick preset quote it (they gave 5 h, 6 h 20 min, 7 h 11 min)."""
    root = project_root()
    row = next(ln for ln in (root / "docs/performance.md").read_text(encoding="utf-8").splitlines()
               if ln.startswith("| `--skip 06` on v2"))  # fmt: skip
    estimate = re.search(r"\*\*(about [^,*]+), estimated\*\*", row).group(1)
    for page in ("README.md", "docs/usage.md", "omcrl/presets/quick.yaml"):
        text = " ".join((root / page).read_text(encoding="utf-8").split())
        assert estimate in text, f"{page} does not quote performance.md's v2 estimate {estimate!r}"
        assert "6 h 20 min" not in text, page


def test_a_notebooks_banner_gives_the_estimate_the_chains_plan_gives():
    """Each notebook's first line and the chain's plan estimate alike, from the suite in use: training and Table I
    notebooks from the grid's measured jobs (jobs.csv), 08 and 09 from their v2 measurement, not the v1 table."""
    from omcrl.config import load_config
    from omcrl.pipeline.expected import (
        EXPECTED_WALL_S,
        chain_plan,
        expected_time,
        grid_evaluation_seconds,
        grid_training_seconds,
    )
    from omcrl.utils.progress import format_duration

    cfg = load_config("quick")
    steps = cfg.rl.total_steps
    train_s, eval_s = grid_training_seconds("quick", "v2", steps), grid_evaluation_seconds("quick", "v2")
    chain = ["03_train_oracle", "07_tables", "08_interpretability"]
    plan = chain_plan("quick", chain, steps, train_s, eval_s, "v2")
    for n, line in zip(chain, plan[1:], strict=False):
        est = line.split("~", 1)[1].split()[0]
        assert f"about {est} on a 2-core CPU" in expected_time("quick", n), n
    assert format_duration(EXPECTED_WALL_S["quick"]["08_interpretability"]) not in plan[3]  # the v1 figure is gone
    assert "grid's measured" in plan[1] and "grid's measured evaluation" in plan[2]
