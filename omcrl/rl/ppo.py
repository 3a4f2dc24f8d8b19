"""PPO's pieces with an optional guide-KL term (paper IV-C, Eqs. 7-9): the rollout buffer, GAE, the loss and one
update. The training loop that uses them, top to bottom, is :func:`omcrl.rl.train.train`.

Design
------
A policy is ``features -> heads`` (:mod:`omcrl.models.features`, :mod:`omcrl.models.actor_critic`). The
rollout runner (:mod:`omcrl.rl.rollout`) fills a :class:`Rollout`; :func:`compute_gae` adds advantages and returns;
:func:`ppo_update` runs the minibatch epochs of :func:`ppo_loss` on it with the settings of ``cfg.rl`` and returns
the mean metrics (the loop sets the learning rate before each update).

Action bounds: the policy samples an *unbounded* Gaussian action; the rollout sends ``clip(a, -1, 1)`` to the
env and stores the unclipped sample, whose log-probability is used in the ratio (the usual PPO practice; the
clip acts as part of the environment). The deterministic action used for evaluation is ``clip(mean, -1, 1)``.

Rollout length: each update collects ``rollout_len = buffer_size // n_envs`` steps per env (``horizon`` when
``buffer_size < n_envs``). ``horizon`` is the ML-Agents "time horizon" the paper's hyperparameters come from:
GAE is cut (bootstrapped from the value) every ``horizon`` steps of a rollout. With
``buffer_size == horizon * n_envs`` this is plain PPO.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import nn

from omcrl.models.actor_critic import ActorCritic, gaussian_entropy, gaussian_kl, gaussian_log_prob
from omcrl.models.features import (
    FeatureExtractor,
    IdentityFeatures,
    OracleFeatures,
    PixelFeatures,
    StudentFeatures,
)
from omcrl.utils.runtime import to_device

__all__ = [
    "ActorCritic",
    "FeatureExtractor",
    "IdentityFeatures",
    "LossParts",
    "NonFiniteLossError",
    "OracleFeatures",
    "PixelFeatures",
    "Rollout",
    "StudentFeatures",
    "compute_gae",
    "gaussian_entropy",
    "gaussian_kl",
    "gaussian_log_prob",
    "ppo_loss",
    "ppo_update",
]


def compute_gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    ends: torch.Tensor,
    gamma: float,
    lam: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalised advantage estimation over a (T, N) rollout.

    Parameters
    ----------
    rewards, values : (T, N) r_t and V(s_t).
    next_values : (T, N) V(s_{t+1}) of the *true* successor (the final observation when an episode ended, so a
        time-limit truncation bootstraps correctly).
    terminated : (T, N) 1 where s_{t+1} is terminal (no bootstrap).
    ends : (T, N) 1 where the advantage recursion must stop after t: episode end (terminated or truncated), a
        horizon cut, or the last step of the rollout.
    gamma, lam : discount and GAE λ.

    Returns
    -------
    advantages, returns : (T, N) each; returns = advantages + values (the critic's regression target).
    """
    t_len = rewards.shape[0]
    adv = torch.zeros_like(rewards)
    last = torch.zeros_like(rewards[0])
    for t in reversed(range(t_len)):
        delta = rewards[t] + gamma * (1.0 - terminated[t]) * next_values[t] - values[t]
        last = delta + gamma * lam * (1.0 - ends[t]) * last
        adv[t] = last
    return adv, adv + values


