"""How agents meet episodes: the small protocol shared by the evaluation runner and the RL trainers' guides.

An agent is a learned policy (:class:`omcrl.rl.Policy`, an ONNX runtime) or a planner
(:class:`omcrl.planners.HybridAPF`): it maps an observation to an action and may want to hear when an episode
starts. This module sits below both :mod:`omcrl.rl` and :mod:`omcrl.eval`, so neither imports the other to
hand an episode to an agent.
"""

from __future__ import annotations

import inspect
from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class Agent(Protocol):
    """What the evaluation runner asks of a policy or planner.

    ``act(obs, info)`` takes one observation (the env's dict of arrays) and the step's ``info`` and returns the
    action, a ``(4,)`` array of normalised velocity commands in [-1, 1]. ``reset`` is optional (see
    :func:`start_episode`); learned policies also have ``act_batch`` (the runner's vectorised path).
    """

    def act(self, obs: Any, info: Any) -> Any: ...


def start_episode(agent: Any, info: dict) -> None:
    """Tell a policy or planner that a new episode starts, handing over the reset ``info`` if it takes it.

    ``agent.reset(info)`` when its ``reset`` accepts a positional argument (e.g. :class:`omcrl.planners.HybridAPF`,
    which needs the episode's ``pose``, ``goal`` and ``path``), ``agent.reset()`` when it takes none (stateless
    policies), nothing when there is no ``reset``. Shared by :func:`omcrl.eval.runner.evaluate` and the planner
    guide of the RL trainers, so a planner behaves the same in evaluation and as an NPE guide.
    """
    reset = getattr(agent, "reset", None)
    if reset is None:
        return
    try:
        params = inspect.signature(reset).parameters.values()
    except (TypeError, ValueError):  # builtins without a signature: call without the info
        params = []
    P = inspect.Parameter
    if any(p.kind in (P.POSITIONAL_ONLY, P.POSITIONAL_OR_KEYWORD, P.VAR_POSITIONAL) for p in params):
        reset(info)
    else:
        reset()
