"""Sweep plans: a grid (:mod:`omcrl.pipeline.grids`) × seeds expanded into jobs with dependencies, their work
in env steps, episodes and iterations, what each job asks of a node, and the hours a plan takes at measured rates.

    collect ─► pretrain (frozen-encoder methods) ─┐
                         train oracle (guided) ────┴─► train method ─► evaluate

A job's id is the identity of what it makes: pretraining and oracle jobs take the run folder the registry gives
them (:mod:`omcrl.runs`), so variants that share an encoder or an oracle share one job.
"""

from __future__ import annotations

import hashlib
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from omcrl.config import (
    UNTRAINED_ENCODERS,
    Config,
    ConfigError,
    config_hash,
    load_config,
    overrides_from_config,
    parse_override,
    project_root,
    section_identity,
)
from omcrl.pipeline.grids import ABLATION_GRIDS, FULL_BUDGET_GRIDS, grid_variants
from omcrl.pretrain.train import pretrain_run
from omcrl.rl.methods import encoder_config, get_method
from omcrl.rl.train import oracle_run
from omcrl.runs import read_identity, read_metrics, training_seconds
from omcrl.utils.runtime import cpu_count

KINDS = ("collect", "pretrain", "train", "evaluate")


@dataclass(frozen=True)
class Job:
    """One unit of work: ``kind`` of ``method`` at ``seed`` under ``overrides``; ``deps`` are job ids."""

    id: str
    kind: str
    method: str
    seed: int
    overrides: tuple[str, ...]
    deps: tuple[str, ...] = ()
    label: str = ""

    @property
    def log_name(self) -> str:
        """A file name for the job's log (ids hold ``/``)."""
        h = hashlib.sha1(self.id.encode()).hexdigest()[:8]
        return f"{self.kind}-{self.method}-seed{self.seed}-{h}.log"


def job_config(base: Config, overrides: Sequence[str], seed: int) -> Config:
    """``base`` with ``overrides`` applied, at ``seed``. ``field*=k`` sets a number to k times its value under
    the overrides before it (``data.episodes*=3``: three times the preset's episodes), rounded for integers."""
    resolved = _scaled(base, overrides)
    cfg = load_config(base.preset, overrides=[*base_overrides(base), *resolved])
    for o in resolved:
        parse_override(o)  # a malformed override fails here, with its text
    return cfg.with_seed(seed)


def _scaled(base: Config, overrides: Sequence[str]) -> list[str]:
    """``overrides`` with every ``field*=k`` replaced by ``field=<k × current value>``."""
    out: list[str] = []
    for o in overrides:
        key, sep, factor = o.partition("*=")
        if not sep or "=" in key:
            out.append(o)
            continue
        cur: Any = load_config(base.preset, overrides=[*base_overrides(base), *out])
        for part in key.strip().split("."):
            if not hasattr(cur, part):
                raise ConfigError(f"override {o!r}: config field {key.strip()!r} does not exist")
            cur = getattr(cur, part)
        try:
            k = float(factor)
        except ValueError:
            raise ConfigError(f"override {o!r}: expected a number after '*=', got {factor!r}") from None
        if isinstance(cur, bool) or not isinstance(cur, int | float):
            raise ConfigError(f"override {o!r}: '*=' needs a numeric field, {key.strip()!r} is {cur!r}")
        out.append(f"{key.strip()}={round(cur * k) if isinstance(cur, int) else cur * k}")
    return out


def base_overrides(cfg: Config) -> list[str]:
    """The overrides that turn the preset into ``cfg`` (every field that differs), so jobs rebuild it anywhere."""
    return list(overrides_from_config(cfg))


def budget_overrides(cfg: Config) -> tuple[str, ...]:
    """Overrides that give sweep runs the budgets of ``cfg.sweep`` (none at 0): RL env steps, with the α decays
    (the students' and the oracle's) scaled by the same ratio so guidance fades over the same share of training,
    and pretraining iterations."""
    out = []
    if cfg.sweep.rl_steps:
        ratio = cfg.sweep.rl_steps / cfg.rl.total_steps
        out.append(f"rl.total_steps={cfg.sweep.rl_steps}")
        for section in ("rl", "oracle"):  # every guidance decay scales, the student's and the oracle's
            decay = getattr(cfg, section).alpha_decay_steps
            out.append(f"{section}.alpha_decay_steps={max(1, round(decay * ratio))}")
    if cfg.sweep.pretrain_iterations:
        out.append(f"pretrain.iterations={cfg.sweep.pretrain_iterations}")
    return tuple(out)


