"""A training grid's small data, kept in the repository as each run finishes: what Table I is rebuilt from.

Policies' weights do not travel (a policy file is ~11 MB); what does is enough to recompute every cell, interval,
verdict and learning curve without training anything::

    reference/<preset>/<grid>-<suite>/
        <label>/seed<k>/episodes.csv.gz     one row per evaluation episode (all scenes; trajectories left out)
        <label>/seed<k>/rl/                 the policy's run record: run.json, config.yaml, metrics.csv.gz
        <label>/seed<k>/rl/final.pt         a teacher's weights only (the oracle: other runs of the grid need it),
        <label>/seed<k>/rl/final.pt.git.json  or, once its students are recorded, where git history keeps them
        <label>/seed<k>/pretrain/           its encoder's run record (frozen-encoder methods): run.json, ...

A teacher's weights are the one exception to "records only": the oracle (~15 MB) takes longer to train than a
session lasts together with its students, so without its weights every session would retrain it before a student
could start (and a retrained teacher is only the same file where training is bit-for-bit reproducible). They stay in
the checkout only while a student of theirs is left to train: once every evaluation that needs a teacher is
recorded, :meth:`GridData.release_weights` replaces its ``final.pt`` by ``final.pt.git.json``, which names the file's
git blob. ``reference/`` must stay under 60 MB, and five seeds of oracles alone would be 73 MB. A later grid that
needs the same teacher (the budget ladder's students) still finds it: :meth:`GridData.restore_run` reads the blob
back from the repository's history, checked against the digest the run recorded.

``label`` is the variant's label (for ``table1``: the method name); planners are recorded once, under ``seed0``.
A sweep run with ``--to-reference`` (:func:`omcrl.pipeline.sweep.run_sweep`) writes these files after every
finished job and, on its next start, trains only the variants whose episodes are not there yet (a new machine
retrains the encoders those need, and lays a kept teacher out as its finished run folder).
"""

from __future__ import annotations

import gzip
import io
import re
import shutil
import time
from collections.abc import Iterable
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

from omcrl.config import Config, project_root
from omcrl.eval.stage import portable_checkpoint
from omcrl.eval.table1 import Table1Result, write_table1
from omcrl.eval.verdicts import write_verdicts
from omcrl.pipeline.reference import config_suite
from omcrl.pipeline.released import POINTER, available, read_kept, release
from omcrl.runs import (
    ArtifactMismatch,
    CorruptFile,
    Run,
    read_identity,
    read_metrics,
    training_seconds,
    verify_artifact,
)
from omcrl.utils.io import atomic_write_bytes, bytes_digest
from omcrl.viz import save_figure
from omcrl.viz.compare import curve_window, plot_learning_curves

EPISODES = "episodes.csv.gz"
# Small files of a run folder that are copied (CSV ones compressed); weights, checkpoints and event files are not.
RECORD_SUFFIXES = (".json", ".yaml", ".csv")
WEIGHTS = "final.pt"
# Released weights: a pointer to the git blob that holds them (GridData.release_weights).
WEIGHTS_POINTER = WEIGHTS + POINTER


def grid_data_dir(cfg: Config, grid: str) -> Path:
    """``<checkout>/reference/<preset>/<grid>-<suite>/`` for ``cfg``'s preset and scene suite."""

    return project_root() / "reference" / cfg.preset / f"{grid}-{config_suite(cfg)}"


def _gz(data: bytes) -> bytes:
    # mtime=0: the same rows give the same bytes, so a re-recorded file is not a change in git.
    buf = io.BytesIO()
    with gzip.GzipFile(fileobj=buf, mode="wb", mtime=0) as f:
        f.write(data)
    return buf.getvalue()


def _folder_name(label: str) -> str:
    name = re.sub(r"[^A-Za-z0-9.+-]+", "_", label).strip("_.")
    if not name:
        raise ValueError(f"grid label {label!r} gives no folder name")
    return name


