"""A training grid's small data, kept in the repository as each run finishes: what Table I is rebuilt from.

Weights do not travel (an RL checkpoint is ~15 MB); what does is enough to recompute every cell, interval,
verdict and learning curve without training anything::

    reference/<preset>/<grid>-<suite>/
        <label>/seed<k>/episodes.csv.gz     one row per evaluation episode (all scenes; trajectories left out)
        <label>/seed<k>/rl/                 the policy's run record: run.json, config.yaml, metrics.csv.gz
        <label>/seed<k>/pretrain/           its encoder's run record (frozen-encoder methods): done.json, ...

``label`` is the variant's label (for ``table1``: the method name); planners are recorded once, under ``seed0``.
A sweep run with ``--to-reference`` (:func:`omcrl.pipeline.sweep.run_sweep`) writes these files after every
finished job and, on its next start, trains only the variants whose episodes are not there yet (a new machine
retrains the upstream runs those need: their weights were not kept).
"""

from __future__ import annotations

import gzip
import io
import shutil
from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from omcrl.config import Config, project_root
from omcrl.utils.io import atomic_write_bytes

EPISODES = "episodes.csv.gz"
# Small files of a run folder that are copied (CSV ones compressed); weights, checkpoints and event files are not.
RECORD_SUFFIXES = (".json", ".yaml", ".csv")


def grid_data_dir(cfg: Config, grid: str) -> Path:
    """``<checkout>/reference/<preset>/<grid>-<suite>/`` for ``cfg``'s preset and scene suite."""
    from omcrl.pipeline.reference import config_suite

    return project_root() / "reference" / cfg.preset / f"{grid}-{config_suite(cfg)}"


def _gz(data: bytes) -> bytes:
    # mtime=0: the same rows give the same bytes, so a re-recorded file is not a change in git.
    buf = io.BytesIO()
    with gzip.GzipFile(fileobj=buf, mode="wb", mtime=0) as f:
        f.write(data)
    return buf.getvalue()


def _portable(checkpoint: object) -> object:
    if not isinstance(checkpoint, str) or "/" not in checkpoint:
        return checkpoint
    p = Path(checkpoint)
    return f"{p.parent.parent.name}/{p.parent.name}"


class GridData:
    """The recorded data of one grid under ``root`` (:func:`grid_data_dir`).

    Parameters
    ----------
    root : the grid's folder; created on the first write.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def folder(self, label: str, seed: int) -> Path:
        return self.root / label / f"seed{int(seed)}"

    def has_episodes(self, label: str, seed: int) -> bool:
        """True when the evaluation episodes of ``label`` at training seed ``seed`` are recorded."""
        return (self.folder(label, seed) / EPISODES).is_file()

    def save_episodes(self, label: str, seed: int, episodes: pd.DataFrame) -> Path:
        """Record ``episodes`` (one row per episode, any columns but ``trajectory``) atomically; returns the file."""
        path = self.folder(label, seed) / EPISODES
        path.parent.mkdir(parents=True, exist_ok=True)
        rows = episodes.drop(columns=["trajectory"], errors="ignore")
        if "checkpoint" in rows:
            # A policy's path names this machine's results folder; its run folder (<method>-<key>/seed<k>) does not.
            rows = rows.assign(checkpoint=rows["checkpoint"].map(_portable))
        atomic_write_bytes(path, _gz(rows.to_csv(index=False).encode()))
        return path

    def save_run(self, label: str, seed: int, stage: str, run_dir: str | Path) -> list[Path]:
        """Copy the small files of a finished run folder (``run.json``, ``done.json``, ``config.yaml``, metrics as
        ``.csv.gz``) under ``<label>/seed<k>/<stage>/``; returns the files written."""
        run_dir = Path(run_dir)
        out = self.folder(label, seed) / stage
        out.mkdir(parents=True, exist_ok=True)
        written = []
        for p in sorted(run_dir.iterdir()):
            if not p.is_file() or p.suffix not in RECORD_SUFFIXES:
                continue
            data = p.read_bytes()
            dest = out / (p.name + ".gz" if p.suffix == ".csv" else p.name)
            atomic_write_bytes(dest, _gz(data) if p.suffix == ".csv" else data)
            written.append(dest)
        if not written:
            raise FileNotFoundError(f"{run_dir}: no run record (run.json, done.json, config.yaml, metrics.csv) to keep")
        return written

    def episodes(self, labels: Iterable[str] | None = None) -> pd.DataFrame:
        """Every recorded episode (of ``labels`` when given), with ``label`` and ``train_seed`` columns as recorded;
        an empty frame when nothing is recorded."""
        want = None if labels is None else set(labels)
        frames = []
        for p in sorted(self.root.glob(f"*/seed*/{EPISODES}")):
            if want is None or p.parent.parent.name in want:
                frames.append(pd.read_csv(p))
        return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()

    def metrics(self, stage: str = "rl") -> dict[str, dict[int, Path]]:
        """``{label: {seed: metrics.csv.gz}}`` of the recorded runs of ``stage`` (learning curves)."""
        out: dict[str, dict[int, Path]] = {}
        for p in sorted(self.root.glob(f"*/seed*/{stage}/metrics.csv.gz")):
            label, seed = p.parent.parent.parent.name, int(p.parent.parent.name.removeprefix("seed"))
            out.setdefault(label, {})[seed] = p
        return out

    def remove(self, label: str, seed: int) -> None:
        """Forget what is recorded for ``label`` at ``seed`` (it is then trained and evaluated again)."""
        shutil.rmtree(self.folder(label, seed), ignore_errors=True)