def expand(cfg: Config, grid: str, seeds: Sequence[int] | None = None) -> list[Job]:
    """The jobs of ``grid`` at ``seeds`` (default ``cfg.seeds``), in an order that respects dependencies.

    Every variant's config is resolved (and validated) here, before any work starts. Budgets come from
    ``cfg.sweep`` (:func:`budget_overrides`), applied before the variant's own overrides.
    """
    seeds = list(seeds if seeds is not None else cfg.seeds)
    budget = () if grid in FULL_BUDGET_GRIDS else budget_overrides(cfg)
    jobs: dict[str, Job] = {}

    def add(job: Job) -> str:
        jobs.setdefault(job.id, job)
        return job.id

    for v in grid_variants(grid):
        overrides = (*budget, *v.overrides)
        spec = get_method(v.method)
        if not spec.learned:
            raise ConfigError(f"sweep {grid}: variant {v.label!r} uses planner {v.method!r}; sweeps train methods")
        for s in seeds:
            c = job_config(cfg, overrides, s)
            deps: list[str] = []
            oracle = Job(f"train:{oracle_run(c).dir}", "train", "oracle", s, overrides)
            if spec.recipe.pretrained:
                enc_cfg = encoder_config(c, spec)
                if enc_cfg.pretrain.method in UNTRAINED_ENCODERS:  # a control's encoder needs no data
                    col: tuple[str, ...] = ()
                else:
                    # Data flown partly by the oracle (data.policy=oracle) waits for that oracle.
                    by_oracle = c.data.policy == "oracle"
                    col = (
                        add(
                            Job(
                                f"collect:{c.data_path}",
                                "collect",
                                v.method,
                                s,
                                overrides,
                                (add(oracle),) if by_oracle else (),
                            )
                        ),
                    )
                enc_run = pretrain_run(enc_cfg)
                deps.append(add(Job(f"pretrain:{enc_run.dir}", "pretrain", v.method, s, overrides, col)))
            if spec.guide == "oracle" or spec.recipe.teacher:
                deps.append(add(oracle))
            if not spec.recipe.teacher:
                # Dependencies by their ids without this machine's project root, and the sections by the one identity
                # rule unresolved (no "auto" decided by this machine): the same job has the same id (and sweep-storage
                # key) on every machine, and a field added at its default changes none.
                portable = [d.replace(str(project_root()), "<root>") for d in deps]
                rl, env = section_identity(c.rl), section_identity(c.env)
                ident = {"method": v.method, "rl": rl, "env": env, "deps": portable, "seed": s}
                ident |= spec.recipe.job_identity(c)
                tid = add(Job(f"train:{v.method}:{config_hash(ident)}", "train", v.method, s, overrides, tuple(deps)))
            else:
                tid = deps[-1]
            add(Job(f"evaluate:{v.label}:{tid}", "evaluate", v.method, s, overrides, (tid,), v.label))
    return list(jobs.values())


# Work units per job kind (what a rate in :func:`sweep_cost` is per second of).
UNITS = {"collect": "episodes", "pretrain": "iterations", "train": "env steps", "evaluate": "episodes"}


def sweep_plan(cfg: Config, grids: Sequence[str] | None = None, seeds: Sequence[int] | None = None) -> pd.DataFrame:
    """Every distinct job of ``grids`` (default: all six ablation grids) at ``seeds``, with its work.

    Jobs that several grids share (the same run folder) are counted once, in the order of a valid schedule.

    Returns
    -------
    DataFrame, one row per job: ``id, kind, method, seed, grids`` (the grids that need it), ``rate_key``
    (``collect | pretrain | train:<features> | evaluate``), ``work`` (in :data:`UNITS` of its kind),
    ``table1`` (True where a Table I run of the same config is the same job), ``deps`` (ids).
    """
    grids = list(grids or ABLATION_GRIDS)
    for g in grids:
        grid_variants(g)
    jobs: dict[str, Job] = {}
    used: dict[str, list[str]] = {}
    for g in grids:
        for j in expand(cfg, g, seeds):
            jobs.setdefault(j.id, j)
            used.setdefault(j.id, []).append(g)
    # The main comparison's jobs under the same budgets: a sweep finds those runs finished when it coincides.
    # The main comparison runs at the preset's own budgets, not the sweep's.
    full = load_config(cfg.preset, overrides=[*base_overrides(cfg), "sweep.rl_steps=0", "sweep.pretrain_iterations=0"])
    main = {j.id for j in expand(full, "table1", seeds) if j.kind != "evaluate"}
    rows = [
        {"id": w.id, "kind": w.kind, "method": w.method, "seed": w.seed, "grids": ",".join(used[w.id]),
         "rate_key": w.rate_key, "work": w.work, "table1": w.id in main, "deps": w.deps}
        for w in work_rows(cfg, list(jobs.values()))
    ]  # fmt: skip
    return pd.DataFrame(rows)


