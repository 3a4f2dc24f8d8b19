"""Digests of what a chain produced, independent of where it put it: for before/after proofs of refactors.

    python scripts/chain_digests.py RESULTS_ROOT DATA_FILE [--json OUT]

RESULTS_ROOT is ``<results_dir>/<preset>``. Printed (and written with ``--json``), per artifact kind and method:

* ``data``: SHA-256 of every dataset array in the HDF5 file (frames, actions, states, ...), not of the file, whose
  bytes carry write times;
* ``encoder/<name>``, ``policy/<method>``: SHA-256 of every tensor of the artifact's weights (``weights_only``
  load), not of the file, which records its run's key and paths;
* ``episodes/<method>``: SHA-256 of the cached evaluation rows less the checkpoint path column.

Run folder names (run keys) are deliberately left out: a change of identity moves them and must not hide or fake a
change of results.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import sys
from pathlib import Path


def _tensors(obj, prefix: str = "") -> dict[str, str]:
    import torch

    out: dict[str, str] = {}
    if isinstance(obj, torch.Tensor):
        out[prefix] = hashlib.sha256(obj.detach().cpu().contiguous().numpy().tobytes()).hexdigest()[:16]
    elif isinstance(obj, dict):
        for k in sorted(obj, key=str):
            out.update(_tensors(obj[k], f"{prefix}/{k}"))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            out.update(_tensors(v, f"{prefix}/{i}"))
    return out


def _weights(path: Path) -> str:
    import torch

    t = _tensors(torch.load(path, map_location="cpu", weights_only=True))
    return hashlib.sha256(json.dumps(t, sort_keys=True).encode()).hexdigest()[:16] + f" ({len(t)} tensors)"


def _data(path: Path) -> str:
    import h5py

    parts = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            parts.append(f"{name}:{hashlib.sha256(obj[()].tobytes()).hexdigest()}")

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return hashlib.sha256("\n".join(sorted(parts)).encode()).hexdigest()[:16] + f" ({len(parts)} arrays)"


def _episodes(folder: Path) -> str:
    import pandas as pd

    rows = []
    # A cached evaluation is a run folder <scene>-<key>/episodes.csv; <scene>-<key>.csv was the layout before, read
    # too so that digests from either side of that change compare.
    for csv in sorted([*folder.glob("*.csv"), *folder.glob("*/episodes.csv")]):
        df = pd.read_csv(csv).drop(columns=["checkpoint"], errors="ignore")
        buf = io.StringIO()
        df.to_csv(buf, index=False)
        name = csv.parent.name if csv.name == "episodes.csv" else csv.stem
        rows.append(name.rsplit("-", 1)[0] + ":" + hashlib.sha256(buf.getvalue().encode()).hexdigest())
    # Sorted by scene, not by folder: the folders' keys carry the policy file's digest, whose meta holds the
    # results folder's path, so the same episodes under another root would otherwise hash in another order.
    return hashlib.sha256("\n".join(sorted(rows)).encode()).hexdigest()[:16] + f" ({len(rows)} scenes)"


def digests(root: Path, data: Path) -> dict[str, str]:
    out = {"data": _data(data)}
    for enc in sorted(root.glob("runs/pretrain/*/seed*/encoder.pt")):
        out[f"encoder/{enc.parts[-3].rsplit('-', 1)[0]}/{enc.parts[-2]}"] = _weights(enc)
    for pol in sorted(root.glob("runs/rl/*/seed*/final.pt")):
        out[f"policy/{pol.parts[-3].rsplit('-', 1)[0]}/{pol.parts[-2]}"] = _weights(pol)
    for folder in sorted(p for p in root.glob("eval/*/seed*") if p.is_dir()):
        out[f"episodes/{folder.parts[-2]}/{folder.parts[-1]}"] = _episodes(folder)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("root", type=Path)
    ap.add_argument("data", type=Path)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    d = digests(a.root, a.data)
    for k, v in d.items():
        print(f"{k:40s} {v}")
    if a.json:
        a.json.write_text(json.dumps(d, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
