"""Occupancy grid, any-angle shortest path, the Hybrid APF baseline (privileged and perceptive), NPE's
non-expert guide (a local potential field on the depth camera) and the blind pilot (no sensing at all)."""

from omcrl.envs.grid import OccupancyGrid, build_grid, geodesic, shortest_path
from omcrl.planners.apf import HybridAPF, LocalAPF, PerceptiveHybridAPF
from omcrl.planners.blind import BlindPilot

# Every planner of the kit by name, from no sensing to the true map: what Table I and the suite criteria fly.
PLANNERS: dict[str, type] = {
    "blind": BlindPilot,
    "local-apf": LocalAPF,
    "hybrid-apf-perceptive": PerceptiveHybridAPF,
    "hybrid-apf": HybridAPF,
}
# A student's planner guide (MethodSpec.guide) -> (its planner in PLANNERS, the name that enters the run's identity).
GUIDES: dict[str, tuple[str, str]] = {"apf": ("hybrid-apf", "hybrid_apf"), "local-apf": ("local-apf", "local_apf")}
# How tables name the planners that are not methods of the comparison (those have a MethodSpec label).
LABELS: dict[str, str] = {"local-apf": "Local APF (NPE's guide)", "blind": "Blind pilot (senses nothing)"}
# The evaluation stage's row of the privileged planner is its class name (the paper's "Hybrid APF").
ALIASES: dict[str, str] = {"HybridAPF": "hybrid-apf"}


def make_planner(name: str, env_config: object = None) -> object:
    """A fresh planner of :data:`PLANNERS` (or an alias of :data:`ALIASES`) for ``env_config`` (an
    :class:`omcrl.config.EnvConfig`; None: the defaults). ValueError names the known planners."""
    key = ALIASES.get(name, name)
    if key not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; expected one of {[*PLANNERS, *ALIASES]}")
    return PLANNERS[key](env_config)


__all__ = [
    "ALIASES",
    "GUIDES",
    "LABELS",
    "PLANNERS",
    "BlindPilot",
    "HybridAPF",
    "LocalAPF",
    "OccupancyGrid",
    "PerceptiveHybridAPF",
    "build_grid",
    "geodesic",
    "make_planner",
    "shortest_path",
]
