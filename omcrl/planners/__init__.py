"""Occupancy grid, any-angle shortest path and the Hybrid APF baseline."""

from omcrl.planners.grid import OccupancyGrid, build_grid, geodesic, shortest_path

__all__ = ["OccupancyGrid", "build_grid", "geodesic", "shortest_path"]

from omcrl.planners.apf import HybridAPF

__all__ += ["HybridAPF"]
