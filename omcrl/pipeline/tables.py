"""CLI stage ``tables``: Table I evaluated here, or rebuilt from a grid's records in the checkout, or the ablations'
tables and figures from theirs. The CLI finds it through :mod:`omcrl.pipeline.registry`.
"""

from __future__ import annotations

from omcrl.config import Config, ConfigError
from omcrl.eval.table1 import Table1Result
from omcrl.eval.table1 import tables_stage as evaluate_tables
from omcrl.pipeline.ablations import AblationResult, ablations_from_reference
from omcrl.pipeline.griddata import tables_from_reference
from omcrl.pipeline.grids import TABLE1_GRIDS
from omcrl.pipeline.why import write_why_tables

# ``tables --grid ablations``: the six ablation grids together (their findings are judged as one family).
ABLATIONS = "ablations"


def tables_stage(
    cfg: Config, *, from_reference: bool = False, grid: str = "table1", progress: bool = True
) -> Table1Result | AblationResult:
    """CLI stage ``tables``: evaluate every finished run and write Table I (:func:`omcrl.eval.table1.tables_stage`),
    or with ``--from-reference`` rebuild it from the data of ``grid`` in the checkout (:func:`omcrl.pipeline.
    griddata.tables_from_reference`; for ``table1`` also the attribution and the teacher's ceiling,
    :func:`omcrl.pipeline.why.write_why_tables`); ``--grid ablations --from-reference``: Tables II–III, Figs. 7–10
    and the six findings from the ablation grids' data (:func:`omcrl.pipeline.ablations.ablations_from_reference`).
    """
    known = [*TABLE1_GRIDS, ABLATIONS]
    if grid not in known:
        raise ConfigError(f"tables: got grid {grid!r}, expected one of {known}")
    if grid != "table1" and not from_reference:
        raise ConfigError(f"tables: --grid {grid} reads that grid's recorded data; add --from-reference")
    if grid == ABLATIONS:
        return ablations_from_reference(cfg)
    if from_reference:
        result = tables_from_reference(cfg, grid)
        if grid == "table1":  # the attribution of the zero-shot gap and the teacher's ceiling, beside Table I
            write_why_tables(cfg.preset, cfg.run_root / "tables")
        return result
    return evaluate_tables(cfg, progress=progress)
