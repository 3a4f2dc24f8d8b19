"""Micro-benchmarks: ``python -m omcrl.bench env|pretrain|rl [--out FILE] [--quick]``.

Each benchmark is a module ``omcrl.bench.<name>`` with ``main(argv) -> int``. They share the helpers here:
:func:`parser` for the common options, :func:`timeit` to time a callable, and :func:`write_results` to print
an aligned table and write ``results/bench/<name>.json`` atomically.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from omcrl.utils.io import atomic_write_text
from omcrl.utils.runtime import machine_info

BENCH_DIR = Path("results") / "bench"


def parser(name: str, description: str = "") -> argparse.ArgumentParser:
    """ArgumentParser with the options every benchmark takes: ``--out FILE`` and ``--quick``."""
    ap = argparse.ArgumentParser(prog=f"python -m omcrl.bench {name}", description=description)
    ap.add_argument("--out", default=None, help=f"JSON output (default: {BENCH_DIR}/{name}.json)")
    ap.add_argument("--quick", action="store_true", help="fewer sizes and shorter timings (seconds in all)")
    return ap


def timeit(
    fn: Callable[[], Any],
    min_time: float = 1.0,
    *,
    warmup: int = 1,
    max_calls: int = 1_000_000,
) -> dict[str, float]:
    """Call ``fn()`` after ``warmup`` untimed calls until at least ``min_time`` seconds have passed.

    Returns ``{"calls", "total_s", "mean_s", "median_s", "min_s", "std_s", "per_s"}`` (per-call times).
    """
    for _ in range(max(0, warmup)):
        fn()
    times: list[float] = []
    start = time.perf_counter()
    while True:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
        if time.perf_counter() - start >= min_time or len(times) >= max_calls:
            break
    total = sum(times)
    mean = total / len(times)
    return {
        "calls": len(times),
        "total_s": total,
        "mean_s": mean,
        "median_s": statistics.median(times),
        "min_s": min(times),
        "std_s": statistics.stdev(times) if len(times) > 1 else 0.0,
        "per_s": 1.0 / mean if mean > 0 else math.inf,
    }


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def format_table(rows: Sequence[dict]) -> str:
    """Rows as an aligned text table; columns in order of first appearance, numbers right-aligned."""
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    cells = [[_fmt(r.get(c, "")) for c in cols] for r in rows]
    widths = [max([len(c)] + [len(row[i]) for row in cells]) for i, c in enumerate(cols)]
    numeric = [
        all(isinstance(r.get(c), (int, float)) and not isinstance(r.get(c), bool) for r in rows if c in r) for c in cols
    ]

    def line(vals: Sequence[str]) -> str:
        return "  ".join(v.rjust(w) if num else v.ljust(w) for v, w, num in zip(vals, widths, numeric)).rstrip()

    out = [line(cols), line(["-" * w for w in widths])]
    out += [line(row) for row in cells]
    return "\n".join(out)


def write_results(name: str, rows: list[dict], out: str | Path | None = None, **meta: Any) -> Path:
    """Print ``rows`` as a table and write them, with machine info, to ``out`` (default
    ``results/bench/<name>.json``) atomically; return the path."""

    path = Path(out) if out is not None else BENCH_DIR / f"{name}.json"
    print(f"# benchmark {name}")
    print(format_table(rows) if rows else "(no rows)")
    doc = {
        "name": name,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "machine": machine_info(),
        **meta,
        "rows": rows,
    }
    atomic_write_text(path, json.dumps(doc, indent=2, default=str) + "\n")
    print(f"# written to {path}")
    return path
