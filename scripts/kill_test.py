"""Kill -9 at random moments of each stage, rerun until it finishes, and compare with an uninterrupted run.

    python scripts/kill_test.py [--stages collect,pretrain,oracle,student,evaluate] [--kills 10] [--seed 0]
                                [--work DIR] [--json FILE]

For each stage, with the smoke preset (RL stages at 2,048 env steps, checkpoints every 256):

1. reference: the stage runs once, uninterrupted, in ``<work>/ref``;
2. killed: the same stage starts in ``<work>/kill`` and gets SIGKILL at a random moment (uniform over 15-90%
   of the reference's wall time, scaled by the share of the work not yet durable, read from the run's own
   files, at least 25%), again and again until a run finishes first; then it is run to completion and
   compared. Rounds repeat from a fresh start until ``--kills`` kills have landed;
3. compare: what the stage promises.

What each stage promises after kills:

* ``collect``: every finished episode survives and the rerun appends until the file has ``data.episodes``;
  appended episodes get new layouts, so the file is not bit-identical to an uninterrupted one.
* ``pretrain``: bit-identical encoder weights (model, optimiser and every RNG state are checkpointed).
* ``oracle`` / ``student``: the same final env-step count; not bit-identical when a kill landed after the first
  checkpoint (the vector env is re-created and reseeded on resume).
* ``evaluate``: bit-identical tables (each (method, scene) evaluation is deterministic and cached atomically).

Prerequisites of a stage (data, encoder, oracle, policies) are the reference's, copied, so only the stage
under test is interrupted.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STAGES = ("collect", "pretrain", "oracle", "student", "evaluate")
RL = ["rl.total_steps=2048", "rl.checkpoint_every=256"]


def _overrides(base: Path) -> list[str]:
    sets = [f"results_dir={base}/results", f"data.file={base}/data/box.h5", "data.episodes=40", *RL]
    return [x for s in sets for x in ("--set", s)]


def _cmd(stage: str, base: Path) -> list[str]:
    return [sys.executable, "-m", "omcrl", stage, "--preset", "smoke", *_overrides(base)]


def _run(stage: str, base: Path) -> tuple[int, float]:
    t0 = time.perf_counter()
    r = subprocess.run(_cmd(stage, base), cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{stage} in {base} failed (exit {r.returncode}):\n{r.stderr[-3000:]}")
    return r.returncode, time.perf_counter() - t0


def _kill_at(stage: str, base: Path, after: float) -> bool:
    """Start the stage, SIGKILL it ``after`` s later; True when it was killed (False: it finished first)."""
    p = subprocess.Popen(_cmd(stage, base), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        p.wait(timeout=after)
        return False
    except subprocess.TimeoutExpired:
        p.send_signal(signal.SIGKILL)
        p.wait()
        return True


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def _one(pattern: str, base: Path) -> Path:
    found = sorted(base.glob(pattern))
    if len(found) != 1:
        raise RuntimeError(f"expected one {pattern} under {base}, found {[str(f) for f in found]}")
    return found[0]


def _outcome(stage: str, base: Path) -> dict:
    """What to compare for ``stage`` in the run under ``base``."""
    import torch

    from omcrl.data import open_dataset

    res = base / "results" / "smoke"
    if stage == "collect":
        with open_dataset(base / "data" / "box.h5") as ds:
            return {"episodes": len(ds), "steps": int(ds.episode_lengths.sum())}
    if stage == "pretrain":
        enc = torch.load(_one("runs/pretrain/omc-*/seed0/encoder.pt", res), weights_only=True)
        h = hashlib.sha256()
        for part in ("f", "phi"):
            for k in sorted(enc[part]):
                h.update(enc[part][k].numpy().tobytes())
        return {"weights": h.hexdigest()[:16]}
    if stage in ("oracle", "student"):
        name = "oracle" if stage == "oracle" else "ours"
        final = torch.load(_one(f"runs/rl/{name}-[0-9a-f]*/seed0/final.pt", res), weights_only=True)
        h = hashlib.sha256()
        for k in sorted(final["model"]):
            h.update(final["model"][k].numpy().tobytes())
        return {"step": int(final["step"]), "weights": h.hexdigest()[:16]}
    return {"table": _digest(res / "tables" / "table1.csv")}


def _fraction_left(stage: str, base: Path, ref: Path) -> float:
    """Share of the stage's work not yet durable in ``base`` (from its own files: episodes, checkpoints, caches)."""
    import torch

    res = base / "results" / "smoke"
    if stage == "collect":
        from omcrl.data import open_dataset

        f = base / "data" / "box.h5"
        if not f.exists():
            return 1.0
        with open_dataset(f) as ds:
            return 1.0 - len(ds) / 40
    if stage in ("pretrain", "oracle", "student"):
        pattern = {"pretrain": "runs/pretrain/omc-*/seed0", "oracle": "runs/rl/oracle-*/seed0"}.get(
            stage, "runs/rl/ours-[0-9a-f]*/seed0"
        )
        runs = sorted(res.glob(pattern))
        if not runs:
            return 1.0
        if (runs[0] / ("encoder.pt" if stage == "pretrain" else "final.pt")).exists():
            return 0.0
        ck = runs[0] / "checkpoint.pt"
        if not ck.exists():
            return 1.0
        total = 20 if stage == "pretrain" else 2048  # smoke iterations / RL steps
        return 1.0 - int(torch.load(ck, weights_only=True)["step"]) / total
    want = len(list((ref / "results" / "smoke" / "eval").glob("*/seed0/*/episodes.csv")))
    have = len(list((res / "eval").glob("*/seed0/*/episodes.csv")))
    return 1.0 - have / max(want, 1)


