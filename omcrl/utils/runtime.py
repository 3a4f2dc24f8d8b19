"""Seeding, CPU thread settings and the compute device."""

from __future__ import annotations

import os
import platform
import random
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from omcrl.utils.errors import ConfigError


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


def exit_with_parent(parent: int, interval: float = 0.5) -> None:
    """End this (worker) process within ``interval`` s of its parent's death, however the parent died (kill -9
    included): a daemon thread polls ``os.getppid()``, which changes when the orphan is adopted. It imports
    nothing: a child forked while another thread of the parent held an import lock must still be able to start
    it (such a child can hang in its first import, and would otherwise never notice its parent's death)."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(interval)
        os._exit(1)

    threading.Thread(target=watch, name="omcrl-parent-watch", daemon=True).start()


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


DEVICES = ("auto", "cpu", "cuda")


def resolve_device(name: str) -> Any:
    """The ``torch.device`` for a config value: ``auto`` (CUDA when available, else CPU), ``cpu`` or ``cuda``.

    Raises
    ------
    ConfigError : an unknown name, or ``cuda`` on a machine without a usable CUDA GPU.
    """
    import torch

    if name not in DEVICES:
        raise ConfigError(f"device: got {name!r}, allowed values are {list(DEVICES)}")
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    elif name == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device: got 'cuda', but torch sees no CUDA GPU here; use 'auto' or 'cpu'")
    return torch.device(name)


def to_device(tree: Any, device: Any) -> Any:
    """Tensors in ``tree`` (nested dicts; other values kept) on ``device``: a no-op for tensors already there.

    Host tensors bound for a GPU are pinned first, so the copy is asynchronous (one batch per call).
    """
    import torch

    if isinstance(tree, dict):
        return {k: to_device(v, device) for k, v in tree.items()}
    if isinstance(tree, torch.Tensor) and tree.device != device:
        if device.type == "cuda" and tree.device.type == "cpu":
            return tree.pin_memory().to(device, non_blocking=True)
        return tree.to(device)
    return tree


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux; ``platform.processor()`` elsewhere), or ``unknown``."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict[str, Any]:
    """What the numbers depend on: the CPU (model, and the vector ISA torch's kernels dispatch to), CPU count,
    threads, Python and torch versions.

    The same seed gives bit-identical results on one machine and build; torch picks its CPU kernels by
    ``cpu_capability`` (e.g. AVX2 vs AVX512), and kernels of different widths round differently, so results from
    another CPU or torch build can differ from the second iteration on.
    """
    info: dict[str, Any] = {
        "platform": platform.platform(),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
    }
    torch = sys.modules.get("torch")
    if torch is not None:
        info["torch"] = torch.__version__
        info["cpu_capability"] = torch.backends.cpu.get_cpu_capability()
        info["torch_threads"] = torch.get_num_threads()
        info["cuda"] = bool(torch.cuda.is_available())
    return info


def code_commit(short: bool = True) -> str:
    """``<sha>`` (``short``: abbreviated) of the checkout the running ``omcrl`` code comes from (not of the results
    folder, which ``OMCRL_ROOT`` may put elsewhere), ``+ local changes`` when dirty; ``unknown`` outside git."""
    root = Path(__file__).resolve().parents[2]
    try:
        sha = subprocess.run(
            ["git", "rev-parse", *(["--short"] if short else []), "HEAD"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (sha + (" + local changes" if dirty else "")) if sha else "unknown"
