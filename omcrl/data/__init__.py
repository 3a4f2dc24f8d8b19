"""Trajectory data: HDF5 dataset (writer, validated reader) and the sequence sampler for pretraining.

Collectors (scripted pilot, random exploration, policies) live in ``omcrl.data.collect`` (separate module).
"""

from __future__ import annotations

import importlib
from typing import Any

from omcrl.data.dataset import (
    FORMAT_VERSION,
    DatasetError,
    DatasetWriter,
    EpisodeBuffer,
    TrajectoryDataset,
    WriterProcess,
    open_dataset,
)

_LAZY = {"SequenceSampler": "omcrl.data.sampler"}


def __getattr__(name: str) -> Any:
    # PEP 562: the sampler (PyTorch, ~1 s) loads on use, so the dataset writer's child process
    # (omcrl.data.writer_child) and readers of datasets start without it.
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'omcrl.data' has no attribute {name!r}")


__all__ = [
    "FORMAT_VERSION",
    "DatasetError",
    "DatasetWriter",
    "EpisodeBuffer",
    "SequenceSampler",
    "TrajectoryDataset",
    "WriterProcess",
    "open_dataset",
]
