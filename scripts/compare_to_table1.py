"""Does a run flown on this machine reproduce Table I's recorded episodes? For a seed retrained from its recorded
config (the look attribution, issue 75) or a teacher restored from git history.

    python scripts/compare_to_table1.py ours 3 --eval ../omcrl-grid-look/results/quick/eval

For each cached own-look evaluation of ``<method>/seed<k>`` under ``--eval`` (the ``evaluate`` stage's cache: one
folder per scene, ``episodes.csv``; box-look flights are skipped), it matches the episodes to
``reference/<preset>/table1-v2/<method>/seed<k>/episodes.csv.gz`` layout by layout and prints SR both ways, the share
of layouts with the same success and collision outcome, and the largest difference in final distance (m). Exit
status 1 when any outcome differs, so a script can stop on it. Reads only; nothing is flown.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("method")
    ap.add_argument("seed", type=int)
    ap.add_argument("--eval", type=Path, required=True, help="an evaluation cache: results/<preset>/eval")
    ap.add_argument("--preset", default="quick")
    args = ap.parse_args()
    ref_file = ROOT / "reference" / args.preset / "table1-v2" / args.method / f"seed{args.seed}" / "episodes.csv.gz"
    if not ref_file.is_file():
        print(f"compare_to_table1: {ref_file}: no Table I record of {args.method} seed {args.seed}", file=sys.stderr)
        return 2
    ref = pd.read_csv(ref_file)
    folders = sorted(p for p in (args.eval / args.method / f"seed{args.seed}").glob("*") if p.is_dir())
    # A box-look flight's folder names the look after its scene ("barrier-v2-box-v2-<key>"): not Table I's.
    own = [p for p in folders if "-box-v2-" not in p.name and (p / "episodes.csv").is_file()]
    if not own:
        print(f"compare_to_table1: no own-look evaluation of {args.method} seed {args.seed} under {args.eval}",
              file=sys.stderr)  # fmt: skip
        return 2
    differs = False
    for folder in own:
        ep = pd.read_csv(folder / "episodes.csv")
        scene = ep["scene"].iloc[0]
        m = ep.merge(ref[ref["scene"] == scene], on="seed", suffixes=("", "_ref"))
        same = (m["success"] == m["success_ref"]) & (m["collision"] == m["collision_ref"])
        differs |= not bool(same.all())
        gap = (m["final_distance"] - m["final_distance_ref"]).abs().max()
        print(f"{args.method} seed {args.seed} {scene}: {len(m)} layouts matched, SR {100 * m['success'].mean():.0f} "
              f"here vs {100 * m['success_ref'].mean():.0f} recorded, same outcome {same.mean():.3f}, "
              f"max |final distance difference| {gap:.2e} m")  # fmt: skip
    return 1 if differs else 0


if __name__ == "__main__":
    sys.exit(main())
