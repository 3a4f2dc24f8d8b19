"""One home for runs: naming, identity keys, skip-if-finished / resume, checkpoints and the finished artifact
(:class:`Run`), metrics I/O, the training hooks (:class:`Callback`) and RNG state.

Every stage that trains something (pretraining, the oracle, each RL method) writes one *run*::

    <run_root>/runs/<stage>/<method>-<key>/seed<k>/
        run.json        identity: stage, method, seed, key and the identity dict the key hashes
        config.yaml     the resolved config (omcrl.config.save_config)
        metrics.csv     tidy rows step,metric,value (MetricsLog writes, read_metrics reads)
        ...             the stage's checkpoints and artifacts

A run is identified by its **method**, its **identity** (every config field and upstream artifact digest that
changes what is trained, nothing else) and its **seed**. The folder name carries a short hash of the identity,
so two different configurations never share a folder, and the same configuration always finds its run again:
a finished run is skipped, an interrupted one resumes from its last checkpoint. ``run.json`` is checked on
every open, so even a hash collision or a hand-copied folder cannot make one configuration reuse another's
run (:class:`RunConfigMismatch`).

RNG states are stored as tensors and plain containers, so checkpoints load with ``weights_only=True``.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import math
import random
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from omcrl.config import Config, config_hash, save_config
from omcrl.utils.io import atomic_save_torch, atomic_write_text, file_digest, load_torch
from omcrl.utils.progress import Progress
from omcrl.utils.runtime import machine_info

RUN_FILE = "run.json"
CHECKPOINT = "checkpoint.pt"

# The behaviour version of each component whose code decides results. A change that alters what a component
# computes (trained weights, collected frames, episode outcomes) bumps its number in the same commit: every run and
# cached evaluation that depends on it then has a new key and is made again instead of being reused stale.
BEHAVIOUR: dict[str, int] = {
    "env": 1,  # omcrl.envs and omcrl.scenes: flight model, scenes, rewards, rendering, episode seeds
    "data": 1,  # omcrl.data: the collection pilots and what a dataset stores
    "pretrain": 1,  # omcrl.pretrain and the encoder networks of omcrl.models: objectives, sampler, augmentation
    "rl": 1,  # omcrl.rl and the policy networks of omcrl.models: PPO, rollouts, guidance, features, inference
    "planners": 1,  # omcrl.planners: the APF planners and pilots (guides and planner methods)
    "eval": 1,  # omcrl.eval: the evaluation loop and its per-episode metrics
}
# The components each kind of artifact depends on (a student's upstream encoder and oracle enter by digest).
DEPENDS: dict[str, tuple[str, ...]] = {
    "pretrain": ("env", "data", "pretrain"),
    "rl": ("env", "planners", "rl"),
    "eval-policy": ("env", "rl", "eval"),
    "eval-planner": ("env", "planners", "eval"),
}


def behaviour(kind: str) -> dict[str, int]:
    """``{component: version}`` of the components an artifact of ``kind`` (a key of :data:`DEPENDS`) depends on."""
    if kind not in DEPENDS:
        raise KeyError(f"behaviour: unknown kind {kind!r}, expected one of {list(DEPENDS)}")
    return {c: BEHAVIOUR[c] for c in DEPENDS[kind]}


class RunConfigMismatch(RuntimeError):
    """A run folder holds a run of a different identity (configuration, method or seed)."""


class RunLocked(RuntimeError):
    """Another live process is training this run folder; the message names its PID."""


class CorruptFile(ValueError):
    """A file the kit wrote cannot be read back (damaged, truncated, emptied); the message names it."""


class ArtifactMismatch(CorruptFile):
    """A file does not match the digest its producer recorded: it was changed or damaged after it was written."""


# Where a producer records the digest of each artifact it writes (file name -> (record file, field)).
DIGEST_FIELDS = {
    "final.pt": ("run.json", "artifact_digest"),
    "checkpoint.pt": ("run.json", "checkpoint_digests"),
    "encoder.pt": ("run.json", "artifact_digest"),
    "config.yaml": ("run.json", "config_digest"),
    "episodes.csv": ("run.json", "artifact_digest"),
}


def recorded_digest(path: str | Path) -> str | None:
    """The digest recorded for ``path`` by the run that wrote it (:data:`DIGEST_FIELDS`), or None when there
    is none (a file from outside a run, or a run written before digests were kept)."""
    p = Path(path)
    where = DIGEST_FIELDS.get(p.name)
    if where is None:
        return None
    rec = p.parent / where[0]
    try:
        value = json.loads(rec.read_text(encoding="utf-8")).get(where[1]) if rec.is_file() else None
    except (OSError, ValueError, AttributeError):
        raise ArtifactMismatch(f"{rec} cannot be read (not JSON); it records the digest of {p}") from None
    if isinstance(value, list):  # checkpoints: the digests of the last two writes (a kill can fall between)
        return ",".join(str(v) for v in value)
    return value if isinstance(value, str) else None


def verify_artifact(path: str | Path, what: str, remedy: str) -> None:
    """Raise :class:`ArtifactMismatch` (one line: the file, the stage to re-run) when ``path`` does not match the
    digest recorded when it was written; nothing when it matches or no digest was recorded."""

    want = recorded_digest(path)
    if want is None:
        return
    got = file_digest(Path(path))
    if got not in want.split(","):
        raise ArtifactMismatch(
            f"{what} {path} does not match the digest recorded when it was written ({got[:12]} vs {want[:12]}): it "
            f"was changed or damaged; {remedy}"
        )


def rerun_command(run_dir: str | Path, stage: str) -> str:
    """``re-run: python -m omcrl <stage> ...`` for the run folder ``<root>/<preset>/runs/<kind>/<name>/seed<k>``."""
    d = Path(run_dir)
    preset = d.parents[3].name if len(d.parents) > 3 else "<preset>"
    rec = read_identity(d) or {}
    method = rec.get("method", "<method>")
    seed = rec.get("seed", d.name.removeprefix("seed"))
    return f"re-run: python -m omcrl {stage} --method {method} --preset {preset} --seed {seed}"


# Locks this process holds: lock-file path -> open file (an flock lasts as long as the file stays open, and the
# kernel drops it when the holder dies, so the lock of a killed process is never stale).
_LOCKS: dict[Path, Any] = {}


def _lock_path(run_dir: Path) -> Path:
    # Beside the folder, not in it: ``overwrite`` deletes the folder and must not delete a live holder's lock.
    return run_dir.with_name(run_dir.name + ".lock")


def acquire_lock(run_dir: Path, what: str = "run folder") -> None:
    """Hold an exclusive lock on ``run_dir`` for this process (re-entrant); raise :class:`RunLocked` naming the
    holder's PID when another live process holds it. A lock left by a dead process is taken over."""
    import fcntl
    import os

    path = _lock_path(Path(run_dir))
    if path in _LOCKS:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fh = open(path, "a+", encoding="utf-8")  # held open for as long as the lock
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        holder = fh.read().strip() or "unknown"
        fh.close()
        raise RunLocked(
            f"{what} {run_dir} is in use by another process (PID {holder}); wait for it to finish or stop it"
        ) from None
    fh.seek(0)
    fh.truncate()
    fh.write(str(os.getpid()))
    fh.flush()
    _LOCKS[path] = fh