class GridData:
    """The recorded data of one grid under ``root`` (:func:`grid_data_dir`).

    Parameters
    ----------
    root : the grid's folder; created on the first write.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def folder(self, label: str, seed: int) -> Path:
        """``<root>/<label>/seed<k>``, the label made a single safe folder name (``Ours w/o OT`` -> ``Ours_w_o_OT``;
        Table I's labels, method names, are kept as they are)."""
        return self.root / _folder_name(label) / f"seed{int(seed)}"

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
            rows = rows.assign(checkpoint=rows["checkpoint"].map(portable_checkpoint))
        atomic_write_bytes(path, _gz(rows.to_csv(index=False).encode()))
        return path

    def save_run(self, label: str, seed: int, stage: str, run_dir: str | Path) -> list[Path]:
        """Copy the small files of a finished run folder (``run.json``, ``config.yaml``, metrics as
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
            raise FileNotFoundError(f"{run_dir}: no run record (run.json, config.yaml, metrics.csv) to keep")
        return written

    def save_weights(self, label: str, seed: int, stage: str, run_dir: str | Path) -> Path:
        """Keep the finished run's ``final.pt`` beside its record (for a teacher that later runs need); it must match
        the digest its ``run.json`` recorded. Returns the file written."""
        src = Path(run_dir) / WEIGHTS
        verify_artifact(src, "teacher weights", "train the run again")
        dest = self.folder(label, seed) / stage / WEIGHTS
        dest.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(dest, src.read_bytes())
        return dest

    def has_weights(self, label: str, seed: int, stage: str) -> bool:
        """True when ``final.pt`` of ``label``'s ``stage`` run at ``seed`` is kept: in the checkout, or released and
        still in the repository's git objects."""
        src = self.folder(label, seed) / stage
        return available(src / WEIGHTS, f"delete {src} to train that run again")

    def kept_weights(self, label: str, seed: int, stage: str) -> bytes | None:
        """The bytes of ``label``'s kept ``stage`` weights at ``seed``: the file in the checkout, or the git blob its
        pointer names (:func:`omcrl.pipeline.released.read_kept`). None (with a warning naming the blob) when
        neither can be read, e.g. in a shallow clone.

        Raises :class:`omcrl.runs.CorruptFile` when the bytes do not match the digest the run recorded.
        """
        src = self.folder(label, seed) / stage
        where = src / WEIGHTS if (src / WEIGHTS).is_file() else src / WEIGHTS_POINTER
        data = read_kept(src / WEIGHTS, f"delete {src} to train that run again", "the teacher is trained again")
        if data is None:
            return None
        want = (read_identity(src) or {}).get("artifact_digest")
        got = bytes_digest(data)
        if want is not None and got != want:
            raise ArtifactMismatch(
                f"kept teacher weights {where} do not match the digest recorded when they were written "
                f"({got[:12]} vs {want[:12]}); delete {src} to train that run again"
            )
        return data

    def release_weights(self, label: str, seed: int, stage: str) -> Path | None:
        """Take ``label``'s kept ``stage`` weights at ``seed`` out of the checkout, leaving ``final.pt.git.json``
        (the git blob, its digest and size) in their place; returns the pointer written.

        Nothing happens (None) when no weights are in the checkout, or when they are not yet in a commit: the
        pointer must name a blob that git history keeps, so weights are released only after they were committed.
        """
        src = self.folder(label, seed) / stage
        if not (src / WEIGHTS).is_file():
            return None
        data = self.kept_weights(label, seed, stage)  # checked against the run's digest before anything changes
        return release(src / WEIGHTS, data)

    def restore_run(self, label: str, stage: str, run: Run) -> bool:
        """Lay ``label``'s kept ``stage`` run (record and weights) out as the finished folder of ``run``, so that
        training it is a skip. Nothing is written when ``run`` already holds a ``final.pt`` or no weights are kept
        (False).

        Raises :class:`omcrl.runs.CorruptFile` when the kept weights do not match the kept ``run.json``'s digest, or
        when that record is of another run (its key and seed), before anything is written.
        """
        src, dest = self.folder(label, run.seed) / stage, run.dir
        if (dest / WEIGHTS).exists():
            return False
        weights = self.kept_weights(label, run.seed, stage)
        if weights is None:
            return False
        rec = read_identity(src) or {}
        if rec.get("key") != run.key or rec.get("seed") != run.seed:
            raise CorruptFile(
                f"{src / 'run.json'}: records run key {rec.get('key')!r} seed {rec.get('seed')!r}, expected "
                f"{run.key!r} seed {run.seed!r} ({dest}); delete {src} to train that run again"
            )
        dest.mkdir(parents=True, exist_ok=True)
        for p in sorted(src.iterdir()):
            if p.name in (WEIGHTS, WEIGHTS_POINTER) or not p.is_file():
                continue
            data = p.read_bytes()
            name = p.name.removesuffix(".gz") if p.name.endswith(".csv.gz") else p.name
            atomic_write_bytes(dest / name, gzip.decompress(data) if name != p.name else data)
        # The weights last: a folder with final.pt is a finished run, so it must not appear before its record.
        atomic_write_bytes(dest / WEIGHTS, weights)
        return True

    def read_episodes(self, label: str, seed: int) -> pd.DataFrame:
        """The recorded episodes of ``label`` at training seed ``seed`` (FileNotFoundError when there are none)."""
        return pd.read_csv(self.folder(label, seed) / EPISODES)

    def episodes(self, labels: Iterable[str] | None = None) -> pd.DataFrame:
        """Every recorded episode (of ``labels`` when given), with ``label`` and ``train_seed`` columns as recorded;
        an empty frame when nothing is recorded."""
        want = None if labels is None else {_folder_name(x) for x in labels}
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

    def account(self) -> pd.DataFrame:
        """How the recorded runs were trained: one row per run record (``<label>/seed<k>/<stage>/run.json``).

        Columns: ``label, seed, stage`` (``pretrain`` or ``rl``), ``method, key, artifact`` (the digest of what it
        wrote), ``encoder, oracle`` (digests of the encoder and teacher it was made of; None where it has none),
        ``dataset`` (a pretraining's dataset fingerprint), ``segments`` (stretches of RL training: 1, plus one per
        resume; NaN for runs recorded before runs kept them), ``cpu`` (the ``cpu_capability`` of each machine that
        trained a part of it, joined; ``""`` where not recorded) and ``train_s`` (seconds of rollout and update an
        RL run's metrics logged, start-up and evaluation left out; NaN for pretraining). An encoder serving several
        labels is a row under each.
        """
        rows = []
        for rec in sorted(self.root.glob("*/seed*/*/run.json")):
            run = read_identity(rec.parent) or {}
            ident = run.get("identity") or {}
            stage = rec.parent.name
            train_s = float("nan")
            if stage == "rl" and (rec.parent / "metrics.csv.gz").is_file():
                train_s = training_seconds(read_metrics(rec.parent / "metrics.csv.gz"))
            rows.append({
                "label": rec.parents[2].name, "seed": int(rec.parents[1].name.removeprefix("seed")), "stage": stage,
                "method": run.get("method"), "key": run.get("key"), "artifact": run.get("artifact_digest"),
                "encoder": ident.get("encoder_digest") or None, "oracle": ident.get("oracle_digest") or None,
                "dataset": run.get("dataset_fingerprint"),
                "segments": len(run["segments"]) if "segments" in run else float("nan"),
                "cpu": ",".join(sorted({str(x.get("cpu_capability")) for x in run.get("machines") or []})),
                "train_s": train_s,
            })  # fmt: skip
        return pd.DataFrame(rows)

    def progress(self, labels: Iterable[str], seeds: Iterable[int]) -> pd.DataFrame:
        """``(label × seed)`` booleans: which evaluations are recorded (the grid's progress)."""
        seeds = list(seeds)
        return pd.DataFrame(
            [[self.has_episodes(lab, s) for s in seeds] for lab in labels],
            index=list(labels),
            columns=[f"seed {s}" for s in seeds],
        )

    def seeds(self) -> list[int]:
        """The training seeds something is recorded for."""
        return sorted({int(p.name.removeprefix("seed")) for p in self.root.glob("*/seed*") if p.name[4:].isdigit()})

    def remove(self, label: str, seed: int) -> None:
        """Forget what is recorded for ``label`` at ``seed`` (it is then trained and evaluated again)."""
        shutil.rmtree(self.folder(label, seed), ignore_errors=True)


def find_kept_run(grids_dir: str | Path, run: Run, stage: str = "rl") -> tuple[GridData, str] | None:
    """The grid record under ``grids_dir`` (``reference/<preset>/``, every grid and suite) that keeps ``run``'s
    weights, and the label it keeps them under; None when none does.

    A run is the same run wherever it is recorded: its key and seed decide (the Table I grid's oracle is also the
    teacher of the budget ladder's students, which the ladder's own record does not keep).
    """
    for rec in sorted(Path(grids_dir).glob(f"*/*/seed{int(run.seed)}/{stage}/run.json")):
        ident = read_identity(rec.parent) or {}
        if ident.get("key") != run.key or ident.get("seed") != run.seed:
            continue
        grid, label = GridData(rec.parents[3]), rec.parents[2].name
        if grid.has_weights(label, run.seed, stage):
            return grid, label
    return None


def tables_from_reference(cfg: Config, grid: str = "table1", reps: int = 2000) -> Table1Result:
    """Table I, the claim ledger's verdicts and Fig. 5 from the grid's data in the checkout alone (nothing trained
    or flown): writes ``tables/table1.*`` and ``tables/ledger_verdicts.*`` under ``cfg.run_root`` and
    ``figures/fig5_training_curves.png``; returns the :class:`omcrl.eval.table1.Table1Result`. Another grid of
    Table I's runs (``table1-confirm``: other layouts) writes its tables to ``tables/<grid>/``; it records no
    training, so its ledger judges the evaluation hypotheses alone (the training rows are ``not run``) and it has
    no Fig. 5.

    FileNotFoundError when the grid has no recorded episodes.
    """

    t0 = time.perf_counter()
    data = GridData(grid_data_dir(cfg, grid))
    episodes = data.episodes()
    if episodes.empty:
        raise FileNotFoundError(
            f"{data.root}: no recorded episodes; run python -m omcrl sweep {grid} --preset {cfg.preset} "
            "--to-reference (or commit its data) first"
        )
    out = cfg.run_root / "tables" if grid == "table1" else cfg.run_root / "tables" / grid
    table, sig, paths = write_table1(episodes, out, os_threshold=cfg.eval.success_threshold_os, reps=reps)
    runs = data.metrics("rl")
    verdicts, vpaths = write_verdicts(episodes, runs, out, config_suite(cfg), reps)
    if runs:
        # As notebook 07 draws it: every learned method's curves, the same smoothing.
        fig = plot_learning_curves(runs, window=curve_window(cfg.rl.total_steps, cfg.rl.buffer_size))
        paths["fig5"] = save_figure(fig, cfg.run_root / "figures", "fig5_training_curves")
        plt.close(fig)
    return Table1Result(episodes, table, sig, [], paths | vpaths, time.perf_counter() - t0, verdicts)
