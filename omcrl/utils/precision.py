"""Numeric precision of the networks: float32, or bfloat16 autocast where the hardware runs it natively.

``precision: fp32 | bf16 | auto`` (``pretrain.precision``, ``rl.precision``). With ``bf16`` the training passes —
every pretraining step, and the forward and backward passes of every PPO update — run under
``torch.autocast(dtype=torch.bfloat16)``: convolutions and matrix products in bfloat16, while the weights, the
optimiser state, the losses and everything reduced from them stay float32 (autocast's own policy keeps
normalisations and reductions in float32; the kit casts the networks' outputs back to float32 before any loss).
Inference — rollouts, the oracle guide, evaluation, deployment — runs the float32 weights in float32: at the kit's
batch sizes (2 envs, 8 lanes) bf16 inference measured 0.64–0.85× the speed of fp32 on this CPU
(``python -m omcrl.bench precision``), and an exported policy then behaves exactly as it did in evaluation.
``auto`` picks bf16 where the hardware executes it natively and fp32 elsewhere:

- CPU: the ``avx512_bf16`` or ``amx_bf16`` flag in ``/proc/cpuinfo`` (Linux; elsewhere fp32);
- CUDA: compute capability 8.0 or newer (Ampere and later have bfloat16 tensor cores).

The resolved precision is part of a run's identity (:func:`omcrl.config.section_identity`: bf16 differs from the
fp32 default), so a bf16 run never reuses an fp32 artifact or the other way round.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from omcrl.utils.errors import ConfigError
from omcrl.utils.runtime import resolve_device

PRECISIONS = ("fp32", "bf16", "auto")
CPU_BF16_FLAGS = ("avx512_bf16", "amx_bf16")


@functools.lru_cache(maxsize=1)
def cpu_flags() -> frozenset[str]:
    """The CPU feature flags of ``/proc/cpuinfo`` (empty where the file does not exist)."""
    try:
        text = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return frozenset()
    for line in text.splitlines():
        if line.startswith("flags"):
            return frozenset(line.split(":", 1)[1].split())
    return frozenset()


def native_bf16(device: Any = "cpu") -> tuple[bool, str]:
    """Whether ``device`` (a ``torch.device`` or its name) executes bfloat16 natively, and how that was decided."""
    import torch

    dev = torch.device(device)
    if dev.type == "cuda":
        major, minor = torch.cuda.get_device_capability(dev)
        return major >= 8, f"CUDA compute capability {major}.{minor} (native bfloat16 from 8.0)"
    if dev.type != "cpu":
        return False, f"device type {dev.type!r}: not checked, fp32"
    found = sorted(set(CPU_BF16_FLAGS) & cpu_flags())
    if found:
        return True, f"CPU flag {', '.join(found)} in /proc/cpuinfo"
    return False, f"none of the CPU flags {', '.join(CPU_BF16_FLAGS)} in /proc/cpuinfo"


def resolve_precision(name: str, device: Any = "cpu") -> str:
    """``fp32`` or ``bf16`` for a config value (``auto``: :func:`native_bf16` decides) on ``device``."""
    if name not in PRECISIONS:
        raise ConfigError(f"precision: got {name!r}, allowed values are {list(PRECISIONS)}")
    if name == "auto":
        return "bf16" if native_bf16(device)[0] else "fp32"
    return name


def section_precision(section: Any) -> str:
    """The resolved precision of a config section with ``precision`` and ``device`` fields (pretrain, rl).

    Only ``auto`` looks at the device (and so needs it here): a driver without a GPU can plan ``fp32`` or ``bf16``
    jobs for GPU nodes."""
    if section.precision != "auto":
        return resolve_precision(section.precision)

    return resolve_precision(section.precision, resolve_device(section.device))


@contextlib.contextmanager
def autocast(precision: str, device_type: str = "cpu") -> Iterator[None]:
    """``torch.autocast`` to bfloat16 when ``precision`` is ``bf16``; a no-op for ``fp32``."""
    import torch

    if precision == "bf16":
        with torch.autocast(device_type, dtype=torch.bfloat16):
            yield
    else:
        yield
