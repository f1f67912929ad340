"""Time (issue 7 item 3), through live estimator nodes on sim time driven by ``/clock``.

* A backward jump of ``/clock`` (a looping bag) resets the estimator
  cleanly: the second pass gives exactly the first pass's estimates.
* A large forward jump resets it too: the estimates after it are the ones a
  fresh filter gives on the same data.
* Both are reported on ``/diagnostics`` (WARN at once, then counted).
* A silent topic turns the diagnostics WARN, naming the topic and what the
  estimator does meanwhile (the skid-steer estimate holds), and clears when
  it resumes.

Each test fails when the jump callback, or the timeout check, of
:class:`~terrain_estimation.ros.framework.EstimatorNode` is removed.
"""

from __future__ import annotations

import math

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from robustness_harness import Harness, bag_items, shifted

from terrain_estimation.ros.skid_steer import ON_TIMEOUT
from terrain_estimation.ros.time import stamp_to_sec
from terrain_estimation.tools.estimate import numeric_fields


def _jump_statuses(h: Harness, direction: str) -> list[DiagnosticStatus]:
    return [
        s for a in h.diagnostics for s in a.status if f"clock jumped {direction}" in s.message and s.level == s.WARN
    ]


def test_backward_clock_jump_resets_the_estimator_cleanly(rclpy_context):
    segment = bag_items("quarter_car", 0.6)
    h = Harness("quarter_car", rclpy_context, sim_time=True)
    try:
        h.feed(segment)
        first = h.estimates("soil_stiffness")
        assert len(first) > 40
        h.set_clock(segment[0].t)  # the bag loops
        h.feed(bag_items("quarter_car", 0.6))
        second = h.estimates("soil_stiffness")[len(first) :]
        assert len(second) == len(first)
        for a, b in zip(first, second, strict=True):
            assert a.header == b.header and numeric_fields(a) == numeric_fields(b)
        assert _jump_statuses(h, "backward"), "no WARN diagnostic at the jump"
        _, _, values = h.diagnostic()
        assert values["clock_jumps_backward"] == "1" and "clock jumped backward" in values["last_reset"]
    finally:
        h.close()


def test_forward_clock_jump_resets_the_estimator(rclpy_context):
    segment = bag_items("quarter_car", 0.6)
    h = Harness("quarter_car", rclpy_context, sim_time=True)
    try:
        h.feed(segment)
        first = h.estimates("soil_stiffness")
        h.set_clock(segment[0].t + 100.0)  # a skipped stretch of the bag
        h.feed(shifted(segment, 100.0))
        second = h.estimates("soil_stiffness")[len(first) :]
        assert len(second) == len(first)
        # a fresh filter on the same data (stamps 100 s later: equal up to the rounding of the time steps)
        for a, b in zip(first, second, strict=True):
            assert stamp_to_sec(b.header.stamp) == pytest.approx(stamp_to_sec(a.header.stamp) + 100.0)
            assert b.k_s == pytest.approx(a.k_s, rel=1e-6)
            assert b.k_s_variance == pytest.approx(a.k_s_variance, rel=1e-5)
        assert _jump_statuses(h, "forward"), "no WARN diagnostic at the jump"
        _, _, values = h.diagnostic()
        assert values["clock_jumps_forward"] == "1" and values["clock_jumps_backward"] == "0"
        assert values["last_reset"].startswith("clock jumped forward by 99.") and "(to 100 s)" in values["last_reset"]
    finally:
        h.close()


def test_silent_topic_turns_diagnostics_warn_and_the_estimate_holds(rclpy_context):
    items = bag_items("skid_steer", 2.0)
    h = Harness("skid_steer", rclpy_context, sim_time=True)
    try:
        h.feed([i for i in items if i.t <= 0.5])
        _, message, values = h.diagnostic()
        assert values["silent_topics"] == "none" and "silent" not in message
        before = len(h.estimates("skid_steer/state"))
        # joint_states stops for a second; the IMU goes on
        h.feed([i for i in items if 0.5 < i.t <= 1.5 and i.topic.endswith("/imu")])
        level, message, values = h.diagnostic()
        assert level == DiagnosticStatus.WARN
        assert values["silent_topics"] == "joint_states"
        assert "joint_states silent for 1 s (timeout 0.5 s): " + ON_TIMEOUT["joint_states"] in message
        held = [stamp_to_sec(s.header.stamp) for s in h.estimates("skid_steer/state")[before:]]
        max_age = 0.05  # estimator.max_wheel_speed_age: then the estimate holds
        assert all(t <= 0.5 + max_age + 1e-9 for t in held)
        # it resumes
        h.feed([i for i in items if i.t > 1.5])
        _, message, values = h.diagnostic()
        assert values["silent_topics"] == "none" and "silent" not in message
        resumed = h.estimates("skid_steer/state")[before + len(held) :]
        assert resumed and all(math.isfinite(s.vx) for s in resumed)
    finally:
        h.close()


def test_stamps_going_back_without_clock_restart_the_estimator(rclpy_context):
    """A bag looped without /clock (wall-clock node): the stamps alone go back, for good."""
    h = Harness("skid_steer", rclpy_context)
    try:
        h.feed(bag_items("skid_steer", 0.8))
        first = h.estimates("skid_steer/state")
        h.feed(bag_items("skid_steer", 0.8))
        second = h.estimates("skid_steer/state")[len(first) :]
        after = 50  # input.restart_after_out_of_order: the estimator restarts on the 50th sample of the new pass
        assert second and min(stamp_to_sec(s.header.stamp) for s in second) >= 0.01 * after
        assert all(math.isfinite(s.vx) for s in second)
        level, message, values = h.diagnostic()
        reasons = [k for k in values if k.startswith("estimator restarts: ")]
        assert reasons and reasons[0].endswith("header.stamp went back for good (a new time line)")
        assert values[reasons[0]] == "1"
        assert level == DiagnosticStatus.WARN and "input messages rejected" in message
    finally:
        h.close()
