"""Live and offline estimation agree: the same bag replayed into the live
estimator node (in-process, lockstep) and run through terrain-estimate
produces identical estimates, message for message."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from integration.replay import LockstepReplay

from terrain_estimation.bag import read_bag
from terrain_estimation.nodes import make_estimator_node
from terrain_estimation.tools.estimate import estimate_bag, numeric_fields

BAGS = Path(__file__).resolve().parents[1] / "bags"


@pytest.mark.parametrize(
    "vehicle, bag", [("quarter_car", "quarter_car_graneville_iso_d_10ms"), ("lrv", "lrv_regolith_iso_g_2ms")]
)
def test_live_and_offline_estimates_are_identical(rclpy_context, vehicle, bag):
    path = BAGS / bag
    offline = estimate_bag(path, vehicle)
    topic = f"/{vehicle}/soil_stiffness"
    expected = offline.messages(topic)
    assert len(expected) > 100

    node = make_estimator_node(vehicle, context=rclpy_context)
    replay = LockstepReplay(node, rclpy_context)
    try:
        played = replay.play(read_bag(path))
        live = replay.collect(topic, len(expected))
    finally:
        replay.close()
        node.destroy_node()

    assert played == offline.inputs_read
    assert len(live) == len(expected)
    for got, want in zip(live, expected, strict=True):
        assert got.header == want.header
        assert got.terrain_class == want.terrain_class and got.converged == want.converged
        got_fields, want_fields = numeric_fields(got), numeric_fields(want)
        assert got_fields == want_fields  # bit-identical: the same adapter and filter
        assert all(math.isfinite(v) for v in got_fields.values())
