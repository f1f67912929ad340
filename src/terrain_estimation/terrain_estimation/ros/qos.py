"""Quality-of-service choices, in one place and explained.

* Sensor topics follow the contract's sensor-data profile: best effort, so a
  subscriber accepts both best-effort and reliable publishers (a reliable
  subscriber would not match a best-effort IMU driver). The depth is raised
  from the profile's 5 to :data:`SENSOR_DEPTH` (an estimator node's
  ``qos.sensor_depth`` parameter) so that a burst (a 1 kHz profile sampler, a
  bag replayed fast) is queued, not dropped, while a callback runs. A replay
  faster than the node can filter (about 4x real time for a quarter car on a
  2-core machine, ``docs/results/robustness.md``) drops messages unless the
  queue holds the whole backlog: raise the depth (e.g. 6000 for a 4 s bag at
  20x) and the node falls behind and catches up instead.
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


def qos_for(kind: str, depth: int = 0) -> QoSProfile:
    """QoS of a topic kind: ``"sensor"`` or ``"estimate"`` (ground truth is an estimate).

    ``depth``: queue depth of a sensor subscription (0: :data:`SENSOR_DEPTH`); the
    estimator nodes take it from their ``qos.sensor_depth`` parameter.
    """
    if kind == "sensor":
        if depth > 0 and depth != SENSOR_DEPTH:
            return QoSProfile(
                history=SENSOR_QOS.history,
                depth=int(depth),
                reliability=SENSOR_QOS.reliability,
                durability=SENSOR_QOS.durability,
            )
        return SENSOR_QOS
    if kind == "estimate":
        return ESTIMATE_QOS
    raise ValueError(f"unknown topic kind {kind!r}: expected 'sensor' or 'estimate'")
