"""Evaluation: episode metrics (NE OS SR SPL CR TTS, paper V-B), the evaluation runner and tables."""

from omcrl.eval.metrics import METRICS, format_table, summarize, summary_table
from omcrl.eval.runner import eval_seeds, evaluate

__all__ = ["METRICS", "eval_seeds", "evaluate", "format_table", "summarize", "summary_table"]
