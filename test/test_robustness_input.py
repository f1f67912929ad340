"""Bad input, per message (issue 7 item 1), through live estimator nodes in lockstep.

Each kind of bad message is rejected before the adapter (so before the
filter), counted per reason in the ``/diagnostics`` the node publishes, and
logged (throttled) with topic, field and value; no estimator publishes a
non-finite number. Every test here fails when its check in
:mod:`terrain_estimation.ros.validation` (or the output check of the
framework) is removed.
"""

from __future__ import annotations

import copy
import math

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped
from rclpy.parameter import Parameter
from robustness_harness import Harness, Item, all_finite, bag_items

from terrain_estimation.ros import framework
from terrain_estimation.ros.framework import AdapterHealth, EstimatorNode, TopicSpec
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_sec

G = 9.80665


def _imus(items: list[Item], suffix: str = "/imu") -> list[int]:
    return [i for i, item in enumerate(items) if item.topic.endswith(suffix)]


def _run(rclpy_context, vehicle, items, overrides=None, sim_time=False):
    h = Harness(vehicle, rclpy_context, overrides, sim_time=sim_time)
    h.feed(items)
    return h


def test_non_finite_fields_are_rejected(rclpy_context):
    items = bag_items("skid_steer", 0.6)
    imu = _imus(items)[30]
    items[imu].msg.linear_acceleration.y = math.nan
    joints = _imus(items, "/joint_states")[40]
    velocity = list(items[joints].msg.velocity)
    velocity[0] = math.inf
    items[joints].msg.velocity = velocity
    bad_imu_t, bad_joint_t = items[imu].t, items[joints].t
    h = _run(rclpy_context, "skid_steer", items)
    try:
        assert bad_imu_t not in h.received_stamps("imu")
        assert bad_joint_t not in h.received_stamps("joint_states")
        states = h.estimates("skid_steer/state")
        assert len(states) == len(_imus(items)) - 1 and all(all_finite(s) for s in states)
        level, message, values = h.diagnostic()
        assert values["input rejected: imu: linear_acceleration.y is not finite"] == "1"
        assert values["input rejected: joint_states: velocity[left_motor] is not finite"] == "1"
        assert level == DiagnosticStatus.WARN and "2 input messages rejected" in message
    finally:
        h.close()


def test_wrong_frame_id_is_rejected(rclpy_context):
    items = bag_items("skid_steer", 0.4)
    imu = _imus(items)[20]
    items[imu].msg.header.frame_id = "base_link"
    bad_t = items[imu].t
    h = _run(rclpy_context, "skid_steer", items)
    try:
        assert bad_t not in h.received_stamps("imu")
        assert len(h.received_stamps("imu")) == len(_imus(items)) - 1
        _, _, values = h.diagnostic()
        assert values["input rejected: imu: header.frame_id is not 'skid_steer/imu_link'"] == "1"
    finally:
        h.close()


def test_accelerations_in_g_are_rejected_and_the_filter_restarted(rclpy_context):
    items = bag_items("skid_steer", 1.6)
    for i in _imus(items):
        a = items[i].msg.linear_acceleration
        a.x, a.y, a.z = a.x / G, a.y / G, a.z / G
    h = _run(rclpy_context, "skid_steer", items)
    try:
        reason = "imu: linear_acceleration (x, y, z) is in g, not m/s^2"
        rejected = h.node.guard.rejected[reason]
        accepted = h.received_stamps("imu")
        # judged once half a window (1 s) is in: those samples restarted the filter, none followed
        assert rejected == len(_imus(items)) - len(accepted) and rejected > 50
        assert max(accepted) < 1.05
        assert h.node.restarts == {reason: 1}
        assert h.node.adapter.health.updates == 0  # the filter holds nothing of the g-unit stream
        _, _, values = h.diagnostic()
        assert values[f"input rejected: {reason}"] == str(rejected)
    finally:
        h.close()


def test_accelerations_without_gravity_are_rejected(rclpy_context):
    items = bag_items("quarter_car", 1.3)
    for i in _imus(items, "/imu/body"):
        items[i].msg.linear_acceleration.z -= G
    h = _run(rclpy_context, "quarter_car", items)
    try:
        reason = "imu/body: linear_acceleration (z) lacks gravity (REP 145: specific force, gravity included)"
        rejected = h.node.guard.rejected[reason]
        assert rejected == len(_imus(items, "/imu/body")) - len(h.received_stamps("imu_body")) and rejected > 20
        assert h.node.restarts == {reason: 1}
        assert h.node.adapter.health.updates == 0
        _, _, values = h.diagnostic()
        assert values[f"input rejected: {reason}"] == str(rejected)
    finally:
        h.close()


def test_covariance_that_is_not_psd_is_rejected(rclpy_context):
    items = bag_items("skid_steer", 0.4)
    imu = _imus(items)[15]
    items[imu].msg.linear_acceleration_covariance = [1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0]  # eigenvalue -1
    bad_t = items[imu].t
    h = _run(rclpy_context, "skid_steer", items)
    try:
        assert bad_t not in h.received_stamps("imu")
        _, _, values = h.diagnostic()
        assert values["input rejected: imu: linear_acceleration_covariance is not positive semi-definite"] == "1"
    finally:
        h.close()


