"""Orchestration on top of the library: method recipes, the CLI's stages, the sweeps, the notebook chain and
the summary. Everything below (:mod:`omcrl.envs` ... :mod:`omcrl.viz`) imports only downwards in the data
flow's order and never from here; ``tests/test_structure.py`` holds the import contracts that keep it so.

``from omcrl.pipeline import train_method, pretrain_method`` trains or pretrains one method of the comparison.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {"pretrain_method": "omcrl.pipeline.recipes", "train_method": "omcrl.pipeline.recipes"}


def __getattr__(name: str) -> Any:
    # PEP 562: the CLI's stage table (omcrl.pipeline.registry) loads without PyTorch; the recipes load on use.
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'omcrl.pipeline' has no attribute {name!r}")


__all__ = ["pretrain_method", "train_method"]
