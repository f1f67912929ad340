"""Skid-steer bags replayed into the live AN-STUKF node (in-process, lockstep, no
launch file): the estimated twist and body sideslip stay within the bounds stored
beside each bag against the simulator's ground truth, and every published
message is finite and well-formed."""

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
SKID_BAGS = [name for name, e in EXPECTATIONS.items() if e["estimate_topic"] == "skid_steer/state"]


@pytest.mark.parametrize("bag", SKID_BAGS)
def test_live_node_tracks_the_truth(rclpy_context, bag):
    expect = EXPECTATIONS[bag]
    ns = "/skid_steer"
    truth = {
        stamp_to_sec(m.msg.header.stamp): m.msg for m in read_bag(BAGS / bag, [f"{ns}/ground_truth/skid_steer/state"])
    }
    n_imu = sum(1 for _ in read_bag(BAGS / bag, [f"{ns}/imu"]))
    assert truth and n_imu, "the bag needs imu and ground truth"
    node = make_estimator_node("skid_steer", context=rclpy_context)
    replay = LockstepReplay(node, rclpy_context)
    try:
        replay.play(read_bag(BAGS / bag))
        states = replay.collect(f"{ns}/skid_steer/state", expected=n_imu)
        odoms = replay.collect(f"{ns}/odom", expected=n_imu)
    finally:
        replay.close()
        node.destroy_node()

    assert len(states) == n_imu and len(odoms) == n_imu  # one estimate per IMU sample
    errors: dict[str, list[float]] = {name: [] for name in expect["absolute_tolerance"]}
    previous = -math.inf
    for state, odom in zip(states, odoms, strict=True):
        t = stamp_to_sec(state.header.stamp)
        assert t > previous, "stamps must increase"
        previous = t
        assert state.header.frame_id == "skid_steer/base_link"
        assert odom.header.frame_id == "skid_steer/odom" and odom.child_frame_id == "skid_steer/base_link"
        assert stamp_to_sec(odom.header.stamp) == t
        assert all(math.isfinite(v) for v in numeric_fields(state).values())
        assert all(math.isfinite(v) for v in numeric_fields(odom).values())
        assert all(math.isfinite(v) for v in state.tire_sideslip)
        assert min(state.vx_variance, state.vy_variance, state.yaw_rate_variance, state.body_sideslip_variance) >= 0
        # Fading >= 1; the noise scale is 1 + K_q mean|alpha| (an_stukf) or the innovation-matched Q scale of
        # the default filter, which shrinks Q as well as grows it.
        assert state.fading_factor >= 1.0 and state.noise_scale > 0.0
        assert odom.twist.twist.linear.x == state.vx and odom.twist.covariance[0] == state.vx_variance
        if state.icr_valid:
            assert abs(state.yaw_rate) > 0.0
        else:
            assert state.icr_x == 0.0 and state.icr_y == 0.0
        if t >= expect["settle_time"]:
            ref = truth[t]
            for name in errors:
                errors[name].append(abs(getattr(state, name) - getattr(ref, name)))
    for name, errs in errors.items():
        assert errs, "the bag is shorter than the settle time"
        worst = max(errs)
        assert worst < expect["absolute_tolerance"][name], f"{name}: worst error {worst:.4f} after settling"