@dataclass(frozen=True)
class _Work:
    id: str
    kind: str
    method: str
    seed: int
    rate_key: str
    work: int
    deps: tuple[str, ...]


def work_rows(cfg: Config, jobs: Sequence[Job]) -> list[_Work]:
    """Each job's rate key and amount of work (see :data:`UNITS`)."""
    out = []
    for j in jobs:
        c = job_config(cfg, j.overrides, j.seed)
        if j.kind == "collect":
            key, work = "collect", c.data.episodes
        elif j.kind == "pretrain":
            enc = encoder_config(c, j.method).pretrain
            key, work = "pretrain", 0 if enc.method in UNTRAINED_ENCODERS else enc.iterations
        elif j.kind == "train":
            key, work = f"train:{get_method(j.method).features}", c.rl.total_steps
        else:
            key, work = "evaluate", c.eval.episodes * len(c.eval.scenes)
        out.append(_Work(j.id, j.kind, j.method, j.seed, key, int(work), j.deps))
    return out


def sweep_cost(plan: pd.DataFrame, rates: dict[str, float], nodes: int = 1) -> dict[str, Any]:
    """Estimated cost of ``plan`` (:func:`sweep_plan`) from measured per-job rates, on ``nodes`` equal machines.

    ``rates`` maps each ``rate_key`` of the plan to units per second on one machine running one job at a time
    (e.g. a trainer's env steps/s from ``python -m omcrl.bench rl``). Each job occupies one machine; the schedule is
    event-driven, a job starting when its dependencies are done and a machine is free (what Ray does with
    one job's worth of CPUs per node): whenever a machine is free it takes the first ready job.

    Returns
    -------
    ``{"jobs", "machine_hours", "wall_hours", "by_key"}``: total machine time and the schedule's makespan (h), and
    ``{rate_key: (jobs, hours)}``. A rate_key missing from ``rates`` is a ConfigError naming it.
    """
    if nodes < 1:
        raise ConfigError(f"sweep_cost: nodes must be >= 1, got {nodes}")
    if not len(plan):
        return {"jobs": 0, "machine_hours": 0.0, "wall_hours": 0.0, "by_key": {}}
    missing = sorted(set(plan["rate_key"]) - set(rates))
    if missing:
        raise ConfigError(f"sweep_cost: no rate for {missing}; rates given for {sorted(rates)}")
    import heapq

    sec = {r.id: r.work / float(rates[r.rate_key]) for r in plan.itertuples()}
    deps = {r.id: set(r.deps) & set(sec) for r in plan.itertuples()}
    by_key: dict[str, list[float]] = {}
    for r in plan.itertuples():
        k = by_key.setdefault(r.rate_key, [0, 0.0])
        k[0] += 1
        k[1] += sec[r.id] / 3600
    # Event-driven list scheduling: whenever a machine is free, it takes the first job (plan order) that is ready.
    waiting, done, now, free = list(sec), set(), 0.0, nodes
    running: list[tuple[float, str]] = []
    while waiting or running:
        for jid in [j for j in waiting if deps[j] <= done]:
            if not free:
                break
            waiting.remove(jid)
            heapq.heappush(running, (now + sec[jid], jid))
            free -= 1
        if not running:
            raise ConfigError(f"sweep_cost: jobs {waiting[:3]} wait for dependencies that never finish")
        now, jid = heapq.heappop(running)
        done.add(jid)
        free += 1
    return {
        "jobs": len(plan),
        "machine_hours": sum(v[1] for v in by_key.values()),
        "wall_hours": now / 3600,
        "by_key": {k: (int(v[0]), v[1]) for k, v in by_key.items()},
    }


