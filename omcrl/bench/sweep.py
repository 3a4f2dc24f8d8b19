"""``python -m omcrl.bench sweep``: the same sweep on an embedded Ray with 1 and with N CPUs, side by side.

Each case runs the grid from nothing (its own empty results folder, so no job is cached) with
``ray.init(num_cpus=k)``; jobs ask Ray for the CPUs they keep busy (:func:`omcrl.pipeline.sweep.job_cpus`), so
with one CPU they run one at a time and with more they overlap where dependencies and CPUs allow. Reported per case: the
sweep's wall time, the sum of its jobs' own times, and ``speedup`` = wall(1 CPU) / wall(k CPUs). The evaluation
rows of every case are compared with the first case's (``same_rows``): scaling must not change results.

Cases alternate over ``--rounds`` (1, N, 1, N, ...) so that whatever else the machine does weighs on both; the
wall time of a case is its median over rounds.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from omcrl.bench import parser, write_results
from omcrl.config import load_config
from omcrl.pipeline.sweep import run_sweep


def run_case(
    preset: str, grid: str, seeds: list[int], num_cpus: int, root: Path, overrides: Sequence[str] = ()
) -> tuple[float, float, pd.DataFrame]:
    """One sweep from an empty ``root`` on an embedded Ray of ``num_cpus``: (wall s, Σ job s, episodes)."""

    cfg = load_config(preset, overrides=[f"results_dir={root}", f"data.file={root}/data/box.h5", *overrides])
    res = run_sweep(cfg, grid, seeds, backend="ray", num_cpus=num_cpus, progress=False)
    if res.failed:
        raise RuntimeError(f"bench sweep: {res!r}")
    eps = res.episodes.sort_values(["label", "scene", "seed", "episode"]).reset_index(drop=True)
    return res.wall_s, float(sum(res.seconds.values())), eps


def _comparable(eps: pd.DataFrame) -> pd.DataFrame:
    """Episode rows without what names the case's own folder (checkpoint paths) or is not a result."""
    return eps.drop(columns=["trajectory", "checkpoint"], errors="ignore")


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("sweep", __doc__ or "")
    ap.add_argument("--preset", default="smoke", help="preset of the sweep (default: smoke)")
    ap.add_argument("--grid", default="smoke", help="grid to run (default: smoke)")
    ap.add_argument("--seeds", default="0,1", help="comma-separated seeds (default: 0,1)")
    ap.add_argument("--cpus", type=int, default=2, help="CPUs of the wider case (default: 2)")
    ap.add_argument("--rounds", type=int, default=1, help="rounds of (1 CPU, --cpus) cases (default: 1)")
    ap.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="config override for every case, e.g. --set rl.n_envs=1 (jobs that fit on one CPU)",
    )
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    rounds = 1 if args.quick else args.rounds
    walls: dict[int, list[float]] = {1: [], args.cpus: []}
    work: dict[int, list[float]] = {1: [], args.cpus: []}
    first: pd.DataFrame | None = None
    same = True
    with tempfile.TemporaryDirectory(prefix="omcrl-bench-sweep-") as tmp:
        for r in range(rounds):
            for k in (1, args.cpus):
                root = Path(tmp) / f"r{r}-cpu{k}"
                wall, jobs_s, eps = run_case(args.preset, args.grid, seeds, k, root, args.overrides)
                walls[k].append(wall)
                work[k].append(jobs_s)
                if first is None:
                    first = eps
                else:
                    same = same and _comparable(eps).equals(_comparable(first))
    base = float(np.median(walls[1]))
    rows = [
        {
            "case": f"embedded Ray, {k} CPU{'s' if k > 1 else ''}",
            "wall_s": float(np.median(walls[k])),
            "jobs_sum_s": float(np.median(work[k])),
            "speedup": base / float(np.median(walls[k])),
        }
        for k in (1, args.cpus)
    ]
    meta = {"preset": args.preset, "grid": args.grid, "seeds": seeds, "rounds": rounds, "same_rows": same}
    meta["overrides"] = args.overrides
    write_results("sweep", rows, args.out, **meta)
    print(f"# wall(1 CPU) / wall({args.cpus} CPUs) = {rows[1]['speedup']:.2f}; evaluation rows identical: {same}")
    return 0 if same else 1
