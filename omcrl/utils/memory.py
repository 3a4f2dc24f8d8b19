"""Peak resident memory of a block of code, sampled by a background thread (Linux ``/proc``; psutil for trees)."""

from __future__ import annotations

import contextlib
import gc
import os
import threading

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes() -> int:
    """Current resident set size (bytes) from ``/proc/self/statm`` (Linux); 0 where unavailable."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * _PAGE
    except OSError:  # pragma: no cover - non-Linux
        return 0


def tree_rss_bytes() -> int:
    """Summed resident set size (bytes) of this process's descendants (a notebook's kernel, its workers).

    Pages that forked workers share are counted in each of them, so this is an upper bound on what they hold.
    """
    import psutil

    total = 0
    for p in psutil.Process().children(recursive=True):
        with contextlib.suppress(psutil.Error):  # a worker that exits between listing and reading
            total += p.memory_info().rss
    return total


class PeakRSS:
    """``with PeakRSS() as m: ...``: resident memory sampled every ``interval`` s while the block runs.

    Parameters
    ----------
    interval : seconds between samples (a sampler can miss spikes shorter than that: a slight underestimate).
    children : measure this process's descendants (:func:`tree_rss_bytes`) rather than this process.

    After the block: ``peak`` and ``baseline`` (bytes, the latter at entry), ``peak_mb`` and ``delta_mb``
    (peak above the baseline), MB.
    """

    def __init__(self, interval: float = 0.002, children: bool = False) -> None:
        self.interval = float(interval)
        self._measure = tree_rss_bytes if children else rss_bytes
        self.baseline = self.peak = 0
        self._stop = threading.Event()

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            self.peak = max(self.peak, self._measure())

    def __enter__(self) -> PeakRSS:
        gc.collect()
        self.baseline = self.peak = self._measure()
        self._thread = threading.Thread(target=self._run, name="omcrl-memory", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.peak = max(self.peak, self._measure())

    @property
    def peak_mb(self) -> float:
        return self.peak / 2**20

    @property
    def delta_mb(self) -> float:
        return (self.peak - self.baseline) / 2**20
