"""scripts/grid_session.sh's git work: what it commits after each variant, with ``--also``.

The script's Python calls go to a stand-in interpreter (``FakePython`` below: it records its arguments, and a
``sweep --to-reference`` writes one episodes file where the real sweep would), so the test is the script's loop,
shipping and commits, not the sweeps themselves (tests/test_sweep.py covers those).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

FAKE_PYTHON = r"""#!/usr/bin/env bash
# FakePython: stands in for .venv/bin/python in a dry run of grid_session.sh.
echo "$PWD|$*" >> "$CALLS"
# The script asks the kit for a grid's variant labels (no --variants): the real interpreter answers that.
if [[ "$1" == -c ]]; then exec "$REAL_PYTHON" "$@"; fi
if [[ "$3" == sweep && " $* " == *" --to-reference "* ]]; then
  args=("$@")
  for ((i = 0; i < ${#args[@]}; i++)); do
    [[ "${args[$i]}" == --seeds ]] && s="${args[$((i + 1))]}"
    [[ "${args[$i]}" == --variants ]] && v="${args[$((i + 1))]}"
  done
  mkdir -p "reference/quick/$4-v2/$v/seed$s"
  echo "$4 $v $s" > "reference/quick/$4-v2/$v/seed$s/episodes.csv.gz"
fi
# reference --pack ... --from DIR: a part where the real packing writes one; --retire: the pointer it leaves.
if [[ "$3" == reference && " $* " == *" --pack "* ]]; then
  mkdir -p "${@: -1}" && echo "$*" > "${@: -1}/MANIFEST.json"
fi
if [[ "$3" == reference && " $* " == *" --retire "* ]]; then echo "$*" > "${@: -1}/runs.tar.xz.git.json"; fi
"""


# The commits the script and the fixture make need an author; nothing else of the caller's environment changes.
IDENTITY = {k: v for who in ("AUTHOR", "COMMITTER") for k, v in ((f"GIT_{who}_NAME", "t"), (f"GIT_{who}_EMAIL", "t@t"))}


def _git(repo: Path, *args: str) -> str:
    env = {**os.environ, **IDENTITY}
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True, env=env).stdout


@pytest.fixture
def checkout(tmp_path: Path) -> Path:
    """A git checkout holding the script and a stand-in interpreter, with one commit and no grid folder yet (a
    grid's first session)."""
    repo = tmp_path / "main"
    (repo / "scripts").mkdir(parents=True)
    shutil.copy2(ROOT / "scripts" / "grid_session.sh", repo / "scripts" / "grid_session.sh")
    # The pages summary --readme rebuilds, which the script stages after a ship.
    for page in ("README.md", "docs/results.md", "docs/generalization.md", "docs/glossary.md", "docs/figures/quick/a"):
        (repo / page).parent.mkdir(parents=True, exist_ok=True)
        (repo / page).write_text("kit\n")
    (repo / ".gitignore").write_text(".venv/\n")
    py = repo / ".venv" / "bin" / "python"
    py.parent.mkdir(parents=True)
    py.write_text(FAKE_PYTHON)
    py.chmod(0o755)
    _git(repo, "init", "-q")
    _git(repo, "add", "-A")
    _git(repo, "commit", "-q", "-m", "start")
    return repo


def _run(repo: Path, *args: str) -> tuple[subprocess.CompletedProcess, list[str]]:
    calls = repo.parent / "calls.log"
    env = {**os.environ, **IDENTITY, "CALLS": str(calls), "REAL_PYTHON": sys.executable, "PYTHONPATH": str(ROOT)}
    cmd = ["bash", str(repo / "scripts" / "grid_session.sh"), "--dir", str(repo.parent / "wt"), *args]
    out = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=120)
    return out, calls.read_text().splitlines() if calls.exists() else []


def test_also_flies_each_variant_in_the_other_grid_and_commits_both(checkout: Path) -> None:
    out, calls = _run(checkout, "--seeds", "4", "--variants", "npe,ppo", "--also", "table1-confirm",
                      "--bundle-seed", "none")  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    sweeps = [c.split("|", 1)[1] for c in calls if "--to-reference" in c]  # only the grids' sweeps record
    # Each variant is trained in table1, then flown in table1-confirm, before the next variant starts.
    assert [(s.split()[3], s.split()[-1]) for s in sweeps] == [
        ("table1", "npe"), ("table1-confirm", "npe"), ("table1", "ppo"), ("table1-confirm", "ppo")
    ]  # fmt: skip
    log = _git(checkout, "log", "--format=%s").splitlines()
    assert log[:4] == [
        "table1-confirm grid: seed 4, ppo recorded (reference/quick/table1-confirm-v2/: ppo/seed4)",
        "table1 grid: seed 4, ppo recorded (reference/quick/table1-v2/: ppo/seed4)",
        "table1-confirm grid: seed 4, npe recorded (reference/quick/table1-confirm-v2/: npe/seed4)",
        "table1 grid: seed 4, npe recorded (reference/quick/table1-v2/: npe/seed4)",
    ]
    for grid in ("table1", "table1-confirm"):
        for v in ("npe", "ppo"):
            shown = _git(checkout, "show", f"HEAD:reference/quick/{grid}-v2/{v}/seed4/episodes.csv.gz")
            assert shown.split() == [grid, v, "4"]
    # The generated pages are rebuilt after both grids' ships (summary --readme), teachers released per grid.
    assert sum("summary --preset quick --readme" in c for c in calls) == 4
    assert any("sweep table1-confirm --preset quick --release-teachers" in c for c in calls)


def test_without_also_only_the_grid_runs(checkout: Path) -> None:
    out, calls = _run(checkout, "--seeds", "4", "--variants", "npe", "--bundle-seed", "none")
    assert out.returncode == 0, out.stdout + out.stderr
    assert not any("table1-confirm" in c for c in calls)
    assert _git(checkout, "log", "--format=%s").splitlines()[0].startswith("table1 grid: seed 4, npe recorded")


def test_without_variants_an_ablation_grid_runs_all_its_variants_in_order(checkout: Path) -> None:
    from omcrl.pipeline.grids import GRIDS

    out, calls = _run(checkout, "--grid", "decay", "--seeds", "0")
    assert out.returncode == 0, out.stdout + out.stderr
    sweeps = [c.split("|", 1)[1] for c in calls if "--to-reference" in c]
    assert [s.split("--variants ")[1].split()[0] for s in sweeps] == [v.label for v in GRIDS["decay"]]
    assert all(" sweep decay " in s for s in sweeps)
    bad, _ = _run(checkout, "--grid", "no-such-grid", "--seeds", "0")
    assert bad.returncode == 2 and "known grids are" in bad.stderr


def test_a_ship_waits_for_another_writers_index_lock(checkout: Path) -> None:
    """Two grid sessions (or a person committing) share the checkout: a ship that meets .git/index.lock waits for it
    to go instead of ending the session."""
    import threading
    import time

    lock = checkout / ".git" / "index.lock"
    lock.write_text("")
    threading.Timer(5.0, lock.unlink).start()  # the other writer finishes after 5 s
    t0 = time.monotonic()
    out, _ = _run(checkout, "--seeds", "4", "--variants", "npe", "--bundle-seed", "none")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "waits for another writer's index lock" in out.stderr and time.monotonic() - t0 >= 5.0
    log = _git(checkout, "log", "--format=%s").splitlines()
    assert log[0].startswith("table1 grid: seed 4, npe recorded")


def test_a_bundle_seed_packs_each_variant_into_the_parts_folder_named(checkout: Path) -> None:
    """--bundle-seed 3 --parts bundle-parts-seed3: each finished variant of seed 3 is packed into that folder (not
    the published bundle's bundle-parts), committed, then retired; a seed other than the bundle seed packs nothing."""
    out, calls = _run(checkout, "--seeds", "1,3", "--variants", "npe", "--bundle-seed", "3", "--parts",
                      "bundle-parts-seed3")  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    packs = [c.split("|", 1)[1] for c in calls if " --pack " in c]
    assert len(packs) == 1 and "--set seeds=[3]" in packs[0] and "--methods npe" in packs[0]
    assert packs[0].endswith("reference/quick/bundle-parts-seed3/npe")
    log = _git(checkout, "log", "--format=%s").splitlines()
    assert "reference bundle: part npe (seed 3) packed" in log
    assert "reference/quick/bundle-parts-seed3/npe/MANIFEST.json" in _git(checkout, "ls-files")
    assert not (checkout / "reference" / "quick" / "bundle-parts").exists()


def test_the_pages_are_not_rebuilt_while_the_library_has_uncommitted_edits(checkout: Path) -> None:
    """The pages are written by the checkout's code: with an uncommitted edit under omcrl/ they would be committed as
    that code renders them, ahead of the code itself. The ship is committed; the rebuild waits, with a line."""
    (checkout / "omcrl").mkdir()
    (checkout / "omcrl" / "why.py").write_text("old\n")
    _git(checkout, "add", "-A")
    _git(checkout, "commit", "-q", "-m", "library")
    (checkout / "omcrl" / "why.py").write_text("new, not committed\n")
    out, calls = _run(checkout, "--seeds", "4", "--variants", "npe", "--bundle-seed", "none")
    assert out.returncode == 0, out.stdout + out.stderr
    assert not any("summary --preset quick --readme" in c for c in calls)
    assert "the library has uncommitted edits: blocks not rebuilt" in out.stdout
    assert _git(checkout, "log", "--format=%s").splitlines()[0].startswith("table1 grid: seed 4, npe recorded")


def test_a_retrain_grid_packs_a_methods_weights_once_not_its_box_look_flights(checkout: Path) -> None:
    """Issue 75's retrain grid flies one run as two variants (``curl`` and ``curl box-look``): both are recorded and
    committed, and the seed's bundle part is packed for the method alone (the box-look variant has no weights of
    its own), into the folder --parts names."""
    out, calls = _run(checkout, "--grid", "table1-retrain", "--seeds", "0", "--variants", "curl,curl box-look",
                      "--bundle-seed", "0", "--parts", "bundle-parts-retrain-seed0")  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    packs = [c.split("|", 1)[1] for c in calls if " --pack " in c]
    assert len(packs) == 1 and "--methods curl --from" in packs[0] and "bundle-parts-retrain-seed0/curl" in packs[0]
    for v in ("curl", "curl box-look"):
        shown = _git(checkout, "show", f"HEAD:reference/quick/table1-retrain-v2/{v}/seed0/episodes.csv.gz")
        assert shown.split() == ["table1-retrain", *v.split(), "0"]
    assert (checkout / "reference/quick/bundle-parts-retrain-seed0/curl/runs.tar.xz.git.json").exists()


def test_ship_only_commits_what_a_stopped_stream_recorded_and_runs_nothing(checkout: Path) -> None:
    """--ship-only at a session's end: a variant longer than a session (the RL ladder's oracle, then its student)
    keeps its finished teacher when the stream is stopped; nothing is trained, and a running sweep is refused."""
    out, _ = _run(checkout, "--grid", "ladder-rl", "--seeds", "0", "--variants", "ours RL x3")
    assert out.returncode == 0, out.stdout + out.stderr
    wt = checkout.parent / "wt"
    teacher = wt / "reference/quick/ladder-rl-v2/oracle_RL_x3/seed1/rl"  # seed 1's teacher, finished when stopped
    teacher.mkdir(parents=True)
    (teacher / "run.json").write_text("{}\n")
    (teacher / "final.pt").write_bytes(b"weights")
    n_calls = len((checkout.parent / "calls.log").read_text().splitlines())
    out, calls = _run(checkout, "--grid", "ladder-rl", "--ship-only")
    assert out.returncode == 0, out.stdout + out.stderr
    assert not any(" sweep ladder-rl " in c and "--to-reference" in c for c in calls[n_calls:])  # nothing ran
    log = _git(checkout, "log", "--format=%s").splitlines()
    assert log[0] == ("ladder-rl grid: what the stream finished before it was stopped recorded "
                      "(reference/quick/ladder-rl-v2/: oracle_RL_x3/seed1)")  # fmt: skip
    assert "reference/quick/ladder-rl-v2/oracle_RL_x3/seed1/rl/final.pt" in _git(checkout, "ls-files")
    assert any("summary --preset quick --readme" in c for c in calls[n_calls:])

    stand_in = [sys.executable, "-c", "import time; time.sleep(30)", "-m", "omcrl", "sweep", "ladder-rl"]
    sweep = subprocess.Popen(stand_in, cwd=wt)
    try:  # a process whose command line is a sweep's, in the worktree: its records may be half written
        out, _ = _run(checkout, "--grid", "ladder-rl", "--ship-only")
    finally:
        sweep.kill()
    assert out.returncode == 2 and f"a sweep runs in {wt}" in out.stderr and f"kill -INT {sweep.pid}" in out.stderr
    missing, _ = _run(checkout, "--grid", "ladder-rl", "--ship-only", "--dir", str(checkout.parent / "none"))
    assert missing.returncode == 2 and "no worktree" in missing.stderr
