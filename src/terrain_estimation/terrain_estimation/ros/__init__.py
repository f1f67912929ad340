"""ROS 2 layer: message conversions, parameters, diagnostics and the node
framework every vehicle's estimator and simulator node is built on.

Everything here may import rclpy and message packages; nothing in
``terrain_estimation.filters``/``models``/``estimators`` may import this.
"""