# ---------------------------------------------------------------- buffer + loss
@dataclass
class Rollout:
    """One rollout of ``T`` vector steps from ``N`` envs; every tensor is (T, N, ...).

    ``valid`` is 0 on the dummy transitions of next-step autoreset (the step after an episode end, whose
    action the env ignores); they are excluded from the loss.
    """

    obs: dict[str, torch.Tensor]
    actions: torch.Tensor
    log_probs: torch.Tensor
    values: torch.Tensor
    next_values: torch.Tensor
    rewards: torch.Tensor
    terminated: torch.Tensor
    ends: torch.Tensor
    valid: torch.Tensor
    guide_mean: torch.Tensor | None = None
    guide_std: torch.Tensor | None = None
    advantages: torch.Tensor | None = None
    returns: torch.Tensor | None = None

    def flat(self) -> dict[str, Any]:
        """Valid transitions only, flattened to (M, ...)."""
        m = self.valid.reshape(-1) > 0
        out: dict[str, Any] = {"obs": {k: v.reshape(-1, *v.shape[2:])[m] for k, v in self.obs.items()}}
        for name in ("actions", "log_probs", "values", "advantages", "returns", "guide_mean", "guide_std"):
            v = getattr(self, name)
            out[name] = None if v is None else v.reshape(-1, *v.shape[2:])[m]
        return out


@dataclass
class LossParts:
    """The pieces of the guided PPO loss (scalars, with grad)."""

    total: torch.Tensor
    rl: torch.Tensor
    policy: torch.Tensor
    value: torch.Tensor
    entropy: torch.Tensor
    kl: torch.Tensor
    extras: dict = field(default_factory=dict)


def ppo_loss(
    agent: ActorCritic,
    mb: dict[str, Any],
    alpha: float,
    beta: float,
    clip: float,
    value_coef: float,
    entropy_coef: float,
) -> LossParts:
    """Guided PPO loss on one minibatch (paper Eq. 7 and 9).

    L_rl = −E[min(r A, clip(r, 1±ε) A)] + c_v E[(V − V̂)²] − c_e H, and
    total = (1 − α) L_rl + α β KL(π_guide ‖ π).
    ``mb`` holds ``obs`` (stored dict), ``actions`` (M, A), ``log_probs``, ``advantages`` (already
    normalised), ``returns`` (M,), and optionally ``guide_mean``/``guide_std`` (M, A).
    Without a guide KL is 0.
    """
    mean, std, value = agent(mb["obs"])
    logp = gaussian_log_prob(mb["actions"], mean, std)
    # Bound the log-ratio before exp: an overflowing ratio leaves the loss finite (the clipped branch wins) but
    # makes its gradient 0 * inf = NaN, which silently corrupted an oracle run at 84k steps. |20| is far
    # outside the clip range, so this changes no gradient that PPO would use.
    ratio = torch.exp(torch.clamp(logp - mb["log_probs"], -20.0, 20.0))
    adv = mb["advantages"]
    policy_loss = -torch.min(ratio * adv, torch.clamp(ratio, 1.0 - clip, 1.0 + clip) * adv).mean()
    value_loss = ((value - mb["returns"]) ** 2).mean()
    entropy = gaussian_entropy(std).mean()
    rl = policy_loss + value_coef * value_loss - entropy_coef * entropy
    guide_bad = 0.0
    if mb.get("guide_mean") is not None:
        gm, gs = mb["guide_mean"], mb["guide_std"]
        # A guide that returns a non-finite distribution for a state must not poison the whole minibatch: those
        # rows are left out of the KL and counted (metric ``guide_nonfinite``, and a warning), never hidden.
        # Seen once in a quick-preset student run (NaN KL at 71,680 steps), not reproduced in 3,000 probe steps.
        ok = torch.isfinite(gm).all(-1) & torch.isfinite(gs).all(-1) & (gs > 0).all(-1)
        guide_bad = float((~ok).float().mean())
        if guide_bad > 0:
            warnings.warn(f"guide gave a non-finite distribution on {guide_bad:.2%} of a minibatch", stacklevel=2)
        kl_rows = gaussian_kl(gm[ok], gs[ok], mean[ok], std[ok])
        kl = kl_rows.mean() if len(kl_rows) else torch.zeros((), dtype=rl.dtype)
    else:
        kl = torch.zeros((), dtype=rl.dtype)
    total = (1.0 - alpha) * rl + alpha * beta * kl
    with torch.no_grad():
        extras = {
            "approx_kl_old": ((ratio - 1.0) - (logp - mb["log_probs"])).mean().item(),
            "clip_frac": ((ratio - 1.0).abs() > clip).float().mean().item(),
            "guide_nonfinite": guide_bad,
        }
    return LossParts(total, rl, policy_loss, value_loss, entropy, kl, extras)