def release_lock(run_dir: Path) -> None:
    """Release this process's lock on ``run_dir`` (no-op when it holds none)."""
    fh = _LOCKS.pop(_lock_path(Path(run_dir)), None)
    if fh is not None:
        fh.close()


@dataclass(frozen=True)
class Run:
    """One run: where it lives and what it is.

    Attributes
    ----------
    stage : ``pretrain``, ``oracle``, ``student``, ...
    method : the method or pretraining-variant name (``ours``, ``curl``, ``omc-rho0.3``, ...).
    seed : the training seed.
    key : 10-hex-digit hash of ``identity``.
    identity : JSON-able dict of everything that changes the trained artifact.
    dir : ``<run_root>/runs/<stage>/<method>-<key>/seed<seed>``.
    """

    stage: str
    method: str
    seed: int
    key: str
    identity: dict
    dir: Path

    @property
    def metrics_path(self) -> Path:
        return self.dir / "metrics.csv"

    def claim(self, overwrite: bool = False) -> None:
        """Lock the folder for this process, create it and write ``run.json``; raise :class:`RunLocked` when
        another live process trains it, RunConfigMismatch if it holds another run.

        ``overwrite`` deletes a folder of a different identity instead of raising. The lock is held until
        :meth:`release` (or the end of the process).
        """
        acquire_lock(self.dir)
        found = read_identity(self.dir)
        if found is not None and found.get("key") != self.key:
            if not overwrite:
                raise RunConfigMismatch(
                    f"run folder {self.dir} holds a run with key {found.get('key')}, this configuration has key "
                    f"{self.key}; delete the folder or pass overwrite=True"
                )
            import shutil

            shutil.rmtree(self.dir)
            found = None
        self.dir.mkdir(parents=True, exist_ok=True)
        if found is None:
            record = {"stage": self.stage, "method": self.method, "seed": self.seed, "key": self.key}
            atomic_write_text(self.dir / RUN_FILE, json.dumps({**record, "identity": self.identity}, indent=1))
        # Same seed, same result holds per machine and torch build (omcrl.utils.runtime.machine_info): every
        # machine that trained a part of this run is kept, so a result that differs can be traced to its host.
        here = machine_info()
        machines = (found or {}).get("machines") or []
        if not machines or machines[-1] != here:
            self.record(machines=[*machines, here])

    def write_config(self, cfg: Config) -> Path:
        """Write the resolved ``cfg`` as the run's ``config.yaml`` (:func:`omcrl.config.save_config`) and record its
        digest in ``run.json``, so a reader of the file (the ONNX export) refuses it when it was damaged: a
        truncated YAML file can still parse, its missing fields then silently taking their defaults."""
        path = save_config(cfg, self.dir)
        self.record(config_digest=file_digest(path))
        return path

    def checkpoint_recorder(self) -> Any:
        """``before_replace`` for :func:`~omcrl.utils.io.atomic_save_torch` of ``checkpoint.pt``: records the new
        digest beside the previous one before the file is replaced, so a resume can verify it."""

        def record(digest: str) -> None:
            prev = (read_identity(self.dir) or {}).get("checkpoint_digests") or []
            self.record(checkpoint_digests=[*prev[-1:], digest])

        return record

    @property
    def checkpoint_path(self) -> Path:
        return self.dir / CHECKPOINT

    def finished(self, artifact: str = "final.pt", again: str = "training this run again") -> Path | None:
        """The run's finished ``artifact`` when it is there and matches the digest ``run.json`` recorded (or none
        was recorded), else None. A finished artifact that changed since it was written is not trusted: it is moved
        aside (``<name>.corrupt``, with a warning ending in ``again``) so that the run is made again."""
        path = self.dir / artifact
        if not path.exists():
            return None
        if self.verified(path) is not False:
            return path
        aside = path.with_name(f"{artifact}.corrupt")
        path.replace(aside)
        warnings.warn(
            f"{path} does not match the digest recorded when it was written (damaged or changed; moved to "
            f"{aside.name}); {again}",
            stacklevel=2,
        )
        return None

    def load(self, what: str = "checkpoint", error: type[Exception] | None = None) -> dict | None:
        """The resumable state :meth:`save` wrote, verified against its recorded digest (:class:`ArtifactMismatch`
        names the file when it was damaged: a damaged checkpoint is refused, never resumed); None when there is
        none; ``error``: the exception type of an unreadable file (default :class:`omcrl.utils.io.UnsafeFileError`).
        Call it before :meth:`claim`, so a refused start leaves nothing behind."""
        path = self.checkpoint_path
        if not path.exists():
            return None
        verify_artifact(path, what, f"delete it to train {self.method} seed {self.seed} from the start")
        return load_torch(path, what) if error is None else load_torch(path, what, error)

    def save(self, state: dict) -> Path:
        """Write the resumable ``state`` (tensors and plain containers) atomically to ``checkpoint.pt``, its digest
        recorded in ``run.json`` before the file is replaced; returns the path."""
        atomic_save_torch(state, self.checkpoint_path, self.checkpoint_recorder())
        return self.checkpoint_path

    def finish(
        self, payload: dict | str, artifact: str = "final.pt", *, keep_checkpoint: bool = False, **record: Any
    ) -> Path:
        """Write the finished ``artifact`` atomically (``payload``: tensors and plain containers, saved by torch, or
        text, e.g. an evaluation's episodes as CSV), then record its digest and ``record`` (what the run ended
        with: iterations, final loss, the data it was made of) in ``run.json``: a run is finished when ``run.json``
        holds the digest of an artifact that matches it (:meth:`finished`). The checkpoint is dropped (the artifact is
        the result; the resumable state is obsolete) unless ``keep_checkpoint`` (pretraining keeps its last one, from
        which a damaged encoder is rebuilt without training). Returns the artifact's path."""
        path = self.dir / artifact
        if isinstance(payload, str):
            atomic_write_text(path, payload)
            digest = file_digest(path)
        else:
            digest = atomic_save_torch(payload, path)
        self.record(**record, artifact_digest=digest)
        if not keep_checkpoint:
            self.checkpoint_path.unlink(missing_ok=True)
        return path

    def release(self) -> None:
        """Release the lock taken by :meth:`claim`."""
        release_lock(self.dir)

    def record(self, **fields: Any) -> None:
        """Add fields to ``run.json`` (e.g. the digest of the finished artifact), atomically."""
        rec = read_identity(self.dir) or {}
        rec.update(fields)
        atomic_write_text(self.dir / RUN_FILE, json.dumps(rec, indent=1))

    def verified(self, artifact: Path, field: str = "artifact_digest") -> bool | None:
        """Does ``artifact`` match the digest recorded in ``run.json`` when it was written?

        True / False; None when no digest was recorded (a run written before digests were kept).
        """

        want = (read_identity(self.dir) or {}).get(field)
        if want is None:
            return None
        return file_digest(artifact) == want

    @contextmanager
    def claimed(self, cfg: Config, overwrite: bool = False) -> Iterator[Run]:
        """Hold the run folder for a training call: :meth:`claim` it, write ``config.yaml`` (:meth:`write_config`),
        and :meth:`release` it however the call ends. Enter it only once the inputs are known to fit (encoder, oracle,
        data), so that a refused start leaves nothing behind that looks like a run."""
        self.claim(overwrite=overwrite)
        try:
            self.write_config(cfg)
            yield self
        finally:
            self.release()

    def session(
        self,
        *,
        total: int,
        start: int,
        unit: str,
        progress: bool = True,
        callbacks: Sequence[Callback] = (),
        digits: int | None = 6,
    ) -> Session:
        """The bookkeeping of one stretch of training from ``start`` to ``total`` units (a :class:`Session`: the
        metrics file, the progress bar, checkpoints and callbacks), to use as a context around the training loop."""
        return Session(self, total, start, unit, progress, callbacks, digits)

    def check(self) -> None:
        """Raise RunConfigMismatch when the folder exists with a ``run.json`` of another key."""
        found = read_identity(self.dir)
        if found is not None and found.get("key") != self.key:
            raise RunConfigMismatch(
                f"run folder {self.dir} holds a run with key {found.get('key')}, this configuration has key {self.key}"
            )


