"""Occupancy grid, any-angle shortest path and the Hybrid APF baseline (privileged and perceptive)."""

from omcrl.planners.apf import HybridAPF, PerceptiveHybridAPF
from omcrl.planners.grid import OccupancyGrid, build_grid, geodesic, shortest_path

__all__ = ["HybridAPF", "OccupancyGrid", "PerceptiveHybridAPF", "build_grid", "geodesic", "shortest_path"]
