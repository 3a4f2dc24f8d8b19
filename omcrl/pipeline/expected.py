"""How long each notebook takes, measured: the line every notebook prints when it starts, and the chain's hint.

Kept apart from :mod:`omcrl.pipeline.summary` so that the notebook runner can read it without importing PyTorch.
"""

from __future__ import annotations

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


def expected_time(preset: str, notebook: str) -> str:
    """One line: how long ``notebook`` (``"03_train_oracle"``) takes at ``preset`` on the reference machine."""
    wall = EXPECTED_WALL_S.get(preset, {}).get(notebook)
    if wall is None:
        return f"{notebook} at preset {preset}: its time on a CPU was not measured (see docs/performance.md)"
    return (
        f"{notebook} at preset {preset}: about {format_duration(wall)} on a 2-core CPU from nothing trained, per "
        "seed (finished runs and cached evaluations are reused in seconds; docs/performance.md)"
    )


# The env steps per training run the times above were measured at (quick: the v1 suite's budget on 2026-12-02; the
# v2 budget check tripled quick's rl.total_steps to 450,560). The training notebooks' times scale with it.
MEASURED_RL_STEPS: dict[str, int] = {"smoke": 512, "quick": 151_552}
TRAINING_NOTEBOOKS = ("03_train_oracle", "04_train_student", "05_train_baselines", "06_ablations")


def chain_plan(preset: str, chain: list[str], rl_steps: int | None = None) -> list[str]:
    """What the chain will do and about how long it takes: one line per notebook of ``chain`` with its estimate at
    ``preset`` (:data:`EXPECTED_WALL_S`; a training notebook's scaled by ``rl_steps`` / :data:`MEASURED_RL_STEPS`
    when the run's budget differs from the one measured), then the total. Estimates, not promises: from nothing
    trained, one seed, on the reference 2-core CPU; finished runs and cached evaluations are reused in seconds."""
    measured = EXPECTED_WALL_S.get(preset, {})
    base_steps = MEASURED_RL_STEPS.get(preset)
    scale = rl_steps / base_steps if rl_steps and base_steps and rl_steps != base_steps else 1.0
    lines = [f"plan, preset {preset} (from nothing trained, one seed, a 2-core CPU; docs/performance.md):"]
    total, unknown = 0.0, []
    for n in chain:
        wall = measured.get(n)
        if wall is None:
            unknown.append(n)
            lines.append(f"  {n:22s} not measured")
            continue
        note = ""
        if n in TRAINING_NOTEBOOKS and scale != 1.0:
            wall *= scale
            note = f"  (measured at {base_steps:,} env steps per run, scaled to {rl_steps:,})"
        total += wall
        lines.append(f"  {n:22s} ~{format_duration(wall)}{note}")
    tail = f" + {len(unknown)} not measured" if unknown else ""
    lines.append(f"  {'total':22s} ~{format_duration(total)}{tail}")
    return lines
