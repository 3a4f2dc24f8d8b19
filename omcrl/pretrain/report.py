"""Summaries of pretraining runs for notebooks and reports: chance accuracy, final metrics, probe tables."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from omcrl.config import PretrainConfig
from omcrl.pretrain.learner import objective
from omcrl.pretrain.probe import TARGETS, probe


def n_candidates(p: PretrainConfig) -> int:
    """Keys each query is scored against in the contrastive loss (its positive included).

    OMC with ``batch_negatives``: all B·T keys of the batch; OMC without: the T keys of its own sequence;
    CURL / CURL-cons: B·T pairs per iteration (the trainer feeds CURL as many stacks as OMC).
    """
    return objective(p).candidates(p)


def chance_accuracy(p: PretrainConfig) -> float:
    """Top-1 accuracy of a guess: 1 / :func:`n_candidates`."""
    return 1.0 / n_candidates(p)


def final_metrics(metrics_path: str | Path, last: int = 50) -> dict[str, float]:
    """Mean of the last ``last`` iterations of ``loss`` and ``accuracy`` in a run's ``metrics.csv``."""
    import csv

    vals: dict[str, list[float]] = {}
    with Path(metrics_path).open() as fh:
        for r in csv.DictReader(fh):
            vals.setdefault(r["metric"], []).append(float(r["value"]))
    out = {}
    for k in ("loss", "accuracy"):
        v = np.asarray(vals.get(k, []), np.float64)
        v = v[np.isfinite(v)][-last:]
        out[k] = float(v.mean()) if len(v) else float("nan")
    return out


def compare_probes(
    encoders: Mapping[str, Any], dataset: Any, n_samples: int = 2000, seed: int = 0, **kw: Any
) -> list[dict]:
    """Run :func:`omcrl.pretrain.probe` on each encoder with the same episode split and samples.

    Parameters
    ----------
    encoders : ``{label: FrozenEncoder}``.
    dataset : open :class:`omcrl.data.TrajectoryDataset`; held-out *episodes* are the test set.
    n_samples, seed, kw : passed to :func:`probe` (the same seed gives every encoder the same split).

    Returns
    -------
    Rows ``{"encoder", "distance", "bearing_sin", "bearing_cos", "mean_r2", "n_train", "n_test"}``.
    """
    rows = []
    for label, enc in encoders.items():
        r = probe(enc, dataset, n_samples=n_samples, seed=seed, **kw)
        rows.append({"encoder": label, **r, "mean_r2": float(np.mean([r[t] for t in TARGETS]))})
    return rows
