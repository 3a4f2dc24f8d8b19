"""Interpretability and transfer diagnostics: feature shift between scenes (more to come: Grad-CAM, t-SNE)."""

from omcrl.interpret.shift import (
    encode,
    feature_shift,
    frechet_distance,
    mmd_rbf,
    pilot_frames,
    saturated_share,
    shift_table,
    with_fixed_features,
)

__all__ = [
    "encode",
    "feature_shift",
    "frechet_distance",
    "mmd_rbf",
    "pilot_frames",
    "saturated_share",
    "shift_table",
    "with_fixed_features",
]
