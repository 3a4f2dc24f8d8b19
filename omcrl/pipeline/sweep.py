"""Sweeps: named grids of (method, overrides) × seeds, run in-process or as Ray tasks (paper VI-C ablations).

A grid (:mod:`omcrl.pipeline.grids`) is a list of variants; :func:`omcrl.pipeline.plan.expand` turns it, for
every seed, into jobs with dependencies (collect, pretrain, train, evaluate). Each job is the stage's
ordinary entry point (``pretrain_method``, ``train_method``, ``evaluate_methods``) with the registry's cache,
so a finished job is skipped and a killed one resumes: re-running a sweep after a crash finishes only what is
missing.

Backends (:func:`run_sweep`):

- ``local``: the jobs one at a time in this process, in dependency order.
- ``ray``: every job a Ray task. With no address, Ray starts embedded on this machine with one CPU per core.
  With an address (``auto``, ``ray://host:port``, or a head's ``host:port``), the jobs go to that cluster. A
  job asks Ray for as many CPUs as it keeps busy (a trainer: one per env; pretraining: its threads;
  evaluation: its workers), so two jobs never share a core.

Every job writes its output to ``<run_root>/sweeps/<grid>/logs/<job>.log``. A failed job is reported with its
error and log path; jobs that need it are skipped, and the others run on.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import time
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from omcrl.config import ROOT_ENV, Config, ConfigError, load_config, project_root, resolve_path
from omcrl.eval.ablation import ablation_table, write_ablation, write_precision, write_remedies
from omcrl.eval.stage import eval_cache_dir, evaluate_methods
from omcrl.interpret.encoder_report import write_encoder_report
from omcrl.pipeline.griddata import GridData, find_kept_run, grid_data_dir
from omcrl.pipeline.grids import (
    ABLATION_GRIDS,
    DEFAULT_VARIANT,
    EVAL_ONLY_GRIDS,
    GRIDS,
    REMEDY_GRIDS,
    TABLE1_GRIDS,
    grid_variants,
)
from omcrl.pipeline.plan import (
    Job,
    base_overrides,
    describe_plan,
    expand,
    job_config,
    job_cpus,
    job_gpus,
    measured_rates,
    rate_maps,
    sweep_cost,
    sweep_plan,
    work_rows,
)
from omcrl.pipeline.recipes import pretrain_method, train_method
from omcrl.pipeline.stages import collect_stage
from omcrl.pipeline.storage import Storage, job_key
from omcrl.planners import PLANNERS
from omcrl.rl.methods import METHODS, final_policy_path, get_method
from omcrl.runs import StopAfter, read_identity
from omcrl.utils.io import atomic_write_text
from omcrl.utils.progress import Progress, log_lines
from omcrl.utils.runtime import cpu_count, machine_info
from omcrl.viz import save_figure
from omcrl.viz.compare import plot_learning_curves


@dataclass
class SweepResult:
    """What a sweep did: jobs, their status (``done | skipped | failed | blocked``), errors, evaluation rows."""

    grid: str
    jobs: list[Job]
    status: dict[str, str]
    errors: dict[str, str] = field(default_factory=dict)
    logs: dict[str, Path] = field(default_factory=dict)
    episodes: pd.DataFrame = field(default_factory=pd.DataFrame)
    wall_s: float = 0.0
    seconds: dict[str, float] = field(default_factory=dict)  # job id -> wall time of this invocation (s)
    started: dict[str, int] = field(default_factory=dict)  # job id -> step/iteration a resumed job began at

    @property
    def failed(self) -> list[Job]:
        return [j for j in self.jobs if self.status.get(j.id) == "failed"]

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for s in self.status.values():
            out[s] = out.get(s, 0) + 1
        return out

    def __repr__(self) -> str:
        lines = [f"sweep {self.grid}: {len(self.jobs)} jobs in {self.wall_s:.0f} s, {self.counts()}"]
        for j in self.failed:
            lines.append(
                f"FAILED {j.kind} {j.method} seed {j.seed}: {self.errors.get(j.id)} (log: {self.logs.get(j.id)})"
            )
        return "\n".join(lines)


def _node_root() -> None:
    """On a node where ``omcrl`` came with the job (Ray's ``runtime_env``) and no ``OMCRL_ROOT`` is set, work in
    ``~/.cache/omcrl`` rather than in whatever folder the Ray worker was started from."""
    if not os.environ.get(ROOT_ENV) and not (Path(__file__).resolve().parents[2] / "pyproject.toml").is_file():
        os.environ[ROOT_ENV] = str(Path.home() / ".cache" / "omcrl")


def _outputs(cfg: Config, job: Job, result: Any) -> list[Path]:
    """What a job produced, to push to storage: the dataset, the run folder, or the evaluation cache folder."""
    if job.kind == "collect":
        return [result.path]
    if job.kind in ("pretrain", "train"):
        return [result.run_dir]
    return [eval_cache_dir(cfg, job.method)]


def run_job(preset_cfg: dict, job: Job, log_path: str, share: dict | None = None) -> dict:
    """Run one job (any backend) with its output in ``log_path``; returns ``{"status", "seconds", "rows"}``.

    ``preset_cfg`` is ``{"preset", "overrides"}`` of the sweep's base config (plain data: it travels to Ray workers),
    and ``"encoder_reports": True`` when a pretraining job should also write its encoder's ``report.json``
    (:func:`omcrl.interpret.encoder_report.write_encoder_report`: a grid recorded to the checkout keeps it).
    ``share`` (with ``sweep.storage``): ``{"uri", "grid", "key", "pull"}``: the job pulls the manifests ``pull``
    (its dependencies' and its own) from storage first, and pushes its outputs under ``key`` and its log after;
    ``log_path`` is then taken from this node's project root when relative. Raises whatever the stage raises (the
    caller records it).
    """
    store = None
    if share is not None:
        _node_root()
        store = Storage(share["uri"])
        log_path = str(resolve_path(log_path))
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        with (
            open(log_path, "a", encoding="utf-8") as log,
            contextlib.redirect_stdout(log),
            contextlib.redirect_stderr(log),
            log_lines(),  # each long job's progress in its own log: `tail -f` shows how far it is
        ):
            print(f"[sweep] {job.kind} {job.method} seed {job.seed} {list(job.overrides)} ({job.id})", flush=True)
            if store is not None:
                got = store.pull(share["pull"])
                print(f"[sweep] from storage {store.uri} into {project_root()}: {got}", flush=True)
            status, rows, outputs, start = _run_stage(preset_cfg, job)
            if store is not None:
                m = store.push(share["key"], outputs)
                print(f"[sweep] pushed {len(m['files'])} files to {store.uri} ({share['key']})", flush=True)
            print(f"[sweep] finished in {time.perf_counter() - t0:.1f} s{' (cached)' if status == 'skipped' else ''}",
                  flush=True)  # fmt: skip
    finally:
        if store is not None:
            store.push_log(share["grid"], Path(log_path).name, Path(log_path))
    return {"status": status, "seconds": time.perf_counter() - t0, "rows": rows, "outputs": [str(p) for p in outputs],
            "start": start}  # fmt: skip


def _job_config(preset_cfg: dict, job: Job) -> Config:
    """The config a job runs with."""
    base = load_config(preset_cfg["preset"], overrides=preset_cfg["overrides"])
    return job_config(base, job.overrides, job.seed)


def _run_stage(preset_cfg: dict, job: Job) -> tuple[str, list[dict], list[Path], int]:
    """The stage of one job in this process: ``(status, evaluation rows, output paths, start)``; ``start``: the env
    step a resumed training (the iteration a resumed pretraining) began at, 0 otherwise, so that its time is set
    against the work it did."""
    cfg = _job_config(preset_cfg, job)
    if cfg.eval.workers == 0 and job.kind == "evaluate":
        cfg.eval.workers = job_cpus(cfg, job)
    rows: list[dict] = []
    result: Any = None
    began: int | None = None  # where a training in Table I's stretches began (its last stretch resumed)
    if job.kind == "collect":
        result = collect_stage(cfg, progress=True)  # with data.policy=oracle, the variant's oracle flies
        skipped = bool(result.skipped)
    elif job.kind == "pretrain":
        result = pretrain_method(cfg, job.method, progress=True)
        skipped = bool(result.skipped)
        if preset_cfg.get("encoder_reports"):
            write_encoder_report(cfg, result.run_dir)
    elif job.kind == "train":
        # A grid that re-flies Table I's runs trains a run in Table I's stretches: stopped where that one was
        # stopped, then resumed (:func:`stretches`), so that it learns the same policy.
        stops: list[int] = []
        if preset_cfg.get("as_table1"):
            table1 = GridData(grid_data_dir(cfg, "table1"))
            # Hours of training that could only learn another policy are not spent: refused before the first step.
            why = not_table1_inputs(preset_cfg, job, table1)
            if why is not None:
                raise RuntimeError(why)
            stops = stretches(preset_cfg, job, table1)
        for stop in stops:
            part = train_method(cfg, job.method, progress=True, callbacks=(StopAfter(stop),))
            began = part.start if began is None else began
        result = train_method(cfg, job.method, progress=True)
        skipped = bool(result.skipped) and began is None
    else:
        path = final_policy_path(cfg, job.method)
        if path is None:
            raise FileNotFoundError(f"{job.method} seed {job.seed}: no finished run to evaluate")
        counts: dict[str, int] = {}
        df = evaluate_methods(cfg, {job.method: path}, stats=counts, progress=True)
        # Read back whole from the cache: a skip, so jobs.csv keeps the time the evaluation took when it ran.
        skipped = counts.get("evaluated", 0) == 0
        df = df.drop(columns=["trajectory"], errors="ignore").assign(label=job.label, overrides=" ".join(job.overrides))
        rows = json.loads(df.to_json(orient="records"))
    start = int(getattr(result, "start", 0))  # a stage that resumed says where (training, pretraining)
    if began is not None:
        start = began
    return ("skipped" if skipped else "done"), rows, _outputs(cfg, job, result), start


def upstream(jobs: Sequence[Job]) -> dict[str, list[str]]:
    """``{job id: ids of every job it depends on, directly or not}``."""
    by_id = {j.id: j for j in jobs}
    out: dict[str, list[str]] = {}

    def walk(jid: str) -> list[str]:
        if jid not in out:
            seen: dict[str, None] = {}
            for d in by_id[jid].deps:
                seen.update(dict.fromkeys([*walk(d), d]))
            out[jid] = list(seen)
        return out[jid]

    for j in jobs:
        walk(j.id)
    return out


def _in_grid_order(episodes: pd.DataFrame, jobs: list[Job]) -> pd.DataFrame:
    """``episodes`` with variants in the grid's order (then by training seed), not in the order the jobs finished,
    so that tables and figures list the variants the same way on every run."""
    if episodes.empty or "label" not in episodes:
        return episodes
    rank = {lab: i for i, lab in enumerate(dict.fromkeys(j.label for j in jobs if j.kind == "evaluate"))}
    key = episodes["label"].map(rank).fillna(len(rank))
    return (
        episodes.assign(_rank=key)
        .sort_values(["_rank", "train_seed"], kind="stable")
        .drop(columns="_rank")
        .reset_index(drop=True)
    )


def run_sweep(
    cfg: Config,
    grid: str,
    seeds: Sequence[int] | None = None,
    *,
    backend: str = "ray",
    address: str | None = None,
    num_cpus: int | None = None,
    progress: bool = True,
    record: GridData | None = None,
    variants: Sequence[str] | None = None,
) -> SweepResult:
    """Run ``grid`` at ``seeds`` (default ``cfg.seeds``) on ``backend`` (``ray`` or ``local``).

    ``address``: a Ray cluster to use (``auto``, ``ray://host:port`` or ``host:port``); None starts Ray embedded with
    ``num_cpus`` CPUs (default one per core). Returns a :class:`SweepResult`; evaluation rows are in
    ``result.episodes`` with the variant's ``label``.

    ``record``: keep each finished job's small data there (:class:`omcrl.pipeline.griddata.GridData`: the runs'
    records after their training, the episodes after their evaluation) and run only the variants whose episodes it
    does not hold yet, with what they need upstream; the others are marked ``recorded`` and their rows read back.
    ``variants``: only these variants (labels) and what they need upstream (ConfigError naming the grid's labels
    for an unknown one, before any job runs).
    A teacher's weights (a training run other training jobs need: the oracle) are kept there too, and laid out as
    its finished run folder before anything runs, so a new machine trains its students without training it again;
    a run that another grid's record keeps (the same key and seed: Table I's oracle for the budget ladder) is laid
    out from there (:func:`omcrl.pipeline.griddata.find_kept_run`). Once every evaluation that needs a teacher is
    recorded, its weights leave the checkout for git history (:func:`release_teachers`).
    """
    if backend not in ("ray", "local"):
        raise ConfigError(f"sweep backend: got {backend!r}, expected 'ray' or 'local'")
    every = expand(cfg, grid, seeds)
    jobs = only_variants(every, variants, grid)
    # A grid that re-flies another grid's runs keeps their episodes alone (the records are that grid's).
    keeps_runs = record is not None and grid not in EVAL_ONLY_GRIDS
    targets = _record_targets(jobs) if keeps_runs else {}
    recorded = _recorded(jobs, record) if record is not None else set()
    # Teachers as the whole grid has them: a teacher's weights are kept under its own variant (the oracle's), which
    # --variants may leave out while a student it guides is run.
    ids = {j.id for j in jobs}
    teachers = {jid: label for jid, label in _teachers(every, _record_targets(every)).items() if jid in ids}
    teachers = teachers if keeps_runs else {}
    logs_dir = cfg.run_root / "sweeps" / grid / "logs"
    # A grid recorded to the checkout keeps what its encoders learned too (the budget ladder's encoder table).
    base = {"preset": cfg.preset, "overrides": base_overrides(cfg), "encoder_reports": record is not None}
    res = SweepResult(grid, jobs, {}, logs={j.id: logs_dir / j.log_name for j in jobs})
    store = Storage(cfg.sweep.storage) if cfg.sweep.storage else None
    shares = _shares(jobs, grid, store)
    # With storage, a job's log path is taken from its node's project root (nodes may have different ones).
    log_arg = {j.id: Storage._rel(res.logs[j.id], project_root()) if store else str(res.logs[j.id]) for j in jobs}
    t0 = time.perf_counter()
    rows: list[dict] = []
    # Jobs are not alike (a pretraining takes an hour, its evaluation a minute): the time left is priced from the
    # measured rates of each kind of job where this preset has them, not from the number of jobs done.
    rate, _ = rate_maps(measured_rates(cfg))
    work_of = work_rows(cfg, jobs)
    work = {w.id: w.work for w in work_of}
    planned = {w.id: w.work / rate[w.rate_key] for w in work_of if rate.get(w.rate_key)}
    ids = [j.id for j in jobs]

    def time_left(elapsed: float) -> float | None:
        # A job resumed from a checkpoint ran only the part after it: the pace is set against that part.
        ran = {j: max(0, work[j] - s) / work[j] for j, s in res.started.items() if work.get(j)}
        return _time_left(planned, ids, res.status, elapsed, ran)

    bar = Progress(len(jobs), f"sweep/{grid}", unit="job", enabled=progress, time_left=time_left)

    # A grid that re-flies Table I's runs flies only Table I's policies: a run retrained here must have trained in
    # Table I's stretches (a resume restarts the envs with a seed of its own, so it learns another policy).
    table1 = GridData(grid_data_dir(cfg, "table1")) if grid in EVAL_ONLY_GRIDS and record is not None else None
    if table1 is not None:
        base["as_table1"] = True  # its training jobs train as Table I's runs did (_run_stage)

    def finish(job: Job, out: dict | None, err: str | None) -> None:
        learned = job.method in METHODS and METHODS[job.method].learned  # not the local APF, the blind pilot
        if err is None and table1 is not None and job.kind == "evaluate" and learned:
            err = not_table1_run(base, job, table1)
        if err is not None:
            res.status[job.id], res.errors[job.id] = "failed", err
        else:
            res.status[job.id] = out["status"]
            res.seconds[job.id] = float(out["seconds"])
            res.started[job.id] = int(out.get("start", 0))
            rows.extend(out["rows"])
            if record is not None:
                for label, stage in targets.get(job.id, ()):
                    record.save_run(label, job.seed, stage, out["outputs"][0])
                # A teacher no variant of this grid records is kept here unless another grid's record keeps the same
                # run (Table I's oracle for the budget ladder's pretraining students: one copy in reference/).
                if job.id in teachers and (job.id in targets or job.id not in kept_elsewhere):
                    if (teachers[job.id], "rl") not in targets.get(job.id, ()):
                        record.save_run(teachers[job.id], job.seed, "rl", out["outputs"][0])
                    record.save_weights(teachers[job.id], job.seed, "rl", out["outputs"][0])
                if job.kind == "evaluate":
                    record.save_episodes(job.label, job.seed, pd.DataFrame(out["rows"]))
            # After every job, not at the end: a killed driver loses no measured time.
            _record_job_times(cfg, res, logs_dir.parent / "jobs.csv")
            if record is not None:
                _record_job_times(cfg, res, record.root / "jobs.csv", True, logs_dir.parent / "jobs.csv")
        bar.update(1, **_postfix(res, running))

    running: set[str] = set()
    for job in jobs:
        if job.id in recorded:
            res.status[job.id] = "recorded"
            if job.kind == "evaluate":
                rows.extend(json.loads(record.read_episodes(job.label, job.seed).to_json(orient="records")))
            bar.update(1, **_postfix(res, running))
    todo = [j for j in jobs if j.id not in recorded]
    kept_elsewhere: set[str] = set()  # training jobs whose run a grid record of this preset keeps already
    if record is not None:
        # A training run whose weights a grid record of this preset keeps (this grid's teacher, or the same run
        # kept by another grid: Table I's oracle for the budget ladder) is laid out instead of trained.
        for job in todo:
            if job.kind != "train" or (run := _train_run(base, job)) is None:
                continue
            kept = find_kept_run(record.root.parent, run)
            if kept is not None:
                kept_elsewhere.add(job.id)
            if kept is not None and kept[0].restore_run(kept[1], "rl", run):
                where = "" if kept[0].root == record.root else f" (kept by {kept[0].root.name})"
                print(f"[sweep] {job.method} seed {job.seed}: kept weights restored into {run.dir}{where}", flush=True)
    if backend == "local":
        for job in todo:
            if any(res.status.get(d) in ("failed", "blocked") for d in job.deps):
                res.status[job.id] = "blocked"
                bar.update(1, **_postfix(res, running))
                continue
            try:
                out = run_job(base, job, log_arg[job.id], shares.get(job.id))
                finish(job, out, None)
            except Exception as e:
                finish(job, None, _error(e, res.logs[job.id]))
    else:
        _run_ray(cfg, todo, base, res, finish, running, bar, address, num_cpus, store, shares, log_arg)
    bar.close()
    if store is not None:
        # The driver's tables and learning curves read the runs: fetch what the finished jobs made (not the data).
        done = [j for j in todo if j.kind != "collect" and res.status.get(j.id) in ("done", "skipped")]
        store.pull([shares[j.id]["key"] for j in done])
    res.wall_s = time.perf_counter() - t0
    res.episodes = _in_grid_order(pd.DataFrame(rows), jobs)
    _record_job_times(cfg, res, logs_dir.parent / "jobs.csv")
    if record is not None:
        for path in release_teachers(cfg, grid, sorted({j.seed for j in jobs}), record):
            print(f"[sweep] teacher weights released (every student recorded): {path}", flush=True)
    return res


def release_teachers(
    cfg: Config, grid: str, seeds: Sequence[int] | None = None, record: GridData | None = None
) -> list[Path]:
    """Take out of the checkout the kept weights of every teacher of ``grid`` whose dependent evaluations (its own
    and its students', over the whole grid at that seed) are all recorded; returns the pointers written
    (:meth:`omcrl.pipeline.griddata.GridData.release_weights`: weights not yet committed stay).

    ``seeds``: default every seed ``record`` holds; ``record``: default the grid's data in the checkout.
    """
    record = record if record is not None else GridData(grid_data_dir(cfg, grid))
    seeds = list(seeds) if seeds is not None else record.seeds()
    if not seeds:
        return []
    jobs = expand(cfg, grid, seeds)
    up = upstream(jobs)
    by_id = {j.id: j for j in jobs}
    out = []
    for jid, label in _teachers(jobs, _record_targets(jobs)).items():
        needs_it = [j for j in jobs if j.kind == "evaluate" and jid in up[j.id]]
        if all(record.has_episodes(j.label, j.seed) for j in needs_it):
            pointer = record.release_weights(label, by_id[jid].seed, "rl")
            if pointer is not None:
                out.append(pointer)
    return out


def _record_targets(jobs: Sequence[Job]) -> dict[str, list[tuple[str, str]]]:
    """``{job id: [(variant label, stage)]}``: under which variants' folders a training or pretraining job's run
    record is kept (a run shared by several variants, such as one encoder, is kept under each)."""
    by_id = {j.id: j for j in jobs}
    out: dict[str, list[tuple[str, str]]] = {}
    for e in jobs:
        if e.kind != "evaluate":
            continue
        train = by_id[e.deps[0]]
        out.setdefault(train.id, []).append((e.label, "rl"))
        for d in train.deps:
            if by_id[d].kind == "pretrain":
                out.setdefault(d, []).append((e.label, "pretrain"))
    return out


def only_variants(jobs: list[Job], variants: Sequence[str] | None, grid: str) -> list[Job]:
    """``jobs`` of the ``variants`` (labels) and every job they need, in their order; all jobs for None."""
    if variants is None:
        return jobs
    labels = list(dict.fromkeys(j.label for j in jobs if j.kind == "evaluate"))
    unknown = [v for v in variants if v not in labels]
    if unknown:
        raise ConfigError(f"sweep {grid}: variants {unknown} are not in the grid; its variants are {labels}")
    up = upstream(jobs)
    keep = {j.id for j in jobs if j.kind == "evaluate" and j.label in variants}
    keep |= {d for jid in list(keep) for d in up[jid]}
    return [j for j in jobs if j.id in keep]


def _teachers(jobs: Sequence[Job], targets: dict[str, list[tuple[str, str]]]) -> dict[str, str]:
    """``{job id: variant label}`` of the training jobs another training job needs (teachers: the oracle), with
    the variant whose folder keeps their weights: the first that records the run, or, for a teacher no variant
    evaluates (the RL ladder's oracle x3), a folder of its own named after its first recorded student
    (``oracle for ours RL x3``). Kept there, a teacher finished in one session is restored in the next on any
    machine (:func:`omcrl.pipeline.griddata.find_kept_run`) instead of being trained again."""
    by_id = {j.id: j for j in jobs}
    need = {d for j in jobs if j.kind == "train" for d in j.deps if by_id[d].kind == "train"}
    out = {}
    for jid in sorted(need):
        if targets.get(jid):
            out[jid] = targets[jid][0][0]
            continue
        student = next((targets[j.id][0][0] for j in jobs if jid in j.deps and targets.get(j.id)), None)
        if student is not None:
            out[jid] = f"{by_id[jid].method} for {student}"
    return out


def _train_run(preset_cfg: dict, job: Job) -> Any:
    """The :class:`omcrl.runs.Run` a training job trains into, or None while its own prerequisites are missing."""
    cfg = _job_config(preset_cfg, job)
    spec = get_method(job.method)
    return spec.recipe.run(cfg, spec)


def _segments(run_dir: Path) -> list[tuple[int, int]]:
    """The stretches of a run's RL training as its ``run.json`` records them: ``[(from_step, env_seed), ...]``."""
    return [(int(s["from_step"]), int(s["env_seed"])) for s in (read_identity(run_dir) or {}).get("segments", [])]


def _cpu(machine: dict[str, Any]) -> str:
    """A machine of a run record (:func:`omcrl.utils.runtime.machine_info`) as its CPU model and the vector ISA torch
    dispatched to (``"AMD EPYC, AVX512"``: one model runs AVX2 kernels on one host and AVX512 on another, which round
    apart)."""
    return ", ".join(str(machine[k]) for k in ("cpu_model", "cpu_capability") if machine.get(k))


def _cpus(record: dict[str, Any]) -> list[str]:
    """The CPUs (:func:`_cpu`) a run's record says it trained on; empty for a record older than that field."""
    return list(dict.fromkeys(_cpu(m) for m in record.get("machines", []) if m.get("cpu_model")))


def _inputs_differ(job: Job, run: Any, recorded: dict[str, Any], here: str | None) -> str | None:
    """Why ``run`` (the run of ``job`` here, on the CPU ``here``) cannot be Table I's run ``recorded`` (its
    ``run.json``), or None: another run key, or another CPU. A record without a key or machines, or ``here`` None
    (unknown), is not judged on them."""
    if recorded.get("key") and recorded["key"] != run.key:
        digest = recorded.get("identity", {}).get("encoder_digest")
        return (
            f"{job.method} seed {job.seed}: the run here has key {run.key} where Table I's has {recorded['key']}"
            + (f" (Table I's trained on the frozen encoder {digest})" if digest else "")
            + ": its inputs differ (an encoder pretrained again on another machine gives another one), so it would "
            "learn another policy"
        )
    cpus = _cpus(recorded)
    if cpus and here is not None and here not in cpus:
        return (
            f"{job.method} seed {job.seed}: Table I's run trained on {' and '.join(cpus)}, the run here on {here}; "
            "the same seed gives the same policy only on the same CPU (docs/reproducibility.md), so a retrain here "
            "is another policy"
        )
    return None


def not_table1_inputs(preset_cfg: dict, job: Job, table1: GridData) -> str | None:
    """Why the training job ``job`` cannot learn Table I's policy of its method and seed on this machine, or None.

    Checked before training, from Table I's record (``<method>/seed<k>/rl/run.json``): its run key, which hashes
    the config and the upstream artifacts (the frozen encoder's digest among them), must be the key of the run here,
    and it must have trained on this machine's CPU (:func:`_cpu`): on the CPU the same seed gives the same result on
    the same machine only (docs/reproducibility.md), so an encoder pretrained again on another CPU, or a policy
    trained on one, is another draw of the seed. A record without a key or machines (older than those fields) is not
    judged on them; a job Table I has no record of, or a run already finished (a teacher restored from its record
    trains nothing), None.
    """
    recorded = read_identity(table1.folder(job.method, job.seed) / "rl") or {}
    run = _train_run(preset_cfg, job)
    if not recorded or run is None or run.finished() is not None:
        return None
    import torch  # noqa: F401  (machine_info reads the ISA from torch only once it is imported)

    why = _inputs_differ(job, run, recorded, _cpu(machine_info()))
    return None if why is None else f"{why}; not trained (run this job on such a machine)"


def _learning_differs(recorded: Path, here: Path) -> str | None:
    """Where a run's training metrics (``metrics.csv``: ``step, metric, value``) first part from a record's, or None
    when every recorded value is reproduced exactly. Timings (metrics ending in ``_s``: seconds, steps/s) are left
    out, and so are metrics the record does not have (it may be older than them); None when either file is missing.
    On one CPU a retrained run reproduces its record's losses and returns bit for bit, so this tells a run trained on
    another machine even where the record is older than its ``machines`` field."""
    if not recorded.is_file() or not here.is_file():
        return None
    a, b = (pd.read_csv(f) for f in (recorded, here))
    a = a[~a["metric"].astype(str).str.endswith("_s")]
    both = a.merge(b, on=["step", "metric"], how="left", suffixes=("", "_here"))
    same = (both["value"] == both["value_here"]) | (both["value"].isna() & both["value_here"].isna())
    off = both[~same]
    if off.empty:
        return None
    r = off.iloc[0]
    return f"{r['metric']} at step {int(r['step']):,}: {r['value']} recorded, {r['value_here']} here"


def not_table1_run(preset_cfg: dict, job: Job, table1: GridData) -> str | None:
    """Why the run ``job`` flies here is not Table I's run of the same method and seed, or None when it is.

    The run's key is Table I's (the same config and upstream artifacts: the grids share the training job); what
    can still differ is how it was trained: on the CPU a run is the same policy when it trained in the same
    stretches, and a run resumed from a checkpoint restarts its envs with a seed of its own
    (:func:`omcrl.rl.train.train`), so it learns another one. Compared: the ``segments`` of its ``run.json`` and of
    Table I's record (``reference/<preset>/table1-<suite>/<method>/seed<k>/rl/run.json``), as before training the
    run key and the CPU it trained on (:func:`not_table1_inputs`), and its training metrics, which a run learned
    again on the same CPU reproduces bit for bit (:func:`_learning_differs`); a method or seed Table I has no record
    of is not judged here (None).
    """
    folder = table1.folder(job.method, job.seed) / "rl"
    record = read_identity(folder) or {}
    run = _train_run(preset_cfg, job)
    if run is None:
        return None
    ran_on = _cpus(read_identity(run.dir) or {})
    inputs = _inputs_differ(job, run, record, ran_on[-1] if ran_on else None)
    if inputs is not None:
        return f"{inputs}: its episodes are not recorded"
    recorded, here = _segments(folder), _segments(run.dir)
    if recorded and here != recorded:
        return (
            f"{job.method} seed {job.seed}: the run in {run.dir} trained in stretches {here} (from_step, env_seed) "
            f"where Table I's trained in {recorded}: it is another policy, so its episodes are not recorded; move that "
            "run folder aside and run the grid again, which trains it in Table I's stretches"
        )
    why = _learning_differs(folder / "metrics.csv.gz", run.dir / "metrics.csv")
    if why is None:
        return None
    return (
        f"{job.method} seed {job.seed}: the run in {run.dir} learned otherwise than Table I's ({why}): it is another "
        "policy (trained on another machine than its record can say), so its episodes are not recorded"
    )


def stretches(preset_cfg: dict, job: Job, table1: GridData) -> list[int]:
    """Before a training job of a grid that re-flies Table I's runs: the steps at which it stops and resumes to train
    as Table I's run did (that run's recorded ``segments`` after the first, those its run here has not reached): a run
    resumed from a checkpoint at step S restarts its envs with the seed Table I's did at S, so it learns the same
    policy (:func:`not_table1_run`). A checkpoint of an interrupted attempt at a step where Table I's run did not
    resume is moved aside first (``checkpoint.pt.diverges``), so the run trains from the start. Empty when Table I's
    run trained in one stretch or has no record."""
    recorded = _segments(table1.folder(job.method, job.seed) / "rl")
    run = _train_run(preset_cfg, job)
    if not recorded or run is None or run.finished() is not None:
        return []
    ckpt = run.load("checkpoint")
    at = 0 if ckpt is None else int(ckpt["step"])
    if at and at not in {s for s, _ in recorded[1:]}:
        aside = run.checkpoint_path.with_name(run.checkpoint_path.name + ".diverges")
        run.checkpoint_path.replace(aside)
        print(f"[sweep] {job.method} seed {job.seed}: checkpoint at step {at:,} moved to {aside} (Table I's run "
              f"trained in stretches {recorded}: resuming here would learn another policy); training from the start",
              flush=True)  # fmt: skip
        at = 0
    return [s for s, _ in recorded[1:] if s > at]


def _recorded(jobs: Sequence[Job], record: GridData) -> set[str]:
    """Ids of the jobs nothing left to run needs: evaluations whose episodes ``record`` holds, and the upstream jobs
    of those alone."""
    need = {j.id for j in jobs if j.kind == "evaluate" and not record.has_episodes(j.label, j.seed)}
    up = upstream(jobs)
    need |= {d for jid in list(need) for d in up[jid]}
    return {j.id for j in jobs} - need


def recorded_jobs(cfg: Config, grids: Sequence[str], seeds: Sequence[int] | None = None) -> set[str]:
    """Ids of the jobs of ``grids`` at ``seeds`` that the checkout's records (reference/) leave nothing to run for:
    :func:`_recorded`'s, and the teachers whose weights are kept. ``sweep --plan --to-reference`` leaves them out.

    A job several grids share (one oracle, one encoder) counts as recorded only when no grid still needs it: a run
    one grid has recorded is not on a fresh machine, so another grid's variant that needs it trains it again."""
    out: set[str] = set()
    need: set[str] = set()
    for g in grids:
        jobs, record = expand(cfg, g, seeds), GridData(grid_data_dir(cfg, g))
        teachers = _teachers(jobs, _record_targets(jobs))
        seed = {j.id: j.seed for j in jobs}
        kept = {j for j, label in teachers.items() if record.has_weights(label, seed[j], "rl")}
        done = _recorded(jobs, record) | kept
        out |= done
        need |= {j.id for j in jobs} - done
    return out - need


def rest_plan(cfg: Config, grids: Sequence[str], seeds: Sequence[int] | None = None) -> pd.DataFrame:
    """:func:`omcrl.pipeline.plan.sweep_plan`'s rows of the jobs still to run: those no record in the checkout
    holds (:func:`recorded_jobs`), the main comparison's runs left out."""
    plan = sweep_plan(cfg, grids, seeds)
    return plan[~plan["id"].isin(recorded_jobs(cfg, grids, seeds)) & ~plan["table1"]]


def rest_hours(cfg: Config, grids: Sequence[str], seeds: Sequence[int] | None = None) -> dict[str, float]:
    """What ``grids`` at ``seeds`` still cost on one machine: the jobs no record in the checkout holds
    (:func:`recorded_jobs`; the main comparison's runs left out, as ``sweep --plan --to-reference`` leaves them) at
    the rates this preset's records measured (:func:`omcrl.pipeline.plan.measured_rates`).

    Returns
    -------
    ``{"jobs", "hours", "hours_fast"}``: the number of jobs, and their machine-hours at the measured rates' median
    and upper quartile (a machine to itself); the hours are NaN when a kind of job has no measured rate.
    """
    plan = rest_plan(cfg, grids, seeds)
    median, fast = rate_maps(measured_rates(cfg))
    rated = set(plan["rate_key"]) <= set(median)
    return {
        "jobs": len(plan),
        "hours": sweep_cost(plan, median)["machine_hours"] if rated else math.nan,
        "hours_fast": sweep_cost(plan, fast)["machine_hours"] if rated else math.nan,
    }


def _shares(jobs: Sequence[Job], grid: str, store: Storage | None) -> dict[str, dict]:
    """Each job's storage instructions for :func:`run_job` (none without storage)."""
    if store is None:
        return {}
    up = upstream(jobs)
    key = {j.id: job_key(j.id) for j in jobs}
    return {
        j.id: {"uri": store.uri, "grid": grid, "key": key[j.id], "pull": [*(key[d] for d in up[j.id]), key[j.id]]}
        for j in jobs
    }


# ``start``: the units a resumed job found done in its checkpoint (0: it ran from the start); empty in rows written
# before it was kept, whose resumes only their work below the kind's largest tells (omcrl.pipeline.ablations).
JOB_TIME_COLUMNS = ["id", "kind", "method", "seed", "status", "seconds", "rate_key", "work", "start"]


def _record_job_times(
    cfg: Config, res: SweepResult, path: Path, portable: bool = False, measured: Path | None = None
) -> None:
    """Keep each job's measured wall time in ``jobs.csv`` beside the sweep's logs.

    A job that was cached this time keeps the time it took when it really ran, so re-runs do not erase what was
    measured. :func:`measured_rates` reads these files. ``portable``: job ids with this machine's results folder and
    checkout written ``<results>`` and ``<root>`` (the copy committed beside a grid's data). ``measured``: the sweep's
    own ``jobs.csv`` on this machine; a job found finished that ``path`` has no row for, but that one timed as done,
    takes that row (a job a stopped session finished: its grid record's copy was reset with the worktree).
    """
    plan = {r.id: r for r in work_rows(cfg, res.jobs)}
    old = pd.read_csv(path) if path.exists() else pd.DataFrame(columns=JOB_TIME_COLUMNS)
    kept = {r["id"]: r for r in old.to_dict("records")}
    ran = {} if measured is None or not measured.is_file() else {
        r["id"]: r for r in pd.read_csv(measured).to_dict("records") if r["status"] == "done"}  # fmt: skip

    def name(jid: str) -> str:
        if not portable:
            return jid
        return jid.replace(str(cfg.run_root.parent), "<results>").replace(str(project_root()), "<root>")

    for j in res.jobs:
        st = res.status.get(j.id)
        if st == "skipped" and name(j.id) not in kept and j.id in ran:
            kept[name(j.id)] = {**ran[j.id], "id": name(j.id)}
        elif st == "done" or (st == "skipped" and name(j.id) not in kept):
            w = plan[j.id]
            # A resumed training or pretraining timed only the part after its checkpoint: its work is that part too.
            start = res.started.get(j.id, 0)
            kept[name(j.id)] = {"id": name(j.id), "kind": j.kind, "method": j.method, "seed": j.seed, "status": st,
                          "seconds": round(res.seconds.get(j.id, float("nan")), 2), "rate_key": w.rate_key,
                          "work": max(0, w.work - start), "start": start}  # fmt: skip
    # Named columns: a sweep that measured nothing (every job recorded) still writes a file that reads back.
    atomic_write_text(path, pd.DataFrame(list(kept.values()), columns=JOB_TIME_COLUMNS).to_csv(index=False))


def _time_left(
    planned: dict[str, float],
    ids: Sequence[str],
    status: dict[str, str],
    elapsed: float,
    ran_share: dict[str, float] | None = None,
) -> float | None:
    """Seconds left of a sweep of jobs ``ids`` from each job's ``planned`` seconds (work / the kind's measured rate):
    the planned seconds of the jobs not finished, times the pace of this run (elapsed wall time over the planned
    seconds of the jobs it finished: parallel nodes, this machine's speed) once those are a tenth of the whole, at
    the measured rates as they are before. ``ran_share``: ``{job id: share of its work this run did}`` for jobs
    resumed from a checkpoint (1 for any other). None when a job involved has no planned time (the caller counts
    jobs)."""
    share = ran_share or {}
    ran = [j for j in ids if status.get(j) == "done"]
    rest = [j for j in ids if status.get(j) not in ("done", "skipped", "recorded", "failed", "blocked")]
    if any(j not in planned for j in ran + rest):
        return None
    spent, left = sum(planned[j] * share.get(j, 1.0) for j in ran), sum(planned[j] for j in rest)
    # A first short job (a collection found on disk) would set the pace for the hour that follows: not before a tenth.
    pace = elapsed / spent if spent > 0 and spent >= 0.1 * (spent + left) else 1.0
    return pace * left


def _postfix(res: SweepResult, running: set[str]) -> dict[str, Any]:
    # Jobs handed to Ray wait there until their CPUs are free, so "submitted" counts running and queued jobs.
    c = res.counts()
    done = c.get("done", 0) + c.get("skipped", 0) + c.get("recorded", 0)
    return {"done": done, "submitted": len(running), "failed": c.get("failed", 0)}


def _error(e: BaseException, log: Path) -> str:
    with contextlib.suppress(OSError):
        with open(log, "a", encoding="utf-8") as f:
            f.write("".join(traceback.format_exception(e)))
    return f"{type(e).__name__}: {e}"


def _run_ray(
    cfg: Config,
    jobs: list[Job],
    base: dict,
    res: SweepResult,
    finish: Any,
    running: set[str],
    bar: Any,
    address: str | None,
    num_cpus: int | None,
    store: Storage | None,
    shares: dict[str, dict],
    log_arg: dict[str, str],
) -> None:
    import ray

    started_here = not ray.is_initialized()
    if started_here:
        if address is None:
            # address="local": a Ray of its own even when a cluster started with `ray start` runs on this machine
            # (plain ray.init() would join that one, and refuse num_cpus).
            ray.init(address="local", num_cpus=num_cpus or cpu_count(), include_dashboard=False, log_to_driver=False)
        else:
            connect_ray(address)
    try:
        if store is None:
            check_shared_results(cfg, base)
        else:
            check_storage(store)
        capacity = largest_node_cpus()
        # A task lost with its node (a system failure) is retried twice; a job that raised is not (Ray retries
        # application errors only with retry_exceptions, off here): a deterministic error fails once, with its log.
        remote = ray.remote(max_retries=2)(run_job)
        cluster_gpus = int(ray.cluster_resources().get("GPU", 0))
        pending: dict[Any, Job] = {}
        todo = list(jobs)
        while todo or pending:
            for job in list(todo):
                st = [res.status.get(d) for d in job.deps]
                if any(s in ("failed", "blocked") for s in st):
                    todo.remove(job)
                    res.status[job.id] = "blocked"
                    bar.update(1, **_postfix(res, running))
                elif all(s in ("done", "skipped") for s in st):
                    todo.remove(job)
                    jcfg = job_config(cfg, job.overrides, job.seed)
                    need, gpus = min(job_cpus(jcfg, job), capacity), job_gpus(jcfg, job)
                    if gpus > cluster_gpus:
                        raise ClusterError(
                            f"sweep: job {job.kind} {job.method} seed {job.seed} asks for {gpus} GPU ({job.kind} "
                            f"device=cuda) and {need} CPUs, but the cluster has {cluster_gpus} GPUs: it could never "
                            "run; add a GPU node, or set rl.device / pretrain.device to auto or cpu"
                        )
                    ref = remote.options(num_cpus=need, num_gpus=gpus).remote(
                        base, job, log_arg[job.id], shares.get(job.id)
                    )
                    pending[ref] = job
                    running.add(job.id)
            if not pending:
                continue
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job = pending.pop(ref)
                running.discard(job.id)
                if store is not None:
                    # The job's node may be another machine: its log comes back through storage.
                    with contextlib.suppress(OSError):
                        store.fetch_log(shares[job.id]["grid"], res.logs[job.id].name, res.logs[job.id])
                try:
                    finish(job, ray.get(ref), None)
                except Exception as e:
                    cause = getattr(e, "cause", None) or e
                    finish(job, None, _error(cause, res.logs[job.id]))
    finally:
        if started_here:
            ray.shutdown()


class ClusterError(RuntimeError):
    """A Ray cluster cannot be reached or used; the message says what to fix."""


def connect_ray(address: str, timeout_s: float = 5.0) -> None:
    """``ray.init(address=...)``, failing within ``timeout_s`` with the fix instead of hanging on Ray's retries.

    ``host:port`` and ``ray://host:port`` are probed with a TCP connect first (nothing listening: one line at
    once); an authentication refusal names ``RAY_AUTH_MODE`` and the token (Ray ≥ 2.60 turns token auth on for
    ``ray start``).
    """
    import socket

    import ray

    target = address.removeprefix("ray://")
    if address != "auto" and ":" in target:
        host, _, port = target.rpartition(":")
        try:
            with socket.create_connection((host, int(port)), timeout=timeout_s):
                pass
        except (OSError, ValueError) as e:
            raise ClusterError(
                f"sweep --address {address}: nothing answers at {host}:{port} within {timeout_s:g} s ({e}); start "
                "the head with `ray start --head --port PORT` on that machine, or check the address"
            ) from None
    # Ray retries joining for ~20 s (NUM_REDIS_GET_RETRIES) whatever the reason; a refusal (no token) or a head that
    # is not Ray's is said within ~5 s instead, unless the user set the budget themselves.
    wait_var = "RAY_gcs_server_port_wait_time_s"
    set_here = wait_var not in os.environ
    if set_here:
        os.environ[wait_var] = "5"
    try:
        # The code travels with the jobs (nodes need Python and the pinned dependencies, not a checkout).
        pkg = str(Path(__file__).resolve().parents[1])
        env = {"py_modules": [pkg], "excludes": ["__pycache__", "*.pyc"]}
        ray.init(address=address, log_to_driver=False, runtime_env=env)
    except Exception as e:
        # Ray wraps the cause (an AuthenticationError inside a RuntimeError inside a ConnectionError): read them all.
        chain, x = [], e
        while x is not None and len(chain) < 8:
            chain.append(f"{type(x).__name__}: {' '.join(str(x).split())}")
            x = x.__cause__ or x.__context__
        text = " <- ".join(chain)
        if "invalidauthtoken" in text.lower() or "authenticationerror" in text.lower():
            raise ClusterError(
                f"sweep --address {address}: the cluster refused authentication (InvalidAuthToken); Ray 2.60's "
                "`ray start` enables token auth: export RAY_AUTH_MODE=token and the head's token (RAY_AUTH_TOKEN, "
                "or RAY_AUTH_TOKEN_PATH=<a copy of the head's ~/.ray/auth_token>) before the sweep; docs/cluster.md"
            ) from None
        raise ClusterError(f"sweep --address {address}: cannot join the cluster ({text[:300]})") from None
    finally:
        if set_here:
            os.environ.pop(wait_var, None)


def _on_every_node(nodes: list[dict], fn: Any, args: tuple, timeout_s: float) -> list[Any]:
    """``fn(*args)`` once on each of Ray's ``nodes`` (a zero-CPU task pinned to it); the answers in node order."""
    import ray
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    task = ray.remote(num_cpus=0, max_retries=0)(fn)
    refs = [
        task.options(scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False)).remote(*args)
        for n in nodes
    ]
    return ray.get(refs, timeout=timeout_s)


def _sees(base: dict, name: str) -> tuple[str, bool]:
    """On a node: where this node's jobs would keep results, and whether the driver's marker ``name`` is there."""
    cfg = load_config(base["preset"], overrides=base["overrides"])
    path = cfg.run_root / "sweeps" / name
    return str(path), path.exists()


def check_shared_results(cfg: Config, base: dict, timeout_s: float = 120.0) -> None:
    """On a cluster of more than one node, refuse to start unless every node's jobs see the driver's results
    folder: a job reads its inputs (encoders, oracles, data, caches) from, and writes its run to, the results
    folder as its node resolves it (``results_dir``, ``OMCRL_ROOT``). The driver writes a marker file; a task
    pinned to each node looks for it. One node (an embedded Ray, or a head alone) needs no check."""
    import uuid

    import ray

    nodes = [n for n in ray.nodes() if n.get("Alive")]
    if len(nodes) < 2:
        return
    name = f".shared-check-{uuid.uuid4().hex[:12]}"
    marker = cfg.run_root / "sweeps" / name
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.write_text("written by the sweep's driver\n")
    try:
        answers = _on_every_node(nodes, _sees, (base, name), timeout_s)
    finally:
        marker.unlink(missing_ok=True)
    blind = [f"{n.get('NodeManagerAddress', '?')} (looks in {path})" for n, (path, ok) in zip(nodes, answers) if not ok]
    if blind:
        raise ClusterError(
            f"sweep: {len(blind)} of {len(nodes)} nodes do not see the driver's results folder {cfg.run_root}: "
            + "; ".join(blind)
            + ". Jobs read and write runs there, so either set --set sweep.storage=URI (a folder or s3:// URI every "
            "node reaches; jobs then pull their inputs and push their runs) or mount a shared filesystem at the same "
            "path on every node; see docs/cluster.md"
        )


def _has_marker(uri: str, name: str) -> tuple[str, bool]:
    """On a node: its address, and whether the driver's marker ``name`` is visible in storage ``uri``."""
    import socket

    try:
        return socket.gethostname(), Storage(uri).has_marker(name)
    except Exception as e:  # an unreachable store or a missing fsspec driver on the node: report, do not hang
        return f"{socket.gethostname()} ({type(e).__name__}: {e})", False


def check_storage(store: Storage, timeout_s: float = 120.0) -> None:
    """Refuse to start unless a task on every live node sees a marker the driver wrote to ``store``."""
    import ray

    nodes = [n for n in ray.nodes() if n.get("Alive")]
    name = store.write_marker()
    try:
        answers = _on_every_node(nodes, _has_marker, (store.uri, name), timeout_s)
    finally:
        store.remove_marker(name)
    blind = [f"{n.get('NodeManagerAddress', '?')} [{who}]" for n, (who, ok) in zip(nodes, answers) if not ok]
    if blind:
        raise ClusterError(
            f"sweep.storage {store.uri}: {len(blind)} of {len(nodes)} nodes cannot see it: "
            + "; ".join(blind)
            + ". Use a location every node reaches (a shared mount at the same path, or an s3:// / gs:// URI with "
            "its fsspec driver installed on every node); see docs/cluster.md"
        )


def largest_node_cpus() -> int:
    """CPUs of the largest live node: a job asking more can never be scheduled, whatever the cluster's total."""
    import ray

    cpus = [n.get("Resources", {}).get("CPU", 0) for n in ray.nodes() if n.get("Alive")]
    return max(1, int(max(cpus, default=1)))


def sweep_stage(
    cfg: Config,
    grid: str | None = None,
    *,
    seeds: Sequence[int] | None = None,
    progress: bool = True,
    plan: bool = False,
    rates: str | None = None,
    rates_out: str | None = None,
    release: bool = False,
    backend: str = "ray",
    address: str | None = None,
    num_cpus: int | None = None,
    to_reference: bool = False,
    variants: Sequence[str] | None = None,
) -> str:
    """CLI stage ``sweep``: ``python -m omcrl sweep <grid|all> --preset P [--seeds 0,1,2] [--address A]
    [--backend B]``; writes each grid's table (:func:`run_ablations`) and returns its account. ``--plan`` prints
    the jobs and their cost (rates from ``--rates FILE.json``, else from this preset's finished sweeps) and runs
    nothing. ``--release-teachers`` only takes the kept weights of teachers whose students are all recorded out of
    the checkout (:func:`release_teachers`) and runs nothing."""
    if grid is None:
        raise ConfigError(f"stage 'sweep' needs a grid name, one of {[*GRIDS, 'all']}")
    # ``a,b``: several grids in turn (``table1,all``: Table I's training and then every ablation).
    grids = list(dict.fromkeys(g for name in grid.split(",") for g in (ABLATION_GRIDS if name == "all" else [name])))
    for g in grids:
        grid_variants(g)
    if release:
        released = [p for g in grids for p in release_teachers(cfg, g, seeds)]
        if not released:
            return "no teacher weights to release (none kept, a student still to record, or not yet committed)"
        return "\n".join(["released teacher weights (now read from git history):", *map(str, released)])
    if plan:
        if rates_out is not None and Path(rates_out).exists():
            raise ConfigError(
                f"--rates-out {rates_out}: the file exists; a plan's rates are written once, to a new file"
            )
        fast = None
        if rates is not None:
            r = json.loads(Path(rates).read_text(encoding="utf-8"))
            if not isinstance(r, dict) or not all(isinstance(v, int | float) and v > 0 for v in r.values()):
                raise ConfigError(f"--rates {rates}: expected a JSON object of positive rates per rate_key, got {r!r}")
        else:
            median, quartile = rate_maps(measured_rates(cfg))
            r, fast = median or None, quartile or None
        only = None if variants is None else {j.id for g in grids for j in only_variants(expand(cfg, g, seeds),
                                                                                          variants, g)}  # fmt: skip
        recorded = recorded_jobs(cfg, grids, seeds) if to_reference else set()
        text = describe_plan(cfg, grids, seeds, r, recorded=recorded, only=only, fast_rates=fast)
        if rates_out is not None:
            Path(rates_out).parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(Path(rates_out), json.dumps(r or {}, indent=1, sort_keys=True) + "\n")
            text += (
                f"\nrates written to {rates_out} (units per second per rate_key; --rates {rates_out} plans the same)"
            )
        return text
    out = run_ablations(cfg, grids, seeds, progress=progress, backend=backend, address=address, num_cpus=num_cpus,
                        to_reference=to_reference, variants=variants)  # fmt: skip
    text = "\n".join(repr(v["result"]) for v in out.values())
    bad = {g: v["result"].counts() for g, v in out.items() if set(v["result"].status.values()) & {"failed", "blocked"}}
    if bad:
        # Scripts must see it: the tables were written with the variants that finished, but the exit status is not 0.
        print(text)
        raise SweepFailed(
            "sweep: jobs failed or were blocked ("
            + "; ".join(f"{g}: {c.get('failed', 0)} failed, {c.get('blocked', 0)} blocked" for g, c in bad.items())
            + "); the tables leave those variants out; the logs above name each failure. Re-run the same command to "
            "finish only what is missing"
        )
    return text


class SweepFailed(RuntimeError):
    """Some jobs of a sweep failed or were blocked by a failed dependency (the rest finished)."""


def variant_runs(cfg: Config, res: SweepResult) -> dict[str, dict[int, Path]]:
    """``{variant label: {seed: run folder}}`` of a sweep's finished trainings, as the evaluation jobs find them
    (for learning curves)."""
    out: dict[str, dict[int, Path]] = {}
    for j in res.jobs:
        if j.kind != "evaluate":
            continue
        path = final_policy_path(job_config(cfg, j.overrides, j.seed), j.method)
        if path is not None:
            out.setdefault(j.label, {})[j.seed] = path.parent
    return out


# The planners Table I flies beside the learned methods: its two rows, and the local APF and the blind pilot (what
# NPE's guide and a pilot without sight reach in the same layouts): every planner method of the kit.
TABLE1_PLANNERS = tuple(PLANNERS)


def record_planners(cfg: Config, record: GridData, planners: Sequence[str] = TABLE1_PLANNERS) -> list[str]:
    """Fly each planner not yet in ``record`` once (training seed ``cfg.seeds[0]``: planners learn nothing) in
    every scene of ``cfg.eval.scenes`` and keep its episodes; returns the planners flown."""
    seed = cfg.seeds[0]
    todo = [p for p in planners if not record.has_episodes(p, seed)]
    for p in todo:
        df = evaluate_methods(cfg.with_seed(seed), {p: p})
        record.save_episodes(p, seed, df.assign(label=p, overrides=""))
    return todo


def run_ablations(
    cfg: Config,
    grids: Sequence[str],
    seeds: Sequence[int] | None = None,
    *,
    backend: str = "ray",
    address: str | None = None,
    num_cpus: int | None = None,
    progress: bool = True,
    to_reference: bool = False,
    variants: Sequence[str] | None = None,
) -> dict[str, dict[str, Any]]:
    """Run each grid (:func:`run_sweep`) and write its table (:func:`omcrl.eval.ablation.write_ablation`; a
    remedy grid also its verdicts, :func:`omcrl.eval.ablation.write_remedies`).

    ``to_reference``: keep each grid's data in the checkout as its jobs finish (:func:`grid_data_dir`; Table I's
    grid also the planners' episodes, flown once) and train only what is not kept there yet. ``variants``: only
    these variants of each grid (:func:`run_sweep`).

    Returns ``{grid: {"result": SweepResult, "table": aggregate table, "paths": written files}}``; a grid whose
    evaluations all failed has an empty table and no files.
    """
    for g in grids:
        grid_variants(g)  # every name checked before the first job runs
    out: dict[str, dict[str, Any]] = {}
    for g in grids:
        record = GridData(grid_data_dir(cfg, g)) if to_reference else None
        if record is not None and g in TABLE1_GRIDS:
            record_planners(job_config(cfg, TABLE1_GRIDS[g], cfg.seeds[0]), record)
        res = run_sweep(
            cfg,
            g,
            seeds,
            backend=backend,
            address=address,
            num_cpus=num_cpus,
            progress=progress,
            record=record,
            variants=variants,
        )
        if g in TABLE1_GRIDS:
            # Not an ablation: Table I itself comes from `python -m omcrl tables` (which adds the planners and
            # finds these runs and their evaluations cached).
            table, paths = pd.DataFrame(), {}
        elif len(res.episodes):
            order = [v.label for v in grid_variants(g)]  # the grid's order of its variants, not the alphabet's
            table = ablation_table(res.episodes, order=order)
            paths = write_ablation(res.episodes, cfg.run_root / "tables", g, order=order)
            if g in REMEDY_GRIDS and DEFAULT_VARIANT.label in set(res.episodes["label"]):
                paths.update(write_remedies(res.episodes, cfg.run_root / "tables", g)[2])
            if g == "precision":
                paths.update(write_precision(res.episodes, cfg.run_root / "tables")[1])
                # Training curves of each precision, mean over seeds with their CI (the "training curves").
                fig = plot_learning_curves(variant_runs(cfg, res))
                paths["curves"] = save_figure(fig, cfg.run_root / "figures", "precision_curves")
        else:
            table, paths = pd.DataFrame(), {}
        out[g] = {"result": res, "table": table, "paths": paths}
    return out
