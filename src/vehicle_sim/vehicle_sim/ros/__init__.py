"""ROS 2 layer of the simulators: parameters, messages, nodes."""