def test_stamps_out_of_order_are_rejected(rclpy_context):
    items = bag_items("skid_steer", 0.4)
    imus = _imus(items)
    late = copy.deepcopy(items[imus[10]])  # a sample of 0.1 s ago arrives again, late
    items.insert(imus[20], late)
    h = _run(rclpy_context, "skid_steer", items)
    try:
        stamps = h.received_stamps("imu")
        assert stamps == sorted(stamps) and len(stamps) == len(imus)
        _, _, values = h.diagnostic()
        assert values["input rejected: imu: header.stamp is before the previous sample's (out of order)"] == "1"
        assert "stale_or_out_of_order" not in values or values["stale_or_out_of_order"] == "0"
    finally:
        h.close()


def test_duplicated_stamps_are_rejected(rclpy_context):
    items = bag_items("skid_steer", 0.4)
    imu = _imus(items)[12]
    items.insert(imu + 1, copy.deepcopy(items[imu]))
    h = _run(rclpy_context, "skid_steer", items)
    try:
        stamps = h.received_stamps("imu")
        assert len(stamps) == len(set(stamps)) == len(_imus(items)) - 1
        _, _, values = h.diagnostic()
        assert values["input rejected: imu: header.stamp duplicates the previous sample's"] == "1"
    finally:
        h.close()


def test_stamp_far_in_the_future_never_reaches_the_filter(rclpy_context):
    """A bag replayed with /clock: one accelerometer sample of the LRV stamped a year ahead.

    Without the check it reaches the soil-stiffness core, whose newest time
    then lies a year ahead: every later sample is dropped as out of order and
    the estimate stops.
    """
    items = bag_items("lrv", 0.8)
    body = _imus(items, "/imu/body")[30]
    future = copy.deepcopy(items[body])
    future.msg.header.stamp = sec_to_stamp(future.t + 365 * 86400.0)
    future.drives_clock = False  # a rogue stamp: the bag's /clock goes on
    items.insert(body + 1, future)
    h = _run(rclpy_context, "lrv", items, sim_time=True)
    try:
        assert max(h.received_stamps("imu_body")) < 1.0
        estimates = h.estimates("soil_stiffness")
        assert estimates and stamp_to_sec(estimates[-1].header.stamp) > 0.7  # the estimate went on
        assert h.node.adapter.health.values["dropped_out_of_order"] == 0
        _, _, values = h.diagnostic()
        key = "input rejected: imu/body: header.stamp is more than input.max_future_stamp = 1 s ahead of the clock"
        assert values[key] == "1"
    finally:
        h.close()


class _Lines:
    def __init__(self):
        self.lines: list[tuple[str, str]] = []

    def __getattr__(self, level):
        return lambda text, **_: self.lines.append((level, text))


def test_rejections_are_logged_throttled_naming_topic_field_and_value(rclpy_context, monkeypatch):
    items = bag_items("skid_steer", 0.5)
    imus = _imus(items)
    for i in imus[10:20]:
        items[i].msg.angular_velocity.z = -math.inf
    wall = [1000.0]
    monkeypatch.setattr(framework, "_wall_time", lambda: wall[0])
    h = Harness("skid_steer", rclpy_context, {"input.log_throttle": 5.0})
    log = _Lines()
    h.node.get_logger = lambda: log  # type: ignore[method-assign]
    try:
        h.feed(items[: imus[19]])  # 9 rejections: one line
        wall[0] += 4.9
        h.feed(items[imus[19] : imus[19] + 1])  # 4.9 s later: still throttled
        wall[0] += 0.2
        items[imus[20]].msg.angular_velocity.z = math.nan
        h.feed(items[imus[19] + 1 : imus[20] + 1])  # 5.1 s after the first line: a line again
        lines = [text for level, text in log.lines if level == "warn"]
        assert lines == [
            "rejected imu: angular_velocity.z = -inf is not finite",
            "rejected imu: angular_velocity.z = nan is not finite (9 more since the last line)",
        ]
    finally:
        h.close()


class _NaNAdapter:
    """Test double: publishes the input's z as the estimate (a NaN too: no input check declared)."""

    def __init__(self, values, namespace):
        self.inputs = [TopicSpec("value", "value", PointStamped)]
        self.outputs = [TopicSpec("mean", "mean", PointStamped, "estimate")]
        self.health = AdapterHealth()

    def handle(self, key, msg):
        self.health.updates += 1
        self.health.last_update_time = stamp_to_sec(msg.header.stamp)
        out = PointStamped(header=msg.header)
        out.point.z = msg.point.z
        return [("mean", out)]

    def reset(self):
        pass


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_a_non_finite_estimate_is_never_published(rclpy_context, bad):
    node = EstimatorNode(
        "nan_estimator",
        (),
        _NaNAdapter,
        namespace="/veh",
        context=rclpy_context,
        parameter_overrides=[Parameter("diagnostics.period", value=60.0)],
    )
    h = Harness("test", rclpy_context, node=node)
    try:
        items = []
        for k in range(1, 6):
            msg = PointStamped()
            msg.header.stamp = sec_to_stamp(0.01 * k)
            msg.point.z = bad if k == 3 else float(k)
            items.append(Item("/veh/value", msg))
        h.feed(items)
        published = h.collect("/veh/mean", 4)
        assert [m.point.z for m in published] == [1.0, 2.0, 4.0, 5.0]
        level, message, values = h.diagnostic()
        assert values["output dropped: mean: point.z not finite"] == "1"
        assert level == DiagnosticStatus.ERROR and "non-finite estimates not published" in message
    finally:
        h.close()
