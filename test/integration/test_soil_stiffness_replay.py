"""A recorded bag replayed into the live soil-stiffness node (in-process,
lockstep, no launch file): the estimate settles within the tolerance stored
beside the bag, and every published message is finite and well-formed."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from integration.replay import LockstepReplay
from terrain_estimation.bag import read_bag
from terrain_estimation.nodes import make_estimator_node
from terrain_estimation.ros.time import stamp_to_sec
from terrain_estimation.tools.estimate import numeric_fields

BAGS = Path(__file__).resolve().parents[2] / "bags"
EXPECTATIONS = yaml.safe_load((BAGS / "expectations.yaml").read_text())
SOIL_BAGS = [name for name, e in EXPECTATIONS.items() if e["estimate_topic"] == "soil_stiffness"]


@pytest.mark.parametrize("bag", SOIL_BAGS)
def test_live_node_settles_within_tolerance(rclpy_context, bag):
    expect = EXPECTATIONS[bag]
    vehicle = expect["vehicle"]
    truth = [m.msg for m in read_bag(BAGS / bag, [f"/{vehicle}/ground_truth/soil_stiffness"])]
    assert truth, "the bag has no ground truth"
    node = make_estimator_node(vehicle, context=rclpy_context)
    replay = LockstepReplay(node, rclpy_context)
    try:
        replay.play(read_bag(BAGS / bag))
        expected = len(truth) - 1 - expect.get("steps_pending_at_end", 0)
        estimates = replay.collect(f"/{vehicle}/soil_stiffness", expected=expected)
    finally:
        replay.close()
        node.destroy_node()

    # one estimate per accelerometer sample after the first, but for the last
    # steps that still wait for road ahead when the bag ends
    assert len(estimates) >= expected
    truth_by_stamp = {stamp_to_sec(m.header.stamp): m.k_s for m in truth}
    previous = -math.inf
    late_errors = []
    for msg in estimates:
        t = stamp_to_sec(msg.header.stamp)
        assert t > previous, "stamps must increase"
        previous = t
        assert msg.header.frame_id == f"{vehicle}/base_link"
        assert all(math.isfinite(v) for v in numeric_fields(msg).values())
        assert msg.k_s > 0 and msg.k_s_variance >= 0 and msg.k_tot_variance >= 0
        assert 0.0 <= msg.class_confidence <= 1.0 and msg.terrain_class
        if t >= expect["settle_time"]:
            late_errors.append(abs(msg.k_s - truth_by_stamp[t]) / truth_by_stamp[t])
    assert late_errors, "the bag is shorter than the settle time"
    worst = max(late_errors)
    assert worst < expect["relative_tolerance"], (
        f"k_s error after {expect['settle_time']} s reached {100 * worst:.2f} %"
    )
