"""Guides for the KL term and the α schedules (paper IV-C Eq. 8-9; NPE baseline V-C).

A guide is any object with ``distribution(obs, infos, starts) -> (mean, std)`` giving a diagonal Gaussian
action distribution for every env of a vector step: ``obs`` is the batched vector-env observation, ``infos``
the vector info dict (gymnasium 1.x layout, ``_key`` masks), ``starts`` (N,) bool marks envs whose
observation is the first of a new episode; ``mean`` and ``std`` are float32 arrays (N, A). The rollout calls
it once per vector step and stores the result, so the KL is computed on the rollout's own states.

A *stateless* guide may also declare ``batched = True`` and provide ``prepare(obs) -> stored`` (a dict of
tensors that owns its memory, one row per env) and ``distribution_stored(stored) -> (mean, std)``. The rollout
then only prepares the guide's input each step and evaluates the guide once per chunk of steps: the oracle's
depth encoder is memory-bound at a batch of ``n_envs`` (its first linear layer has millions of weights, read
once per call), so one call on a few hundred states costs little more than one on two.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np
import torch

from omcrl.agent import start_episode
from omcrl.rl.ppo import ActorCritic
from omcrl.utils.runtime import to_device


class Guide(Protocol):
    def distribution(self, obs: Any, infos: dict, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


def alpha_at(
    step: int,
    schedule: str,
    alpha_start: float,
    decay_steps: int = 1,
    exp_factor: float = 1.0,
    exp_every: int = 1,
) -> float:
    """Guidance weight α after ``step`` environment steps.

    ``linear``: alpha_start · max(0, 1 − step / decay_steps); ``exp``: alpha_start · exp_factor^⌊step /
    exp_every⌋; ``fixed``: alpha_start; ``none``: 0 (the "w/o OT" variant).
    """
    if schedule == "linear":
        return float(alpha_start * max(0.0, 1.0 - step / decay_steps))
    if schedule == "exp":
        return float(alpha_start * exp_factor ** (step // exp_every))
    if schedule == "fixed":
        return float(alpha_start)
    if schedule == "none":
        return 0.0
    raise ValueError(f"alpha schedule: got {schedule!r}, allowed values are ['linear', 'exp', 'fixed', 'none']")


def alpha_from_config(step: int, rl_cfg: Any) -> float:
    """:func:`alpha_at` with the fields of an :class:`omcrl.config.RLConfig`."""
    return alpha_at(
        step,
        rl_cfg.alpha_schedule,
        rl_cfg.alpha_start,
        rl_cfg.alpha_decay_steps,
        rl_cfg.alpha_exp_factor,
        rl_cfg.alpha_exp_every,
    )


# ---------------------------------------------------------------- vector-env helpers
def obs_at(obs: Any, i: int) -> Any:
    """Observation of env ``i`` from a batched (dict of) array(s)."""
    if isinstance(obs, dict):
        return {k: v[i] for k, v in obs.items()}
    return obs[i]


def info_at(infos: dict, i: int) -> dict:
    """Info dict of env ``i`` from a gymnasium 1.x vector info dict (drops entries masked out by ``_key``)."""
    out: dict = {}
    for k, v in infos.items():
        if k.startswith("_"):
            continue
        mask = infos.get(f"_{k}")
        if mask is not None and not mask[i]:
            continue
        out[k] = info_at(v, i) if isinstance(v, dict) else v[i]
    return out


# ---------------------------------------------------------------- guides
class PolicyGuide:
    """A trained policy (the oracle) as guide: its Gaussian mean and learned std on its own observation.

    The oracle reads the privileged part of the same vector observation (depth stack, state, privileged Δp).
    It is stateless, so the rollout evaluates it in chunks (``batched``; see the module docstring).
    """

    batched = True

    def __init__(self, agent: ActorCritic) -> None:
        self.agent = agent.eval()
        for p in self.agent.parameters():
            p.requires_grad_(False)

    def prepare(self, obs: Any) -> dict[str, torch.Tensor]:
        """The guide's input for one vector step, as tensors that do not alias the env's buffers."""
        return self.agent.prepare(obs)

    def to(self, device: Any) -> PolicyGuide:
        """Run the guide's network on ``device`` (its prepared inputs stay in host memory until evaluated)."""
        self.agent.to(device)
        return self

    @torch.no_grad()
    def distribution_stored(self, stored: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and std (B, A) float32, on the guide's device, for prepared inputs of B states."""
        mean, std = self.agent.distribution(to_device(stored, next(self.agent.parameters()).device))
        return mean.float(), std.float()

    def distribution(self, obs: Any, infos: dict, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mean, std = self.distribution_stored(self.prepare(obs))
        return mean.cpu().numpy(), std.cpu().numpy()


class PlannerGuide:
    """Deterministic planner(s) as a guide with fixed std (the NPE baseline's non-expert guidance).

    Parameters
    ----------
    planners : one planner per env (each keeps its own per-episode state), or a zero-argument factory called
        ``n_envs`` times. A planner has ``act(obs, info) -> action (A,)``; when its env starts a new episode
        its ``reset`` is called with that env's reset info (which carries ``pose``, ``goal`` and ``path``; see
        :func:`omcrl.agent.start_episode`). Planners are not bound to the envs here (vector-env workers
        live in other processes), so HybridAPF follows the env's shortest path from the reset info.
    std : the fixed standard deviation (config ``rl.guide_std``), same for every action dim.
    n_envs : number of envs (needed with a factory).
    """

    def __init__(self, planners: Sequence[Any] | Callable[[], Any], std: float, n_envs: int | None = None) -> None:
        if callable(planners) and not isinstance(planners, Sequence):
            if n_envs is None:
                raise ValueError("PlannerGuide: n_envs is required when planners is a factory")
            planners = [planners() for _ in range(n_envs)]
        self.planners = list(planners)
        self.std = float(std)

    def distribution(self, obs: Any, infos: dict, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        acts = []
        for i, planner in enumerate(self.planners):
            info = info_at(infos, i)
            if starts[i]:
                start_episode(planner, info)
            a = np.asarray(planner.act(obs_at(obs, i), info), dtype=np.float32)
            acts.append(np.clip(a, -1.0, 1.0))
        mean = np.stack(acts)
        return mean, np.full_like(mean, self.std)
