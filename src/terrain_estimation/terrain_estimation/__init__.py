"""Terrain estimation from what a vehicle feels: filters, estimation models,
ROS 2 adapters and nodes, offline tools.

The math core (``terrain_estimation.filters``, ``terrain_estimation.models``)
imports numpy/scipy only, never rclpy.
"""

__version__ = "0.1.0"
