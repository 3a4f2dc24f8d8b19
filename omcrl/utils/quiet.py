"""Import a module whose C extension prints to the process's stderr on import (PyBullet prints its build time)."""

from __future__ import annotations

import importlib
import os
import sys
from types import ModuleType


def import_quietly(name: str) -> ModuleType:
    """``importlib.import_module(name)`` with file descriptor 2 sent to /dev/null while it loads.

    PyBullet writes "pybullet build time: ..." from C, past ``sys.stderr``, on its first import: every CLI
    stage, notebook and worker process printed it, and one-line errors got a second line. An import that fails
    still raises its Python exception here.
    """
    if name in sys.modules:
        return sys.modules[name]
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        return importlib.import_module(name)
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