def _plain(x: Any) -> Any:
    """JSON-able copy: tuples become lists, paths strings."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, Path):
        return str(x)
    return x


def run_key(identity: dict) -> str:
    """10-hex-digit hash of an identity dict (order of keys does not matter)."""
    return config_hash(_plain(identity))[:10]


def make_run(cfg: Config, stage: str, method: str, identity: dict) -> Run:
    """The :class:`Run` of ``method`` at ``cfg.seed`` whose artifact is determined by ``identity``.

    ``identity``: the :func:`~omcrl.config.section_identity` of every config section the run reads (resolved for
    the method) and the digests of its upstream artifacts. The stage, the method and the behaviour versions of the
    components the stage depends on (:func:`behaviour`) are added here; the seed is the folder's. It is stored as
    given (plain JSON) in ``run.json``.
    """
    ident = _plain({"stage": stage, "method": method, **identity, "versions": behaviour(stage)})
    key = run_key(ident)
    d = cfg.run_root / "runs" / stage / f"{method}-{key}" / f"seed{cfg.seed}"
    return Run(stage, method, int(cfg.seed), key, ident, d)


def cache_run(folder: str | Path, name: str, seed: int, identity: dict, stage: str = "eval") -> Run:
    """The :class:`Run` of one cached result under ``folder``: ``<folder>/<name>-<key>/`` (``run.json`` and the
    artifact). Evaluations are runs too (``stage`` ``eval``): ``identity`` is everything that decides their rows
    (:func:`omcrl.eval.stage.evaluation_identity`, which carries the behaviour versions), so one lock, one record
    and one digest check serve them as they serve training. ``name``: what the result is of (a scene, a
    condition), readable in the folder's name beside the key."""
    ident = _plain(identity)
    key = run_key(ident)
    return Run(stage, name, int(seed), key, ident, Path(folder) / f"{name}-{key}")


