"""Interpretability and transfer diagnostics: Grad-CAM, feature stability and t-SNE inputs, disturbance tests,
feature shift between scenes, the zero-shot diagnosis and the scenes' gradient of difficulty."""

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
