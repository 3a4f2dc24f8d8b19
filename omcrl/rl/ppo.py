"""PPO with an optional guide-KL term (paper IV-C, Eqs. 7-9).

Design
------
A policy is ``features -> heads``. A :class:`FeatureExtractor` turns a *batched* vector-env observation into

* ``preprocess(obs) -> dict[str, Tensor]``: what the rollout buffer stores per step. Frozen parts (the
  student's pretrained pixel encoder) are run here, once per env step, batched across envs, under
  ``no_grad``; trainable parts (the oracle's depth encoder) store their raw input so PPO epochs can
  back-propagate through them.
* ``forward(stored) -> Tensor (B, F)``: the feature vector the actor and critic see.

Three extractors cover every trainer: :class:`IdentityFeatures` (plain Box observations),
:class:`OracleFeatures` ([DepthEncoder(depth stack), v, ω, θ, Δp ∈ R⁶], depth encoder trained with the
policy) and :class:`StudentFeatures` ([frozen f(rgb stack), v, ω, θ, Δp_goal]).

Heads (:class:`ActorCritic`): separate actor and critic MLPs, each ``LayerNorm(F) -> Linear(hidden) -> Tanh ->
Linear(hidden) -> Tanh -> Linear``; LayerNorm on the inputs follows the paper (V-D); Tanh rather than ReLU
because it is the better-behaved default for PPO on continuous control (Andrychowicz et al. 2021, "What
matters in on-policy RL") and keeps the small-output-init policy close to zero-mean. Gaussian policy with a
state-independent learned log-std.

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

import numpy as np
import torch
from torch import nn

LOG_2PI = math.log(2.0 * math.pi)


# ---------------------------------------------------------------- features
class FeatureExtractor(nn.Module):
    """Base class: batched observation -> stored tensors -> feature vector of size ``out_dim``."""

    out_dim: int
    kind: str = "base"

    def preprocess(self, obs: Any) -> dict[str, torch.Tensor]:  # pragma: no cover - interface
        raise NotImplementedError

    def spec(self) -> dict:
        """JSON-able description used to rebuild the extractor from a checkpoint."""
        return {"kind": self.kind, "out_dim": self.out_dim}


class IdentityFeatures(FeatureExtractor):
    """Feature = flattened Box observation. ``obs``: (B, *obs_shape) -> stored ``x`` (B, F) float32."""

    kind = "identity"

    def __init__(self, obs_dim: int) -> None:
        super().__init__()
        self.out_dim = int(obs_dim)

    def preprocess(self, obs: Any) -> dict[str, torch.Tensor]:
        x = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        return {"x": x.reshape(x.shape[0], -1)}

    def forward(self, stored: dict[str, torch.Tensor]) -> torch.Tensor:
        return stored["x"]

    def spec(self) -> dict:
        return {"kind": self.kind, "out_dim": self.out_dim, "obs_dim": self.out_dim}


class OracleFeatures(FeatureExtractor):
    """Oracle feature [DepthEncoder(depth), v, ω, θ, Δp_obstacle, Δp_goal] (paper Eq. 5-6).

    ``obs["depth"]`` (B, L, H, W) float32 metres is stored as float16 (halves buffer memory; 0.01 m
    resolution at 20 m is far below what the encoder resolves). ``low`` = state[:, :9] (v, ω, θ) ++
    privileged (6,) -> (B, 15). The depth encoder is trained with the policy, so ``forward`` runs it on every
    minibatch.
    """

    kind = "oracle"

    def __init__(self, depth_encoder: nn.Module, depth_dim: int, encoder_kwargs: dict | None = None) -> None:
        super().__init__()
        self.depth_encoder = depth_encoder
        self.depth_dim = int(depth_dim)
        self.encoder_kwargs = dict(encoder_kwargs or {})
        self.out_dim = self.depth_dim + 15

    def preprocess(self, obs: Any) -> dict[str, torch.Tensor]:
        depth = torch.as_tensor(np.asarray(obs["depth"]), dtype=torch.float16)
        low = np.concatenate([np.asarray(obs["state"])[:, :9], np.asarray(obs["privileged"])], axis=1)
        return {"depth": depth, "low": torch.as_tensor(low, dtype=torch.float32)}

    def forward(self, stored: dict[str, torch.Tensor]) -> torch.Tensor:
        z = self.depth_encoder(stored["depth"].float())
        return torch.cat([z, stored["low"]], dim=1)

    def spec(self) -> dict:
        return {
            "kind": self.kind,
            "out_dim": self.out_dim,
            "depth_dim": self.depth_dim,
            "encoder_kwargs": self.encoder_kwargs,
        }


class StudentFeatures(FeatureExtractor):
    """Student feature [f(rgb stack), v, ω, θ, Δp_goal] with a frozen pretrained encoder f (paper IV-C).

    ``obs["rgb"]`` (B, L, 3, H, W) uint8 is reshaped to (B, 3L, H, W) and encoded once per env step in
    ``preprocess`` (no grad); the buffer stores only ``x`` (B, d + 12). The encoder is deliberately *not* a
    registered submodule: it is not optimised and not saved in policy checkpoints (they record its path
    instead).
    """

    kind = "student"

    def __init__(
        self,
        encoder: nn.Module,
        enc_dim: int,
        encoder_path: str = "",
        image_size: int = 0,
        frame_stack: int = 0,
    ) -> None:
        super().__init__()
        self.__dict__["encoder"] = encoder  # bypass nn.Module registration on purpose (frozen, external)
        self.enc_dim = int(enc_dim)
        self.encoder_path = str(encoder_path)
        self.image_size, self.frame_stack = int(image_size), int(frame_stack)
        self.out_dim = self.enc_dim + 12

    @torch.no_grad()
    def preprocess(self, obs: Any) -> dict[str, torch.Tensor]:
        rgb = torch.as_tensor(np.asarray(obs["rgb"]))
        b = rgb.shape[0]
        z = self.encoder(rgb.reshape(b, -1, rgb.shape[-2], rgb.shape[-1])).float()
        state = torch.as_tensor(np.asarray(obs["state"]), dtype=torch.float32)
        return {"x": torch.cat([z.reshape(b, -1), state], dim=1)}

    def forward(self, stored: dict[str, torch.Tensor]) -> torch.Tensor:
        return stored["x"]

    def spec(self) -> dict:
        return {
            "kind": self.kind,
            "out_dim": self.out_dim,
            "enc_dim": self.enc_dim,
            "encoder_path": self.encoder_path,
            "image_size": self.image_size,
            "frame_stack": self.frame_stack,
        }


# ---------------------------------------------------------------- heads
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

    def forward(self, stored: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return mean (B, A), std (B, A) and value (B,) for stored observations."""
        f = self.features(stored)
        mean = self.actor(f)
        std = self.log_std.exp().expand_as(mean)
        return mean, std, self.critic(f).squeeze(-1)

    @torch.no_grad()
    def step(
        self, stored: dict[str, torch.Tensor], deterministic: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sample (unclipped) actions. Returns action, log-prob, value, mean, std."""
        mean, std, value = self(stored)
        action = mean if deterministic else mean + std * torch.randn_like(mean)
        return action, gaussian_log_prob(action, mean, std), value, mean, std

    def spec(self) -> dict:
        return {
            "features": self.features.spec(),
            "act_dim": self.act_dim,
            "hidden": self.hidden,
            "layer_norm": self.layer_norm,
        }


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
    *,
    epochs: int,
    minibatch: int,
    alpha: float,
    beta: float,
    clip: float,
    value_coef: float,
    entropy_coef: float,
    max_grad_norm: float,
    step: int = 0,
) -> dict[str, float]:
    """Run ``epochs`` passes of minibatch SGD on one rollout; return mean loss statistics.

    Raises :class:`NonFiniteLossError` before any parameter update with a non-finite loss is applied.
    """
    data = rollout.flat()
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
        perm = torch.randperm(n)
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