def read_identity(run_dir: str | Path) -> dict | None:
    """The ``run.json`` of a run folder, or None when there is none."""
    p = Path(run_dir) / RUN_FILE
    if not p.is_file():
        return None
    try:
        rec = json.loads(p.read_text(encoding="utf-8"))
        if not isinstance(rec, dict):
            raise ValueError(f"a JSON {type(rec).__name__}, not an object")
        return rec
    except (OSError, ValueError) as e:  # ValueError: bad JSON and non-UTF-8 bytes alike
        raise RunConfigMismatch(f"{p} is not a readable run record ({_short(e)}); delete the run folder") from None


def _short(e: BaseException) -> str:
    """An error's message on one line, at most 120 characters."""
    text = " ".join(str(e).split())
    return text if len(text) <= 120 else text[:117] + "..."


def find_runs(run_root: str | Path, stage: str | None = None, method: str | None = None) -> list[dict]:
    """Every run under ``<run_root>/runs`` (optionally of one stage / method): their ``run.json`` + ``dir``."""
    base = Path(run_root) / "runs"
    out = []
    for rec in sorted(base.glob(f"{stage or '*'}/*/seed*/{RUN_FILE}")):
        ident = read_identity(rec.parent)
        if ident is None or (method is not None and ident.get("method") != method):
            continue
        out.append({**ident, "dir": rec.parent})
    return out