PREREQS = {"collect": [], "pretrain": ["collect"], "oracle": [], "student": ["collect", "pretrain", "oracle"]}
PREREQS["evaluate"] = ["collect", "pretrain", "oracle", "student"]


def kill_test(stages: list[str], kills: int, seed: int, work: Path) -> list[dict]:
    rng = random.Random(seed)
    ref, kill = work / "ref", work / "kill"
    rows = []
    done: set[str] = set()
    for stage in stages:
        for pre in PREREQS[stage]:  # the reference's prerequisites, once
            if pre not in done:
                _run(pre, ref)
                done.add(pre)
        _, wall = _run(stage, ref)
        done.add(stage)
        want = _outcome(stage, ref)
        landed, rounds, results = 0, 0, []
        while landed < kills and rounds < 8:
            rounds += 1
            # Start from the reference's prerequisites only: its data and runs, less the run under test.
            shutil.rmtree(kill, ignore_errors=True)
            if PREREQS[stage]:
                shutil.copytree(ref / "data", kill / "data")
                shutil.copytree(ref / "results" / "smoke" / "runs", kill / "results" / "smoke" / "runs")
                under_test = {"pretrain": "pretrain/*", "student": "rl/ours-[0-9a-f]*"}.get(stage)
                for d in (kill / "results" / "smoke" / "runs").glob(under_test or "__none__"):
                    shutil.rmtree(d)
            while landed < kills:
                # A random moment of the work that is left: each resume starts further on.
                left = max(_fraction_left(stage, kill, ref), 0.25)
                if not _kill_at(stage, kill, rng.uniform(0.15, 0.9) * wall * left):
                    break  # it finished first: this round is over
                landed += 1
            _run(stage, kill)
            results.append(_outcome(stage, kill))
        got = results[-1]
        same = all(r == want for r in results)
        if stage == "collect":
            promise = all(r["episodes"] == want["episodes"] for r in results)
        elif stage in ("oracle", "student"):
            promise = all(r["step"] == want["step"] for r in results)
        else:  # pretrain, evaluate: bit-identical
            promise = same
        rows.append(
            {
                "stage": stage,
                "kills": landed,
                "rounds": rounds,
                "reference_wall_s": round(wall, 1),
                "reference": want,
                "after_kills": got,
                "bit_identical": same,
                "promise_held": promise,
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stages", default=",".join(STAGES))
    ap.add_argument("--kills", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", default=None, help="working folder (default: a temporary one)")
    ap.add_argument("--json", default=None, help="write the rows here")
    args = ap.parse_args(argv)
    stages = [s for s in args.stages.split(",") if s]
    bad = [s for s in stages if s not in STAGES]
    if bad:
        ap.error(f"unknown stages {bad}; known: {list(STAGES)}")
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work) if args.work else Path(tmp)
        rows = kill_test(stages, args.kills, args.seed, work)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0 if all(r["promise_held"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
