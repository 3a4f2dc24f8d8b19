"""Upstream representation learning: masking, InfoNCE, OMC and the CURL family, probes.

``pretrain_encoder(cfg) -> PretrainResult`` trains and writes the frozen-encoder artifact
(load it with :func:`omcrl.models.load_encoder`).
"""

from omcrl.pretrain.learner import OBJECTIVES, ContrastiveLearner, Objective, objective, transformer_lr_factor
from omcrl.pretrain.losses import bilinear_info_nce, masked_info_nce
from omcrl.pretrain.masking import (
    OP_KEEP,
    OP_NONE,
    OP_REPLACE,
    OP_ZERO,
    apply_mask_ops,
    mask_sequence,
    sample_mask_ops,
)
from omcrl.pretrain.probe import probe, probe_targets
from omcrl.pretrain.train import (
    PretrainResult,
    default_dataset_path,
    encoder_path,
    method_name,
    pretrain_encoder,
    pretrain_run,
    run_dir,
)

__all__ = [
    "OBJECTIVES",
    "OP_KEEP",
    "OP_NONE",
    "OP_REPLACE",
    "OP_ZERO",
    "ContrastiveLearner",
    "Objective",
    "PretrainResult",
    "apply_mask_ops",
    "bilinear_info_nce",
    "default_dataset_path",
    "encoder_path",
    "mask_sequence",
    "masked_info_nce",
    "method_name",
    "objective",
    "pretrain_encoder",
    "pretrain_run",
    "probe",
    "probe_targets",
    "run_dir",
    "sample_mask_ops",
    "transformer_lr_factor",
]
