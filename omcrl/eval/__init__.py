"""Evaluation: episode metrics (NE OS SR SPL CR TTS, paper V-B), the evaluation runner and tables.

``run(cfg)`` is the CLI stage ``python -m omcrl evaluate``: every trained oracle/student policy under
``<run_root>/runs`` plus Hybrid APF in all evaluation scenes, tables under ``<run_root>/tables``.
"""

from omcrl.eval.metrics import METRICS, format_table, summarize, summary_table
from omcrl.eval.runner import eval_seeds, evaluate, start_episode
from omcrl.eval.stage import EvalResult, evaluate_methods, find_policies, run, to_markdown, write_tables

__all__ = [
    "METRICS",
    "EvalResult",
    "eval_seeds",
    "evaluate",
    "evaluate_methods",
    "find_policies",
    "format_table",
    "run",
    "start_episode",
    "summarize",
    "summary_table",
    "to_markdown",
    "write_tables",
]
