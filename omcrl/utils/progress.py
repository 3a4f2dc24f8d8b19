"""Progress of long loops, shown where the user is looking.

One :class:`Progress` serves every long loop of the kit (data collection, pretraining, RL, evaluation). Where
its text goes depends on where the code runs:

- **in a Jupyter kernel** (a notebook, interactive or run by papermill): one output that is updated in place
  (``display(..., display_id=True)`` and ``update_display``), at most once per ``notebook_interval`` seconds, so
  an executed notebook holds one output per loop however long it ran;
- **in a terminal** (stderr is a TTY): a tqdm bar;
- **elsewhere** (a log file, CI, a pipe), and inside :func:`log_lines` whatever the process: a status line on
  stderr every ``log_interval`` seconds (a sweep's job writes its own progress into its log this way, even when the
  local backend runs it in a notebook's kernel);
- and, in every case, when the environment variable ``OMCRL_STATUS_FILE`` names a file, the same status line
  is appended to it every ``status_interval`` seconds. The notebook runner (:mod:`omcrl.pipeline.notebooks`) sets it and
  prints the file's new lines on the console, so ``./reproduce.sh --quick`` is never silent for long.

A status line reads ``pretrain/omc seed0 | 600/1500 it (40%) | loss 2.91 acc 0.13 | 12m03s elapsed, ~18m05s
left``. Intervals come from ``OMCRL_STATUS_INTERVAL`` (seconds, default 30) for the status file and the log.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

T = TypeVar("T")

STATUS_FILE_ENV = "OMCRL_STATUS_FILE"
STATUS_INTERVAL_ENV = "OMCRL_STATUS_INTERVAL"
DEFAULT_STATUS_INTERVAL_S = 30.0
NOTEBOOK_INTERVAL_S = 1.0
# Set by log_lines(): a context variable, so a thread that runs a job does not change another's mode.
_LOG_LINES: contextvars.ContextVar[bool] = contextvars.ContextVar("omcrl_progress_log_lines", default=False)


@contextlib.contextmanager
def log_lines() -> Iterator[None]:
    """Within this block every enabled :class:`Progress` writes status lines to ``sys.stderr`` (never a notebook
    output or a terminal bar): a sweep redirects a job's stderr to the job's log, and the local backend runs the job
    in the caller's process, which may be a notebook's kernel."""
    token = _LOG_LINES.set(True)
    try:
        yield
    finally:
        _LOG_LINES.reset(token)


def format_duration(seconds: float) -> str:
    """``75.0 -> "1m15s"``, ``3725 -> "1h02m05s"``, ``9.4 -> "9s"``."""
    s = round(max(0.0, seconds))
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    if h:
        return f"{h}h{m:02d}m{s:02d}s"
    if m:
        return f"{m}m{s:02d}s"
    return f"{s}s"


def _in_kernel() -> bool:
    """True inside a Jupyter kernel (where ``display`` reaches a notebook), False in a plain interpreter."""
    ip = sys.modules.get("IPython")
    if ip is None:
        return False
    try:
        shell = ip.get_ipython()  # type: ignore[attr-defined]
    except Exception:
        return False
    return shell is not None and getattr(shell, "kernel", None) is not None


def _status_interval() -> float:
    raw = os.environ.get(STATUS_INTERVAL_ENV)
    if raw is None:
        return DEFAULT_STATUS_INTERVAL_S
    try:
        return max(0.0, float(raw))
    except ValueError:
        return DEFAULT_STATUS_INTERVAL_S


class Progress:
    """Progress of one loop of ``total`` units.

    Parameters
    ----------
    total : number of units the loop will reach (env steps, iterations, episodes).
    desc : what runs, e.g. ``"rl/ours seed0"``; starts every status line.
    unit : the unit's name, e.g. ``"step"``, ``"it"``, ``"ep"``.
    initial : units already done (a resumed run); the rate and time left count only this session's units.
    enabled : False: nothing is shown or written anywhere (tests, nested loops).
    notebook_interval, log_interval, status_interval : seconds between refreshes of the notebook output, the
        stderr log line and the status-file line (the last two default to ``OMCRL_STATUS_INTERVAL`` or 30 s).
    time_left : optional ``f(elapsed_s) -> seconds | None``: the time left when units are not alike (a sweep's
        jobs), instead of elapsed / units done × units left; None from it falls back to that.

    Examples
    --------
    >>> with Progress(100, "demo", enabled=False) as bar:
    ...     for _ in range(100):
    ...         bar.update(1, loss=0.5)
    """

    def __init__(
        self,
        total: int,
        desc: str,
        *,
        unit: str = "step",
        initial: int = 0,
        enabled: bool = True,
        notebook_interval: float = NOTEBOOK_INTERVAL_S,
        log_interval: float | None = None,
        status_interval: float | None = None,
        time_left: Callable[[float], float | None] | None = None,
    ) -> None:
        self.total = int(total)
        self.desc = desc
        self.unit = unit
        self.n = int(initial)
        self.initial = int(initial)
        self.enabled = enabled
        self.postfix: dict[str, str] = {}
        self._time_left = time_left
        self.t0 = time.perf_counter()
        self._closed = False
        every = _status_interval()
        self._intervals = {
            "notebook": notebook_interval,
            "log": every if log_interval is None else log_interval,
            "status": every if status_interval is None else status_interval,
        }
        self._last: dict[str, float] = {}
        self._handle: Any = None
        self._tqdm: Any = None
        self._status_path = os.environ.get(STATUS_FILE_ENV) if enabled else None
        self._mode = "off"
        if not enabled:
            return
        if _LOG_LINES.get():
            self._mode = "log"
        elif _in_kernel():
            self._mode = "notebook"
            from IPython.display import display

            self._handle = display(self._text_object(), display_id=True)
        elif sys.stderr is not None and sys.stderr.isatty():
            from tqdm import tqdm

            self._mode = "tty"
            self._tqdm = tqdm(total=self.total, initial=self.n, desc=desc, unit=unit, dynamic_ncols=True)
        else:
            self._mode = "log"
        self._emit(force=True)

    # ------------------------------------------------------------ reporting
    def update(self, n: int = 1, **postfix: Any) -> None:
        """Add ``n`` units done and replace the shown metrics by ``postfix`` (``name=value``; floats get 3
        significant digits)."""
        if not self.enabled or self._closed:
            return
        self.n += int(n)
        if postfix:
            self.postfix = {k: _fmt(v) for k, v in postfix.items()}
        if self._tqdm is not None:
            self._tqdm.update(int(n))
            if postfix:
                self._tqdm.set_postfix(self.postfix, refresh=False)
        self._emit(force=False)

    def close(self) -> None:
        """Show the final state everywhere (once)."""
        if not self.enabled or self._closed:
            return
        self._emit(force=True, final=True)
        self._closed = True
        if self._tqdm is not None:
            self._tqdm.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------ text
    def status_line(self, final: bool = False) -> str:
        """One line: what runs, units done of total, metrics, elapsed and (unless ``final``) the time left."""
        elapsed = time.perf_counter() - self.t0
        pct = f" ({100.0 * self.n / self.total:.0f}%)" if self.total > 0 else ""
        parts = [self.desc, f"{self.n}/{self.total} {self.unit}{pct}"]
        if self.postfix:
            parts.append(" ".join(f"{k} {v}" for k, v in self.postfix.items()))
        done = self.n - self.initial
        timing = f"{format_duration(elapsed)} elapsed"
        if final:
            timing += ", done" if self.n >= self.total else ", stopped"
        elif self.total > self.n:
            left = self._time_left(elapsed) if self._time_left is not None else None
            if left is None and done > 0:
                left = elapsed / done * (self.total - self.n)
            if left is not None:
                timing += f", ~{format_duration(left)} left"
        parts.append(timing)
        return " | ".join(parts)

    def _bar_text(self, final: bool = False) -> str:
        width = 24
        frac = min(1.0, self.n / self.total) if self.total > 0 else 1.0
        filled = round(frac * width)
        return f"[{'#' * filled}{'.' * (width - filled)}] {self.status_line(final)}"

    def _text_object(self, final: bool = False) -> Any:
        from IPython.display import Pretty

        return Pretty(self._bar_text(final))

    def _due(self, sink: str, now: float, force: bool) -> bool:
        if force or now - self._last.get(sink, -1e18) >= self._intervals[sink]:
            self._last[sink] = now
            return True
        return False

    def _emit(self, force: bool, final: bool = False) -> None:
        now = time.perf_counter()
        if self._mode == "notebook" and self._due("notebook", now, force):
            self._handle.update(self._text_object(final))
        elif self._mode == "log" and self._due("log", now, force):
            print(f"[omcrl] {self.status_line(final)}", file=sys.stderr, flush=True)
        if self._status_path and self._due("status", now, force):
            try:
                with open(self._status_path, "a", encoding="utf-8") as f:
                    f.write(self.status_line(final) + "\n")
            except OSError:
                self._status_path = None  # the console feed is a courtesy; training must not fail over it


def track(iterable: Iterable[T], total: int | None = None, desc: str = "", unit: str = "it", **kw: Any) -> Iterator[T]:
    """Iterate ``iterable`` with a :class:`Progress` (``total`` defaults to ``len(iterable)``)."""
    items = iterable if total is not None else list(iterable)
    n = total if total is not None else len(items)  # type: ignore[arg-type]
    with Progress(n, desc, unit=unit, **kw) as bar:
        for x in items:
            yield x
            bar.update(1)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)
