"""Downstream RL: the rollout runner, PPO with an optional guide-KL term, α schedules, and the methods of the
paper's comparison (oracle, ours, ours-noOT, ppo, curl, curl-phi, npe, npe-ot; paper IV-C, V-C).

The methods are specs (:mod:`omcrl.rl.methods`); ``omcrl.pipeline.train_method(cfg, "curl")`` trains one by
name, finding its encoder and oracle. The trainers here take explicit inputs, one per kind of learning:
``train_oracle`` (privileged depth and state), ``train_visuomotor`` (the camera: a frozen encoder, or pixels end to
end) and ``train_ppo`` (a caller's Box-observation env); all three run the one PPO loop, :func:`train` (a method's
recipe hands the loop :func:`omcrl.rl.train.visuomotor_parts` itself).
"""

from omcrl.rl.guidance import Guide, PlannerGuide, PolicyGuide, alpha_at, alpha_from_config, info_at, obs_at
from omcrl.rl.methods import METHODS, MethodSpec, get_method
from omcrl.rl.policy import CheckpointError, Policy, load_policy
from omcrl.rl.ppo import (
    ActorCritic,
    FeatureExtractor,
    IdentityFeatures,
    NonFiniteLossError,
    OracleFeatures,
    PixelFeatures,
    StudentFeatures,
    compute_gae,
    gaussian_kl,
    ppo_loss,
    ppo_update,
)
from omcrl.rl.rollout import Runner
from omcrl.rl.train import Result, RunConfigMismatch, train, train_oracle, train_ppo, train_visuomotor

__all__ = [
    "METHODS",
    "ActorCritic",
    "CheckpointError",
    "FeatureExtractor",
    "Guide",
    "IdentityFeatures",
    "MethodSpec",
    "NonFiniteLossError",
    "OracleFeatures",
    "PixelFeatures",
    "PlannerGuide",
    "Policy",
    "PolicyGuide",
    "Result",
    "RunConfigMismatch",
    "Runner",
    "StudentFeatures",
    "alpha_at",
    "alpha_from_config",
    "compute_gae",
    "gaussian_kl",
    "get_method",
    "info_at",
    "load_policy",
    "obs_at",
    "ppo_loss",
    "ppo_update",
    "train",
    "train_oracle",
    "train_ppo",
    "train_visuomotor",
]
