"""Shared test settings: few threads on the 2-core machine, a headless matplotlib, the repository root."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# Before anything imports numpy/torch: two cores are shared, so tests stay single-threaded by default.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", os.environ["OMP_NUM_THREADS"])
os.environ["MPLBACKEND"] = "Agg"

REPO_ROOT = Path(__file__).resolve().parent.parent

# Modules whose tests run stages end to end (training, pretraining, collection, sweeps, notebook chains, flights):
# marked "stage". The fast developer loop leaves them out: pytest -m "not slow and not stage". CI and
# ./reproduce.sh --test run everything but "slow".
STAGE_MODULES = {
    "test_notebooks",
    "test_integration",
    "test_integrity",
    "test_precision",
    "test_sweep",
    "test_methods",
    "test_deploy",
    "test_hardening",
    "test_pretrain",
    "test_collect",
    "test_table1",
    "test_interpret",
    "test_transfer",
    "test_bench",
    "test_extending",
}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.module is not None and item.module.__name__.rsplit(".", 1)[-1] in STAGE_MODULES:
            item.add_marker(pytest.mark.stage)


def pytest_configure(config: pytest.Config) -> None:
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a hard dependency
        return
    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root (the folder holding pyproject.toml)."""
    return REPO_ROOT
