"""Shared test settings: few threads on the 2-core machine, a headless matplotlib, the repository root."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import tempfile
from collections.abc import Callable, Iterator
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


# Modules that talk to a Tello double on the SDK's fixed UDP ports (djitellopy binds its reply socket to 8889 and
# listens for state on 8890). ./reproduce.sh --test runs test modules on every core (pytest-xdist, --dist loadfile: a
# module's fixtures are built once, on one worker), so their tests take a lock on the machine first: two of them, from
# two workers or two pytest runs, never hold the ports at once. The notebook chain flies one too, in notebook 09 only:
# it takes the same lock around that notebook (fixture `tello_ports`), not for its whole ten notebooks, so the other
# worker's Tello tests wait seconds for it rather than minutes.
TELLO_MODULES = {"test_deploy", "test_flight_safety", "test_tello_timing"}
TELLO_PORTS_LOCK = Path(tempfile.gettempdir()) / "omcrl-tests-tello-ports.lock"
# Set while a test holds the lock, so the processes it starts (a child pytest, a notebook kernel) do not wait on it.
TELLO_PORTS_HELD = "OMCRL_TESTS_TELLO_PORTS_HELD"


# The longest modules of the default run, longest first (summed setup + call + teardown, idle, 2026-12-05: the chain
# 356 s, gradient 148, griddata 104, integrity 98, deploy 84, tello_timing 52 of 1,082 s). --dist loadfile hands out
# modules in collection order only with --no-loadscope-reorder (./reproduce.sh passes it); by default xdist sorts them
# by their number of tests, which ignores this order. With xdist 3.8's rules (one module per worker, another when
# <= 2 of its tests are pending) on an idle full run's durations (2026-12-05): 546 s on the busier worker in xdist's
# order, 534 s in this one; measured in this order, 528 s on each worker. The suite's length is its total work.
LONGEST_FIRST = (
    "test_notebooks",
    "test_gradient",
    "test_griddata",
    "test_integrity",
    "test_deploy",
    "test_tello_timing",
)


def _module_name(item: pytest.Item) -> str:
    return item.module.__name__.rsplit(".", 1)[-1] if item.module is not None else ""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if _module_name(item) in STAGE_MODULES:
            item.add_marker(pytest.mark.stage)
    # On xdist workers only (every worker sorts the same way, as xdist requires); a run on one process keeps the
    # collection order, so its quick modules report first.
    if os.environ.get("PYTEST_XDIST_WORKER"):
        rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
        items.sort(key=lambda item: rank.get(_module_name(item), len(rank)))  # stable: the rest keep their order


@contextlib.contextmanager
def _hold_tello_ports() -> Iterator[None]:
    """Holds the Tello ports' lock (waiting for it) until the block ends; a no-op where a parent process holds it."""
    if os.environ.get(TELLO_PORTS_HELD) == "1":
        yield
        return
    with open(TELLO_PORTS_LOCK, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)  # released when f closes
        os.environ[TELLO_PORTS_HELD] = "1"
        try:
            yield
        finally:
            del os.environ[TELLO_PORTS_HELD]


@pytest.fixture(autouse=True)
def _tello_ports_module(request: pytest.FixtureRequest) -> Iterator[None]:
    """Holds the Tello ports' lock through each test of :data:`TELLO_MODULES`."""
    if request.module.__name__.rsplit(".", 1)[-1] not in TELLO_MODULES:
        yield
        return
    with _hold_tello_ports():
        yield


@pytest.fixture
def tello_ports() -> Callable[[], contextlib.AbstractContextManager[None]]:
    """The Tello ports' lock for part of a test: ``with tello_ports(): ...`` around what flies a Tello double."""
    return _hold_tello_ports


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


@pytest.fixture(scope="session")
def pages(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Every generated block of the pages rebuilt once from ``reference/quick/`` (:func:`omcrl.pipeline.glance.
    page_blocks`), for the tests that check a page against its data: ``{page: {start marker: block}}``.

    Built once per run, not once per xdist worker (about 75 s of work each): the first worker to ask writes the
    blocks as JSON beside the workers' temporary folders (one parent per run), the others wait on its lock and read.
    """
    from omcrl.pipeline.glance import page_blocks
    from omcrl.utils.io import atomic_write_text

    def build() -> dict:
        return {page: {start: block for block, start, _ in blocks} for page, blocks in page_blocks("quick").items()}

    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return build()
    shared = tmp_path_factory.getbasetemp().parent / "pages.json"
    with open(shared.with_suffix(".lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not shared.exists():
            atomic_write_text(shared, json.dumps(build()))
        return json.loads(shared.read_text(encoding="utf-8"))