# ---------------------------------------------------------------- metrics
def read_metrics(path: str | Path) -> Any:
    """A tidy ``metrics.csv`` (or a run folder holding one) as a DataFrame with columns step, metric, value."""
    import pandas as pd

    p = Path(path)
    if p.is_dir():
        p = p / "metrics.csv"
    if not p.exists():
        return pd.DataFrame({"step": pd.Series(dtype=int), "metric": pd.Series(dtype=str), "value": []})
    try:
        raw = p.read_bytes()
        if p.suffix == ".gz":  # a run record kept in the checkout (omcrl.pipeline.griddata)
            raw = gzip.decompress(raw)
        if raw and not raw.endswith(b"\n"):  # every write ends its rows: a cut file ends mid-row
            raise ValueError("it ends in the middle of a row (cut short)")
        df = pd.read_csv(io.BytesIO(raw))
        if df[["step", "value"]].isna().any().any() if {"step", "value"} <= set(df.columns) else False:
            raise ValueError("rows with missing steps or values")
    except (OSError, EOFError, ValueError, pd.errors.ParserError) as e:  # includes an empty file and non-UTF-8 bytes
        raise CorruptFile(f"{p} is not a readable metrics file ({_short(e)})") from None
    if not {"step", "metric", "value"} <= set(df.columns):
        raise CorruptFile(f"{p} is not a metrics file: columns {list(df.columns)[:6]}, expected step, metric, value")
    return df


def training_seconds(metrics: Any) -> float:
    """Seconds of training a PPO run's metrics (:func:`read_metrics`) logged: the sum of its updates' ``rollout_s``
    and ``update_s`` (start-up and evaluation left out; 0 when none are logged)."""
    return float(metrics.loc[metrics["metric"].isin(["rollout_s", "update_s"]), "value"].sum())


