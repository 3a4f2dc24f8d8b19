"""Trajectory data: HDF5 dataset (writer, validated reader) and the sequence sampler for pretraining.

Collectors (scripted pilot, random exploration, policies) live in ``omcrl.data.collect`` (separate module).
"""

from omcrl.data.dataset import (
    FORMAT_VERSION,
    DatasetError,
    DatasetWriter,
    EpisodeBuffer,
    TrajectoryDataset,
    WriterProcess,
    open_dataset,
)
from omcrl.data.sampler import SequenceSampler

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
