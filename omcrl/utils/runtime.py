"""Seeding and CPU thread settings."""

from __future__ import annotations

import os
import random

import numpy as np


def cpu_count() -> int:
    """Cores this process may run on (its CPU affinity; ``os.cpu_count()`` where affinity is unknown)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def set_threads(n: int | None = None) -> int:
    """Limit torch/BLAS intra-op threads to ``n`` (default: ``OMP_NUM_THREADS`` or 2 on this 2-core target).

    Oversubscribing 2 cores with env workers plus torch threads costs more than it gains, so every
    entry point calls this once.
    """
    n = int(n or os.environ.get("OMP_NUM_THREADS", 0) or min(2, os.cpu_count() or 1))
    try:
        import torch

        torch.set_num_threads(n)
    except ImportError:  # pragma: no cover - torch is a hard dependency
        pass
    return n


def seed_everything(seed: int) -> np.random.Generator:
    """Seed python, numpy and torch (CPU) and return a numpy Generator for explicit use."""
    random.seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002 - third-party code may still use the legacy global RNG
    try:
        import torch

        torch.manual_seed(seed)
    except ImportError:  # pragma: no cover
        pass
    return np.random.default_rng(seed)