def metric_series(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{metric: (steps, values)}`` from a tidy metrics file, each sorted by step."""
    df = read_metrics(path)
    out = {}
    for name, g in df.groupby("metric", sort=False):
        g = g.sort_values("step", kind="stable")
        out[str(name)] = (g["step"].to_numpy(), g["value"].to_numpy(dtype=float))
    return out


class MetricsLog:
    """Append-only tidy ``metrics.csv`` (step, metric, value) plus TensorBoard events.

    Resuming at ``resume_step`` drops rows past it (they belong to work the checkpoint does not hold), so a
    resumed run's file equals an uninterrupted one's. ``tensorboard=False`` writes the CSV only. Values are
    written with ``digits`` significant digits (RL: 6), or every digit with ``digits=None`` (pretraining).
    """

    def __init__(
        self, run_dir: str | Path, resume_step: int | None, tensorboard: bool = True, digits: int | None = 6
    ) -> None:
        run_dir = Path(run_dir)
        self.digits = digits  # significant digits of the CSV values; None: every digit (repr)
        self.path = run_dir / "metrics.csv"
        if resume_step is None or not self.path.exists():
            atomic_write_text(self.path, "step,metric,value\n")
        else:
            with open(self.path, newline="") as fh:
                rows = list(csv.reader(fh))[1:]
            keep = io.StringIO()
            w = csv.writer(keep, lineterminator="\n")
            w.writerow(["step", "metric", "value"])
            w.writerows(r for r in rows if r and int(r[0]) <= resume_step)
            atomic_write_text(self.path, keep.getvalue())
        self.tb = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.tb = SummaryWriter(str(run_dir / "tb"), purge_step=resume_step)

    def log(self, step: int, values: dict[str, float]) -> None:
        with open(self.path, "a", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            for k, v in values.items():
                if v is None or (isinstance(v, float) and math.isnan(v)):
                    continue
                w.writerow([step, k, repr(float(v)) if self.digits is None else f"{float(v):.{self.digits}g}"])
                if self.tb is not None:
                    self.tb.add_scalar(k, float(v), step)

    def close(self) -> None:
        if self.tb is not None:
            self.tb.flush()
            self.tb.close()


# ---------------------------------------------------------------- training hooks
class Callback:
    """Hooks a training loop calls (pretraining and every RL method), as Stable-Baselines3's callbacks are.

    Override what you need; ``on_step`` returning False stops the run unfinished (its last checkpoint stays, so
    the next call resumes from there). ``run`` is the :class:`Run` being trained.
    """

    def on_start(self, run: Run, step: int) -> None:
        """Before the first step of this session (``step``: where it starts, > 0 when resumed)."""

    def on_step(self, run: Run, step: int, metrics: dict[str, float]) -> bool:
        """After each step, its metrics logged and any checkpoint written; False stops the run."""
        return True

    def on_checkpoint(self, run: Run, step: int, path: Path) -> None:
        """After a checkpoint was written (atomically, its digest recorded in ``run.json``)."""

    def on_end(self, run: Run, step: int, finished: bool) -> None:
        """After the last step of this session (``finished``: the run reached its total)."""


class StopAfter(Callback):
    """Stop a run once it has reached ``step`` units (an interruption on purpose: tests, time-boxed sessions)."""

    def __init__(self, step: int) -> None:
        self.step = int(step)

    def on_step(self, run: Run, step: int, metrics: dict[str, float]) -> bool:
        return step < self.step


class Session:
    """One call's stretch of training a run, kept out of its loop: ``metrics.csv`` (and TensorBoard), the progress bar,
    the checkpoints and the :class:`Callback` s, so that the loop that uses it holds the algorithm alone (as
    CleanRL's does). Made by :meth:`Run.session` and used as a context::

        with run.claimed(cfg), run.session(total=n, start=step, unit="step") as s:
            while step < n:
                ...                                   # the algorithm: one update, its metrics in ``row``
                s.log(step, row, advance, loss=...)   # metrics.csv and the bar (fields shown beside it)
                if s.due(before, step, every):
                    s.checkpoint(step, state)         # atomic, digest in run.json, then on_checkpoint
                if not s.keep_going(step, row):       # on_step of every callback
                    break
        finished = s.ended                            # on_end called with it

    Starting at ``start`` > 0 (a resume) keeps the metrics rows up to ``start`` and drops the rest (work the
    checkpoint does not hold). Units (``step``, ``it``) are the loop's own: env steps for PPO, iterations for
    pretraining.
    """

    def __init__(
        self,
        run: Run,
        total: int,
        start: int,
        unit: str,
        progress: bool,
        callbacks: Sequence[Callback],
        digits: int | None,
    ) -> None:
        self.run, self.total, self.callbacks = run, int(total), tuple(callbacks)
        self.step = int(start)
        self.ended: bool | None = None  # set on leaving the context: did the run reach ``total``?
        self.metrics = MetricsLog(run.dir, start if start > 0 else None, digits=digits)
        self.bar = Progress(
            total, f"{run.stage}/{run.method} seed{run.seed}", unit=unit, initial=start, enabled=progress
        )

    def __enter__(self) -> Session:
        for cb in self.callbacks:
            cb.on_start(self.run, self.step)
        return self

    def log(self, step: int, row: dict[str, float], advance: int, **shown: Any) -> None:
        """Write ``row`` at ``step`` to the metrics and move the bar ``advance`` units on, ``shown`` beside it."""
        self.step = step
        self.metrics.log(step, row)
        self.bar.update(advance, **shown)

    def due(self, before: int, step: int, every: int) -> bool:
        """Is a checkpoint due (:func:`checkpoint_due`)? Never at the last unit: the finished artifact replaces it."""
        return step < self.total and checkpoint_due(before, step, every)

    def checkpoint(self, step: int, state: dict) -> Path:
        """Save the resumable ``state`` (:meth:`Run.save`: atomic, its digest recorded) and tell the callbacks."""
        path = self.run.save(state)
        for cb in self.callbacks:
            cb.on_checkpoint(self.run, step, path)
        return path

    def keep_going(self, step: int, row: dict[str, float]) -> bool:
        """Every callback's ``on_step`` (:func:`keep_going`); True at the last unit whatever they say."""
        return keep_going(self.callbacks, self.run, step, row) or step >= self.total

    def __exit__(self, kind: Any, exc: Any, tb: Any) -> None:
        self.bar.close()
        self.metrics.close()
        if kind is None:
            self.ended = self.step >= self.total
            for cb in self.callbacks:
                cb.on_end(self.run, self.step, self.ended)


def checkpoint_due(before: int, step: int, every: int) -> bool:
    """Did progress from ``before`` to ``step`` units cross a multiple of ``every`` (a checkpoint is then due)?"""
    return step // every > before // every


def keep_going(callbacks: Sequence[Callback], run: Run, step: int, metrics: dict[str, float]) -> bool:
    """Call every callback's ``on_step`` (all of them, even after one says stop); False when one says stop."""
    return all([cb.on_step(run, step, metrics) for cb in callbacks])


# ---------------------------------------------------------------- RNG state
def rng_state() -> dict:
    """torch, numpy-legacy and python RNG states as tensors and plain containers (``weights_only`` safe).

    The legacy global numpy RNG is saved because third-party code (envs, planners) may draw from it.
    """
    import torch

    name, keys, pos, has_gauss, cached = np.random.get_state()  # noqa: NPY002
    return {
        "torch": torch.get_rng_state(),
        "numpy": {
            "name": str(name),
            "keys": torch.from_numpy(np.asarray(keys, np.int64)),
            "pos": int(pos),
            "has_gauss": int(has_gauss),
            "cached": float(cached),
        },
        "python": [list(random.getstate()[1]), random.getstate()[0]],
    }


def set_rng_state(s: dict) -> None:
    """Restore what :func:`rng_state` returned."""
    import torch

    torch.set_rng_state(s["torch"])
    n = s["numpy"]
    np.random.set_state(  # noqa: NPY002
        (n["name"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"])
    )
    internal, version = s["python"]
    random.setstate((int(version), tuple(int(v) for v in internal), None))
