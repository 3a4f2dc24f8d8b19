"""Ablation tables (paper VI-C): a sweep's evaluation episodes aggregated per variant and scene, with CIs.

:func:`write_ablation` writes ``tables/ablation_<grid>.{csv,md,tex}`` in Table I's layout (variants as rows,
mean ± CI half-width over seeds and episodes); the ``sequential`` grid is also written as ``table2.*`` (paper
Table II) and the ``decay`` grid as ``table3.*`` (Table III).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from omcrl.eval.stats import aggregate
from omcrl.utils.io import atomic_write_text

PAPER_TABLES = {"sequential": "table2", "decay": "table3"}


def ablation_table(episodes: pd.DataFrame, reps: int = 2000) -> pd.DataFrame:
    """Metrics with 95 % CIs per variant (``label``) and scene: :func:`omcrl.eval.stats.aggregate` by
    (label, scene), index renamed (method, scene) so Table I's writers apply."""
    ep = episodes.drop(columns=["method"]).rename(columns={"label": "method"})
    return aggregate(ep, ("method", "scene"), reps=reps)


def write_ablation(episodes: pd.DataFrame, directory: str | Path, grid: str, reps: int = 2000) -> dict[str, Path]:
    """Write the ablation table of ``grid`` (and its paper-table copy); returns the paths by suffix."""
    from omcrl.eval.table1 import _latex, _markdown, table1_frames

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    table = ablation_table(episodes, reps)
    long, wide = table1_frames(table)
    seeds = int(table["seeds"].max()) if len(table) else 0
    note = (
        f"Ablation `{grid}`: mean ± half-width of the 95% CI over {seeds} training seed(s) and the evaluation "
        "episodes. NE m, OS/SR/CR %, SPL 0-1, TTS steps. Bold: best variant.\n\n"
    )
    paths: dict[str, Path] = {}
    for name in (f"ablation_{grid}", PAPER_TABLES.get(grid)):
        if name is None:
            continue
        for suffix, text in (
            ("csv", long.to_csv(index=False)),
            ("md", note + _markdown(wide, {})),
            ("tex", _latex(wide, {})),
        ):
            path = d / f"{name}.{suffix}"
            atomic_write_text(path, text)
            paths[f"{name}.{suffix}"] = path
    return paths
