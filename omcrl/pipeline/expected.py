"""How long each notebook takes, measured: the line every notebook prints when it starts, and the chain's hint.

Kept apart from :mod:`omcrl.pipeline.summary` so that the notebook runner can read it without importing PyTorch.
"""

from __future__ import annotations

import csv
import statistics

from omcrl.config import load_config, project_root
from omcrl.scenes import suite_of
from omcrl.utils.progress import format_duration

# Wall time (s) of each notebook from nothing trained, one seed, on the reference machine (2 CPU cores, no GPU),
# as `python -m omcrl notebooks` measured it; docs/performance.md has the table with its date and peak memory. Each
# notebook prints its line of this table when it starts (:func:`preset_banner`).
EXPECTED_WALL_S: dict[str, dict[str, float]] = {
    # 2026-12-02, `python -m omcrl notebooks --preset smoke`, venv present.
    "smoke": {
        "00_scenes": 9,
        "01_collect_data": 4,
        "02_pretrain_encoder": 9,
        "03_train_oracle": 7,
        "04_train_student": 12,
        "05_train_baselines": 8,
        "06_ablations": 10,
        "07_tables": 14,
        "08_interpretability": 30,
        "09_deploy_tello": 24,
    },
    # 2026-12-02, `./reproduce.sh --quick --skip 06` from a fresh clone; 06 the same day, `--only 06` after
    # `--from-reference` (no ablation run can be reused from the bundle: the sweep trains at its own budgets).
    "quick": {
        "00_scenes": 88,
        "01_collect_data": 11,
        "02_pretrain_encoder": 402,
        "03_train_oracle": 663,
        "04_train_student": 729,
        "05_train_baselines": 2392,
        "06_ablations": 3922,
        "07_tables": 220,
        "08_interpretability": 208,
        "09_deploy_tello": 34,
    },
}


# Notebooks whose time on the v2 suite differs from the v1 measurement above and is not made of grid jobs: measured on
# v2 (2026-12-05/06, quick, on the reference bundle, beside a grid run on both cores: upper bounds rather than idle).
SUITE_WALL_S: dict[str, dict[str, dict[str, float]]] = {
    "quick": {"v2": {"08_interpretability": 774, "09_deploy_tello": 90}},
}
# The methods notebook 07 flies from nothing cached (Table I's learned methods less the kit's controls): with the grid's
# measured evaluation times of the suite in use, its estimate is their sum.
NOTEBOOK_EVALUATION: dict[str, tuple[str, ...]] = {
    "07_tables": ("oracle", "ours", "ours-noOT", "npe", "npe-ot", "ours-lapf", "curl", "curl-phi", "ppo"),
}


def expected_time(preset: str, notebook: str) -> str:
    """One line: how long ``notebook`` (``"03_train_oracle"``) takes at ``preset`` on the reference machine, estimated
    as the chain's plan estimates it (:func:`notebook_estimate`: for the preset's scene suite and RL budget, from the
    Table I grid's measured jobs where they make up the notebook)."""
    cfg = load_config(preset)
    suite = suite_of(cfg.env.scene)
    wall, _ = notebook_estimate(preset, notebook, suite, cfg.rl.total_steps,
                                grid_training_seconds(preset, suite, cfg.rl.total_steps),
                                grid_evaluation_seconds(preset, suite))  # fmt: skip
    if wall is None:
        return f"{notebook} at preset {preset}: its time on a CPU was not measured (see docs/performance.md)"
    return (
        f"{notebook} at preset {preset}: about {format_duration(wall)} on a 2-core CPU from nothing trained, per "
        "seed (finished runs and cached evaluations are reused in seconds; docs/performance.md)"
    )


def notebook_estimate(
    preset: str,
    notebook: str,
    suite: str | None = None,
    rl_steps: int | None = None,
    train_s: dict[str, float] | None = None,
    eval_s: dict[str, float] | None = None,
) -> tuple[float | None, str]:
    """``(seconds, note)``: the estimate of ``notebook`` at ``preset`` (None when nothing measured it) and what it
    rests on. A training notebook: the sum of the measured training seconds ``train_s`` (``{method: s}``) of the
    methods it trains (:data:`NOTEBOOK_TRAINING`) when all are given, else its wall time (:data:`EXPECTED_WALL_S`)
    scaled by ``rl_steps`` / :data:`MEASURED_RL_STEPS`; notebook 07: the sum of the measured evaluation seconds
    ``eval_s`` of the methods it flies (:data:`NOTEBOOK_EVALUATION`) when all are given; any other: its measured wall
    time on ``suite`` (:data:`SUITE_WALL_S`), else on the suite of :data:`EXPECTED_WALL_S`."""
    train_s, eval_s = train_s or {}, eval_s or {}
    methods = NOTEBOOK_TRAINING.get(notebook, ())
    if methods and all(m in train_s for m in methods):
        return sum(
            train_s[m] for m in methods
        ), f"  (training {', '.join(methods)}: the grid's measured times at this budget)"
    flown = NOTEBOOK_EVALUATION.get(notebook, ())
    if flown and all(m in eval_s for m in flown):
        return sum(eval_s[m] for m in flown), f"  (flying {len(flown)} methods: the grid's measured evaluation times)"
    wall = SUITE_WALL_S.get(preset, {}).get(suite or "", {}).get(notebook)
    if wall is not None:
        return wall, f"  (measured on {suite})"
    wall = EXPECTED_WALL_S.get(preset, {}).get(notebook)
    base_steps = MEASURED_RL_STEPS.get(preset)
    if wall is not None and notebook in TRAINING_NOTEBOOKS and rl_steps and base_steps and rl_steps != base_steps:
        return wall * rl_steps / base_steps, f"  (measured at {base_steps:,} env steps per run, scaled to {rl_steps:,})"
    return wall, ""


