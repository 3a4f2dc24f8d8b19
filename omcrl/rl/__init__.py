"""Downstream RL: PPO with an optional guide-KL term, α schedules, oracle / student trainers (paper IV-C)."""

from omcrl.rl.guidance import Guide, PlannerGuide, PolicyGuide, alpha_at, alpha_from_config, info_at, obs_at
from omcrl.rl.policy import CheckpointError, Policy, load_policy
from omcrl.rl.ppo import (
    ActorCritic,
    FeatureExtractor,
    IdentityFeatures,
    NonFiniteLossError,
    OracleFeatures,
    StudentFeatures,
    compute_gae,
    gaussian_kl,
    ppo_loss,
    ppo_update,
)
from omcrl.rl.train import Result, RunConfigMismatch, train, train_oracle, train_ppo, train_student

__all__ = [
    "ActorCritic",
    "CheckpointError",
    "FeatureExtractor",
    "Guide",
    "IdentityFeatures",
    "NonFiniteLossError",
    "OracleFeatures",
    "PlannerGuide",
    "Policy",
    "PolicyGuide",
    "Result",
    "RunConfigMismatch",
    "StudentFeatures",
    "alpha_at",
    "alpha_from_config",
    "compute_gae",
    "gaussian_kl",
    "info_at",
    "load_policy",
    "obs_at",
    "ppo_loss",
    "ppo_update",
    "train",
    "train_oracle",
    "train_ppo",
    "train_student",
]
