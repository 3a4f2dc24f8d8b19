"""Actor-critic heads and diagonal-Gaussian maths for PPO (paper V-D: two 256-unit layers, LayerNorm inputs).

Heads (:class:`ActorCritic`): separate actor and critic MLPs, each ``LayerNorm(F) -> Linear(hidden) -> Tanh ->
Linear(hidden) -> Tanh -> Linear``; LayerNorm on the inputs follows the paper (V-D); Tanh rather than ReLU
because it is the better-behaved default for PPO on continuous control (Andrychowicz et al. 2021, "What
matters in on-policy RL") and keeps the small-output-init policy close to zero-mean. Gaussian policy with a
state-independent learned log-std.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn

from omcrl.models.features import FeatureExtractor
from omcrl.utils.precision import autocast

LOG_2PI = math.log(2.0 * math.pi)


def _mlp(inp: int, hidden: int, out: int, out_gain: float, layer_norm: bool) -> nn.Sequential:
    net = nn.Sequential(
        nn.LayerNorm(inp) if layer_norm else nn.Identity(),  # Identity keeps the state-dict indices
        nn.Linear(inp, hidden),
        nn.Tanh(),
        nn.Linear(hidden, hidden),
        nn.Tanh(),
        nn.Linear(hidden, out),
    )
    # Orthogonal init (standard PPO); a small last layer gives a near-zero initial mean.
    for m in net:
        if isinstance(m, nn.Linear):
            nn.init.orthogonal_(m.weight, gain=math.sqrt(2.0))
            nn.init.zeros_(m.bias)
    nn.init.orthogonal_(net[-1].weight, gain=out_gain)
    return net


class ActorCritic(nn.Module):
    """Features -> (Gaussian policy mean, std) and value.

    Parameters
    ----------
    features : the feature extractor (its trainable parameters are optimised with the heads).
    act_dim : action size (3 for the drone: vx, vy, ωz in [-1, 1]).
    hidden : width of the two hidden layers of actor and critic.
    init_log_std : initial state-independent log standard deviation.
    layer_norm : LayerNorm on the head inputs (paper V-D; default). Switch it off for tiny raw observations:
        over a 2-D input LayerNorm keeps only the sign of x − y and discards the magnitude.
    """

    def __init__(
        self,
        features: FeatureExtractor,
        act_dim: int,
        hidden: int = 256,
        init_log_std: float = -0.5,
        layer_norm: bool = True,
    ) -> None:
        super().__init__()
        self.features = features
        self.act_dim, self.hidden, self.layer_norm = int(act_dim), int(hidden), bool(layer_norm)
        self.actor = _mlp(features.out_dim, hidden, act_dim, out_gain=0.01, layer_norm=layer_norm)
        self.critic = _mlp(features.out_dim, hidden, 1, out_gain=1.0, layer_norm=layer_norm)
        self.log_std = nn.Parameter(torch.full((act_dim,), float(init_log_std)))
        # "fp32" or "bf16" (resolved; omcrl.utils.precision): the training passes (grad enabled: PPO updates) run
        # under autocast; inference (rollouts, guides, evaluation, no grad) stays fp32, which is faster at the
        # kit's batch sizes (python -m omcrl.bench precision). Everything returned is float32. Not a parameter: the
        # trainer sets it and the policy file records it.
        self.precision = "fp32"

    def _autocast(self) -> Any:
        return autocast(self.precision if torch.is_grad_enabled() else "fp32", self.log_std.device.type)

    def prepare(self, obs: object) -> dict[str, torch.Tensor]:
        """``features.preprocess(obs)``: what the rollout stores (a frozen encoder runs here: inference, fp32)."""
        return self.features.preprocess(obs)

    def forward(self, stored: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return mean (B, A), std (B, A) and value (B,) for stored observations (float32)."""
        with self._autocast():
            f = self.features(stored)
            mean, value = self.actor(f), self.critic(f)
        mean = mean.float()
        std = self.log_std.exp().expand_as(mean)
        return mean, std, value.float().squeeze(-1)

    def distribution(self, stored: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean (B, A) and std (B, A) without the critic: what acting and guiding need (same mean as ``forward``)."""
        with self._autocast():
            mean = self.actor(self.features(stored))
        mean = mean.float()
        return mean, self.log_std.exp().expand_as(mean)

    @torch.no_grad()
    def step(
        self, stored: dict[str, torch.Tensor], deterministic: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sample (unclipped) actions. Returns action, log-prob, value, mean, std."""
        mean, std, value = self(stored)
        action = mean if deterministic else mean + std * torch.randn_like(mean)
        return action, gaussian_log_prob(action, mean, std), value, mean, std

    def spec(self) -> dict:
        out = {
            "features": self.features.spec(),
            "act_dim": self.act_dim,
            "hidden": self.hidden,
            "layer_norm": self.layer_norm,
        }
        if self.precision != "fp32":  # only then: fp32 policy files stay byte-identical to those before the field
            out["precision"] = self.precision
        return out


# ---------------------------------------------------------------- maths
def gaussian_log_prob(x: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """Log density of a diagonal Gaussian, summed over the last dim. (..., A) -> (...)."""
    return (-0.5 * ((x - mean) / std) ** 2 - std.log() - 0.5 * LOG_2PI).sum(-1)


def gaussian_entropy(std: torch.Tensor) -> torch.Tensor:
    """Entropy of a diagonal Gaussian, summed over the last dim. (..., A) -> (...)."""
    return (0.5 + 0.5 * LOG_2PI + std.log()).sum(-1)


def gaussian_kl(mean_p: torch.Tensor, std_p: torch.Tensor, mean_q: torch.Tensor, std_q: torch.Tensor) -> torch.Tensor:
    """Closed-form KL(p ‖ q) of diagonal Gaussians, summed over the last dim. (..., A) -> (...).

    KL = Σ_i log(σ_q/σ_p) + (σ_p² + (μ_p − μ_q)²) / (2σ_q²) − 1/2. With p the guide and q the learner this is
    the paper's D_KL(π^o ‖ π) (Eq. 8), the expectation under the guide's actions.
    """
    var_q = std_q**2
    return (torch.log(std_q / std_p) + (std_p**2 + (mean_p - mean_q) ** 2) / (2.0 * var_q) - 0.5).sum(-1)
