"""Occupancy grid, any-angle shortest path, the Hybrid APF baseline (privileged and perceptive), NPE's
non-expert guide (a local potential field on the depth camera) and the blind pilot (no sensing at all)."""

from omcrl.envs.grid import OccupancyGrid, build_grid, geodesic, shortest_path
from omcrl.planners.apf import HybridAPF, LocalAPF, PerceptiveHybridAPF
from omcrl.planners.blind import BlindPilot

__all__ = [
    "BlindPilot",
    "HybridAPF",
    "LocalAPF",
    "OccupancyGrid",
    "PerceptiveHybridAPF",
    "build_grid",
    "geodesic",
    "shortest_path",
]