def job_cpus(cfg: Config, job: Job) -> int:
    """CPUs a job keeps busy: its env processes (training, collection), threads (pretraining) or workers."""
    if job.kind == "train":
        return max(1, cfg.rl.n_envs)
    if job.kind == "collect":
        return max(1, cfg.data.n_envs)
    if job.kind == "pretrain":
        return max(1, cfg.pretrain.num_threads)
    return max(1, cfg.eval.workers or cpu_count())


def job_gpus(cfg: Config, job: Job) -> int:
    """GPUs a job asks Ray for: one for training and pretraining when its section says ``device=cuda`` (so
    paper-preset jobs are steered to GPU nodes and never share a GPU unasked), else none. ``auto`` asks for none:
    the driver cannot know whether the node it lands on has a GPU."""
    device = {"train": cfg.rl.device, "pretrain": cfg.pretrain.device}.get(job.kind)
    return 1 if device == "cuda" else 0


def measured_rates(cfg: Config, grids: Sequence[str] | None = None) -> pd.DataFrame:
    """Rates (work units per second, see :data:`UNITS`) of the jobs that really ran in this preset's sweeps.

    Reads ``results/<preset>/sweeps/<grid>/jobs.csv`` for ``grids`` (default: every grid that has one) and the
    ``jobs.csv`` committed beside each grid's data (``reference/<preset>/<grid>-<suite>/``, so a fresh checkout has
    the rates its grids measured); cached jobs are left out. A training kind that no ``jobs.csv`` measured is rated
    from the recorded runs' own clocks (:func:`recorded_training_times`). Returns one row per ``rate_key``: ``jobs``,
    ``median_s`` (per job), ``rate`` (median of work / seconds) and ``rate_fast`` (its upper quartile: jobs that
    shared the machine with another ran at a fraction of the rate of one that had it alone, so the median prices a
    run beside other work and the upper quartile one alone).
    """
    root, shipped = cfg.run_root / "sweeps", project_root() / "reference" / cfg.preset
    files = [root / g / "jobs.csv" for g in grids] if grids else sorted(root.glob("*/jobs.csv"))
    patterns = [f"{g}-*" for g in grids] if grids else ["*"]
    for pattern in patterns:
        files += sorted(shipped.glob(f"{pattern}/jobs.csv"))
    frames = [pd.read_csv(f) for f in files if f.exists()]
    df = pd.concat(frames).drop_duplicates("id") if frames else pd.DataFrame(columns=JOB_COLUMNS)
    df = df[(df["status"] == "done") & (df["seconds"] > 0)]
    own = pd.DataFrame(
        [r for pattern in patterns for d in sorted(shipped.glob(pattern)) for r in recorded_training_times(d)],
        columns=JOB_COLUMNS,
    )
    df = pd.concat([df, own[~own["rate_key"].isin(set(df["rate_key"]))].drop_duplicates("id")])
    if df.empty:
        return pd.DataFrame(columns=["rate_key", "jobs", "median_s", "rate", "rate_fast"])
    df = df.assign(rate=df["work"] / df["seconds"])
    out = df.groupby("rate_key").agg(
        jobs=("id", "size"), median_s=("seconds", "median"), rate=("rate", "median"),
        rate_fast=("rate", lambda r: r.quantile(0.75)),
    )  # fmt: skip
    return out.reset_index()


JOB_COLUMNS = ["id", "status", "seconds", "rate_key", "work"]


def rate_maps(rates: pd.DataFrame) -> tuple[dict[str, float], dict[str, float]]:
    """:func:`measured_rates`' rows as ``{rate_key: units/s}``: at the median, and at the upper quartile (a machine
    to itself), the forms :func:`sweep_cost` and :func:`describe_plan` take."""
    keys = rates["rate_key"]
    return dict(zip(keys, rates["rate"], strict=True)), dict(zip(keys, rates["rate_fast"], strict=True))


def recorded_training_times(grid_dir: Path) -> list[dict]:
    """One ``jobs.csv``-like row per training run recorded under a grid's data folder (``<label>/seed<k>/rl/``):
    its seconds are the sum of the ``rollout_s`` and ``update_s`` its PPO updates logged (start-up and the
    evaluation left out), its work the last step logged.

    For runs that no sweep timed: a teacher laid out from kept weights, or one trained before its grid recorded
    job times. Runs recorded under several labels count once (``id``: the run's key and seed).
    """
    rows = []
    for path in sorted(grid_dir.glob("*/seed*/rl/metrics.csv.gz")):
        rec = read_identity(path.parent) or {}
        m = read_metrics(path)
        seconds = training_seconds(m)
        if seconds <= 0 or rec.get("method") is None:
            continue
        key = f"train:{get_method(rec['method']).features}"
        rows.append({"id": f"run:{rec.get('key')}:seed{rec.get('seed')}", "status": "done", "seconds": float(seconds),
                     "rate_key": key, "work": int(m["step"].max())})  # fmt: skip
    return rows


