"""Evaluation: episode metrics (NE OS SR SPL CR TTS, paper V-B), the evaluation runner and tables.

``evaluate_stage(cfg)`` is the CLI stage ``python -m omcrl evaluate``: every trained oracle/student policy under
``<run_root>/runs`` plus Hybrid APF in all evaluation scenes, tables under ``<run_root>/tables``.
"""

from omcrl.agent import start_episode
from omcrl.eval.metrics import (
    GLOSSARY,
    METRICS,
    episode_values,
    format_table,
    glossary_markdown,
    summarize,
    summary_table,
)
from omcrl.eval.runner import EvalPool, eval_seeds, evaluate
from omcrl.eval.stage import EvalResult, evaluate_methods, evaluate_stage, find_policies, to_markdown, write_tables
from omcrl.eval.stats import aggregate, compare_sr, mean_ci
from omcrl.eval.table1 import Table1Result, evaluate_grid, paper_table1, write_table1

__all__ = [
    "GLOSSARY",
    "METRICS",
    "EvalPool",
    "EvalResult",
    "Table1Result",
    "aggregate",
    "compare_sr",
    "episode_values",
    "eval_seeds",
    "evaluate",
    "evaluate_grid",
    "evaluate_methods",
    "evaluate_stage",
    "find_policies",
    "format_table",
    "glossary_markdown",
    "mean_ci",
    "paper_table1",
    "start_episode",
    "summarize",
    "summary_table",
    "to_markdown",
    "write_table1",
    "write_tables",
]