# The env steps per training run the times above were measured at (quick: the v1 suite's budget on 2026-12-02; the
# v2 budget check tripled quick's rl.total_steps to 450,560). The training notebooks' times scale with it.
MEASURED_RL_STEPS: dict[str, int] = {"smoke": 512, "quick": 151_552}
# The methods each training notebook trains (one seed each): with the grid's measured training times of the suite in
# use, its estimate is their sum (notebooks 03-05 train these; 06 trains its sweeps at their own budgets).
NOTEBOOK_TRAINING: dict[str, tuple[str, ...]] = {
    "03_train_oracle": ("oracle",),
    "04_train_student": ("ours", "ours-noOT"),
    "05_train_baselines": ("ppo", "npe", "npe-ot", "ours-lapf", "curl", "curl-phi"),
}
TRAINING_NOTEBOOKS = (*NOTEBOOK_TRAINING, "06_ablations")


def chain_plan(
    preset: str,
    chain: list[str],
    rl_steps: int | None = None,
    train_s: dict[str, float] | None = None,
    eval_s: dict[str, float] | None = None,
    suite: str | None = None,
) -> list[str]:
    """What the chain will do and about how long it takes: one line per notebook of ``chain`` with its estimate at
    ``preset`` (:func:`notebook_estimate`, the same estimate each notebook's banner prints), then the total.
    Estimates, not promises: from nothing trained, one seed, on the reference 2-core CPU; finished runs and cached
    evaluations are reused in seconds."""
    lines = [f"plan, preset {preset} (from nothing trained, one seed, a 2-core CPU; docs/performance.md):"]
    total, unknown = 0.0, []
    for n in chain:
        wall, note = notebook_estimate(preset, n, suite, rl_steps, train_s, eval_s)
        if wall is None:
            unknown.append(n)
            lines.append(f"  {n:22s} not measured")
            continue
        total += wall
        lines.append(f"  {n:22s} ~{format_duration(wall)}{note}")
    tail = f" + {len(unknown)} not measured" if unknown else ""
    lines.append(f"  {'total':22s} ~{format_duration(total)}{tail}")
    return lines


def grid_training_seconds(preset: str, suite: str | None, rl_steps: int) -> dict[str, float]:
    """``{method: s}``: the median seconds of the Table I grid's finished training jobs of ``suite`` at ``rl_steps``
    env steps (``reference/<preset>/table1-<suite>/jobs.csv``, measured on the 2-core machine, often beside other
    work); empty when there is no such file or no job at that budget."""
    return _grid_job_seconds(preset, suite, "train", rl_steps)


def grid_evaluation_seconds(preset: str, suite: str | None) -> dict[str, float]:
    """``{method: s}``: the median seconds of the Table I grid's finished evaluation jobs of ``suite`` (every scene of
    Table I at its layouts; ``reference/<preset>/table1-<suite>/jobs.csv``); empty when there is no such file."""
    return _grid_job_seconds(preset, suite, "evaluate")


def _grid_job_seconds(preset: str, suite: str | None, kind: str, work: int | None = None) -> dict[str, float]:
    """Median seconds per method of the Table I grid's finished jobs of ``kind`` (of ``work`` units, when given)."""
    path = project_root() / "reference" / preset / f"table1-{suite}" / "jobs.csv"
    if suite is None or not path.exists():
        return {}
    times: dict[str, list[float]] = {}
    with path.open(newline="") as fh:
        for r in csv.DictReader(fh):
            if r["kind"] == kind and r["status"] == "done" and (work is None or int(float(r["work"])) == work):
                times.setdefault(r["method"], []).append(float(r["seconds"]))
    return {m: statistics.median(v) for m, v in times.items()}
