"""Test isolation for ROS 2: each test process gets its own ROS_DOMAIN_ID and
keeps DDS discovery on this host, so parallel workers (pytest-xdist) and a
demo running beside the tests never hear each other."""

from __future__ import annotations

import os

_worker = os.environ.get("PYTEST_XDIST_WORKER", "")
_index = int(_worker[2:]) if _worker.startswith("gw") else 0
# Domains 1..101 are safe on Linux (port ranges); spread runs by parent pid.
os.environ["ROS_DOMAIN_ID"] = str(1 + (os.getppid() % 25) * 4 + _index % 4)
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")

import pytest  # noqa: E402


@pytest.fixture
def rclpy_context():
    """A fresh rclpy context for one test, shut down afterwards."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)
