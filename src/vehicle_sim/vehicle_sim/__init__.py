"""Vehicle simulators: plants, terrain, sensors, unmodelled effects, and the
ROS 2 simulator nodes that publish them.

The math core (``vehicle_sim.plants``, ``vehicle_sim.terrain``) imports
numpy/scipy only, never rclpy.
"""

__version__ = "0.1.0"
