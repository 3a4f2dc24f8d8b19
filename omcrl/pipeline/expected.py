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
