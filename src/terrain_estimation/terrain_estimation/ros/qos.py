"""Quality-of-service choices, in one place and explained.

* Sensor topics follow the contract's sensor-data profile: best effort, so a
  subscriber accepts both best-effort and reliable publishers (a reliable
  subscriber would not match a best-effort IMU driver). The depth is raised
  from the profile's 5 to :data:`SENSOR_DEPTH` so that a burst (a bag replayed
  at 20x, a 1 kHz profile sampler) is queued, not dropped, while a callback
  runs.
* Estimates and ground truth: reliable, keep last 10 (the contract).
* ``/clock``: the rclpy clock subscription's own profile is best effort,
  keep last 1; publishing it reliable is compatible with that.
"""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

__all__ = ["SENSOR_DEPTH", "SENSOR_QOS", "ESTIMATE_QOS", "CLOCK_QOS", "qos_for"]

SENSOR_DEPTH = 200

SENSOR_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=SENSOR_DEPTH,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)

ESTIMATE_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

CLOCK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)


def qos_for(kind: str) -> QoSProfile:
    """QoS of a topic kind: ``"sensor"`` or ``"estimate"`` (ground truth is an estimate)."""
    if kind == "sensor":
        return SENSOR_QOS
    if kind == "estimate":
        return ESTIMATE_QOS
    raise ValueError(f"unknown topic kind {kind!r}: expected 'sensor' or 'estimate'")