def describe_plan(
    cfg: Config,
    grids: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    rates: dict[str, float] | None = None,
    nodes: Sequence[int] = (1, 4, 16),
    recorded: Collection[str] = (),
    only: Collection[str] | None = None,
    fast_rates: dict[str, float] | None = None,
) -> str:
    """A plain-text account of :func:`sweep_plan`: jobs and work per kind, what the main comparison already ran,
    and, with ``rates`` (units/s per rate_key on one machine), :func:`sweep_cost` on each number of ``nodes``.
    ``recorded``: ids of jobs whose results the checkout already keeps (``--to-reference``); they are left out.
    ``only``: the ids of the jobs to count (``--variants``); None: every job of the grids. ``fast_rates``: the
    same keys at the rate of a machine to itself (:func:`measured_rates`' ``rate_fast``): one more line, the cost
    on one machine at those rates, so the plan gives a range rather than one figure."""
    plan = sweep_plan(cfg, grids, seeds)
    if only is not None:
        plan = plan[plan["id"].isin(list(only))]
    seeds = list(seeds if seeds is not None else cfg.seeds)
    kept = plan["id"].isin(list(recorded))
    plan = plan[~kept]
    lines = [
        f"sweep plan, preset {cfg.preset}, seeds {seeds}, grids {list(grids or ABLATION_GRIDS)}: {len(plan)} jobs "
        f"({int(plan['table1'].sum())} of them are runs of the main comparison, found finished once Table I ran)",
    ]
    if kept.any():
        lines.append(f"  {int(kept.sum())} more jobs are recorded in the checkout (reference/): not run again")
    lines.append("  rate_key        jobs  work")
    for key, g in plan.groupby("rate_key", sort=False):
        unit = UNITS[g["kind"].iloc[0]]
        lines.append(f"  {key:<15} {len(g):>4}  {int(g['work'].sum()):,} {unit} ({int(g['table1'].sum())} shared)")
    if rates:
        # With the table1 grid in the plan, Table I's own runs are work to do; else they are assumed done.
        whole = "table1" in (grids or ())
        new = plan if whole else plan[~plan["table1"]]
        which = "every job, Table I's included" if whole else "the jobs not shared with the main comparison"
        unrated = new[~new["rate_key"].isin(list(rates))]
        if len(unrated):
            # Said, not guessed: those jobs are left out of the hours (collection is minutes at quick).
            lines.append(
                "  no measured rate for "
                + ", ".join(
                    f"{k} ({len(g)} jobs, {int(g['work'].sum()):,} {UNITS[g['kind'].iloc[0]]})"
                    for k, g in unrated.groupby("rate_key")
                )
                + ": left out of the hours below (measure with python -m omcrl.bench cost --rates-out FILE)"
            )
            new = new[new["rate_key"].isin(list(rates))]
        by = sweep_cost(new, rates, 1)["by_key"]
        lines.append(f"  machine-hours ({which}): " + ", ".join(f"{k} {h:,.1f}" for k, (_, h) in by.items()))
        for n in nodes:
            c = sweep_cost(new, rates, n)
            lines.append(
                f"  on {n} machine(s): {c['machine_hours']:.1f} machine-hours, {c['wall_hours']:.1f} h wall ({which})"
            )
        if fast_rates and set(new["rate_key"]) <= set(fast_rates):
            c = sweep_cost(new, fast_rates, 1)
            lines.append(
                f"  at the upper quartile of the measured rates (a machine to itself): {c['machine_hours']:.1f} "
                "machine-hours on 1 machine"
            )
    else:
        lines.append(
            "  no rates, so no hours: finished sweeps of this preset record theirs (sweeps/<grid>/jobs.csv) and are "
            "used when present; or measure this machine: python -m omcrl.bench cost --rates-out rates.json, then "
            "--plan --rates rates.json"
        )
    return "\n".join(lines)
