"""Occupancy grid, any-angle shortest path, the Hybrid APF baseline (privileged and perceptive) and NPE's
non-expert guide, a local potential field on the depth camera."""

from omcrl.planners.apf import HybridAPF, LocalAPF, PerceptiveHybridAPF
from omcrl.planners.grid import OccupancyGrid, build_grid, geodesic, shortest_path

__all__ = ["HybridAPF", "LocalAPF", "OccupancyGrid", "PerceptiveHybridAPF", "build_grid", "geodesic", "shortest_path"]
