"""Occupancy grid, any-angle shortest path, the Hybrid APF baseline (privileged and perceptive) and NPE's
non-expert guide, a local potential field on the depth camera."""

from omcrl.envs.grid import OccupancyGrid, build_grid, geodesic, shortest_path
from omcrl.planners.apf import HybridAPF, LocalAPF, PerceptiveHybridAPF

__all__ = ["HybridAPF", "LocalAPF", "OccupancyGrid", "PerceptiveHybridAPF", "build_grid", "geodesic", "shortest_path"]
