"""Plotting helpers for the notebooks (matplotlib only; every function returns its Figure).

Submodules are imported on demand (``from omcrl.viz.data import plot_source_mix``) so that importing
``omcrl.viz`` stays cheap and one missing optional module never breaks the others.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

__all__ = ["METHOD_COLORS", "method_color", "save_figure", "steps_axis"]


def save_figure(fig: Any, directory: str | Path, name: str, dpi: int = 120) -> Path:
    """Save ``fig`` as ``<directory>/<name>.png`` (folders created) and return the path."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.png"
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return path


# One colour per method in every figure (by kit name or the paper's label). Blue and orange are left to maps
# (start, shortest path); the rest are distinct under common colour-vision deficiencies as far as 10 colours go.
METHOD_COLORS = {
    "oracle": "#000000",
    "ours": "#d62728",
    "ours-noOT": "#ff9896",
    "npe": "#2ca02c",
    "npe-ot": "#98df8a",
    "npe-expert": "#17becf",
    "ours-lapf": "#e377c2",
    "ours-random": "#b8860b",  # the controls: without colours of their own both drew in the default blue
    "ours-blind": "#393b79",
    "curl": "#9467bd",
    "curl-phi": "#c5b0d5",
    "ppo": "#8c564b",
    "hybrid-apf": "#7f7f7f",
    "hybrid-apf-perceptive": "#bcbd22",
    "HybridAPF": "#7f7f7f",
}


def method_color(method: str, default: str | None = "#4c72b0") -> str | None:
    """The colour of ``method`` (a kit name such as ``ours-noOT`` or its label such as ``Ours w/o OT``) in every
    figure; ``default`` (a stable grey-blue, or the caller's own cycle colour) for names without a colour of their
    own, such as ablation variants that are not methods of the comparison."""
    if method in METHOD_COLORS:
        return METHOD_COLORS[method]
    # Only for a label: `import omcrl.viz` stays free of PyTorch (0.05 s, against ~1.4 s with omcrl.rl).
    from omcrl.rl.methods import METHODS

    kit = next((n for n, s in METHODS.items() if s.label == method), None)
    return METHOD_COLORS.get(kit, default) if kit else default


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
