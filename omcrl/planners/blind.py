"""The blind pilot: the floor a method must beat (a pilot that senses nothing).

It flies the straight line from where the episode starts to the goal with the Hybrid APF's speed and heading law
(carrot following at cruise speed, slowing in the last metre, facing the direction of travel) and no repulsion:
no camera, no map, no obstacle vector. Whatever it reaches, a scene gives away without sight; on the v2 suite
every sampled goal lies behind an obstacle (``SceneSpec.line_blocked``), so it should fail there.
"""

from __future__ import annotations

import numpy as np

from omcrl.planners.apf import LocalAPF


class BlindPilot(LocalAPF):
    """Policy ``act(obs, info) -> action`` (float32 (3,) in [-1, 1]): straight to the goal, sensing nothing.

    The local APF (:class:`~omcrl.planners.LocalAPF`: the straight line to the goal, the Hybrid APF's speed and
    heading law) with its push taken away: pose and goal come from ``info`` (as for every policy's goal vector);
    ``obs`` is never read. Parameters are :class:`~omcrl.planners.HybridAPF`'s (``speed``, ``lookahead``).
    """

    name = "BlindPilot"
    uses_camera = False

    def act(self, obs: dict, info: dict) -> np.ndarray:
        if ("path" in info and info is not self._reset_info) or len(self.path) == 0:
            self.reset(info)
        return self._control(info, _NOTHING)


# Where a sensing planner would see its nearest obstacle: far beyond any influence radius, so nothing pushes.
_NOTHING = np.array([1e6, 0.0, 0.0])