class NonFiniteLossError(FloatingPointError):
    """A loss became NaN/inf; the message names the env step and which loss."""


def ppo_update(
    agent: ActorCritic,
    optimizer: torch.optim.Optimizer,
    rollout: Rollout,
    rl: Any,
    *,
    alpha: float,
    step: int = 0,
) -> dict[str, float]:
    """Run ``rl.epochs`` passes of minibatch SGD (``rl.minibatch`` transitions) of :func:`ppo_loss` on one rollout
    whose advantages and returns are set (:func:`compute_gae`); returns the mean loss statistics.

    ``rl``: an :class:`omcrl.config.RLConfig` (``epochs``, ``minibatch``, ``beta``, ``clip``, ``value_coef``,
    ``entropy_coef``, ``max_grad_norm``); ``alpha`` weighs the guide KL (0 without a guide); ``step`` (env steps)
    only labels errors. Raises :class:`NonFiniteLossError` before any parameter update with a non-finite loss or
    gradient is applied.
    """
    epochs, minibatch, max_grad_norm = int(rl.epochs), int(rl.minibatch), float(rl.max_grad_norm)
    beta, clip, value_coef, entropy_coef = float(rl.beta), float(rl.clip), float(rl.value_coef), float(rl.entropy_coef)
    # One transfer of the whole batch to the networks' device (a no-op on the CPU).
    data = to_device(rollout.flat(), next(agent.parameters()).device)
    n = data["actions"].shape[0]
    if n == 0:
        return {}
    adv = data["advantages"]
    # Normalise advantages over the whole batch: keeps the surrogate's scale independent of the reward scale,
    # which matters here because it is mixed with the KL term by fixed weights.
    data["advantages"] = (adv - adv.mean()) / (adv.std(unbiased=False) + 1e-8)
    sums: dict[str, float] = {}
    count = 0
    for _ in range(epochs):
        perm = torch.randperm(n).to(data["actions"].device)  # drawn on the CPU: the same order on any device
        for start in range(0, n, minibatch):
            idx = perm[start : start + minibatch]
            mb = {"obs": {k: v[idx] for k, v in data["obs"].items()}}
            for k in ("actions", "log_probs", "advantages", "returns", "guide_mean", "guide_std"):
                mb[k] = None if data[k] is None else data[k][idx]
            parts = ppo_loss(agent, mb, alpha, beta, clip, value_coef, entropy_coef)
            for name in ("policy", "value", "entropy", "kl", "total"):
                if not torch.isfinite(getattr(parts, name)):
                    raise NonFiniteLossError(
                        f"non-finite {name} loss ({getattr(parts, name).item()}) at env step {step}; "
                        "training stopped, the last good checkpoint is kept"
                    )
            optimizer.zero_grad(set_to_none=True)
            parts.total.backward()
            grad_norm = nn.utils.clip_grad_norm_(agent.parameters(), max_grad_norm if max_grad_norm > 0 else math.inf)
            if not torch.isfinite(grad_norm):
                # A finite loss can still have a non-finite gradient; never let it reach the weights.
                raise NonFiniteLossError(
                    f"non-finite gradient (norm {grad_norm.item()}) at env step {step}; training stopped, the "
                    "last good checkpoint is kept"
                )
            optimizer.step()
            vals = {
                "loss": parts.total.item(),
                "policy_loss": parts.policy.item(),
                "value_loss": parts.value.item(),
                "entropy": parts.entropy.item(),
                "kl": parts.kl.item(),
                **parts.extras,
            }
            for k, v in vals.items():
                sums[k] = sums.get(k, 0.0) + v
            count += 1
    return {k: v / count for k, v in sums.items()}
