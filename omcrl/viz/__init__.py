"""Plotting helpers for the notebooks (matplotlib only; every function returns its Figure).

Submodules are imported on demand (``from omcrl.viz.data import plot_source_mix``) so that importing
``omcrl.viz`` stays cheap and one missing optional module never breaks the others.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

__all__ = ["save_figure"]


def save_figure(fig: Any, directory: str | Path, name: str, dpi: int = 120) -> Path:
    """Save ``fig`` as ``<directory>/<name>.png`` (folders created) and return the path."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.png"
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return path


def steps_axis(axis: Any) -> None:
    """Label a matplotlib axis (``ax.xaxis`` or ``ax.yaxis``) of env steps in thousands ("50k"): full step counts
    run into each other on a figure's width."""
    from matplotlib.ticker import FuncFormatter

    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v / 1000:g}k" if v else "0"))


def __getattr__(name: str) -> Any:  # ``omcrl.viz.data`` etc. without importing every submodule up front
    try:
        return importlib.import_module(f"{__name__}.{name}")
    except ModuleNotFoundError as e:
        if e.name != f"{__name__}.{name}":  # a dependency of an existing submodule is missing: a real error
            raise
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
