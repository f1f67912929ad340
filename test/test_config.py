"""The vehicle configs document every parameter the nodes declare, and only those."""

from __future__ import annotations

from pathlib import Path

import pytest

from terrain_analysis.tools.config_template import render_config
from terrain_estimation.params import load_parameter_file, resolve_parameters
from terrain_estimation.ros.framework import EstimatorNode, SimulatorNode
from terrain_estimation.vehicles import VEHICLES
from vehicle_sim.ros.registry import get_simulator

CONFIG = Path(__file__).resolve().parents[1] / "config"


@pytest.mark.parametrize("vehicle", sorted(VEHICLES))
def test_committed_config_is_the_rendered_one(vehicle):
    assert (CONFIG / f"{vehicle}.yaml").read_text() == render_config(vehicle), (
        f"config/{vehicle}.yaml is stale: python -m terrain_analysis.tools.config_template {vehicle}"
    )


@pytest.mark.parametrize("vehicle", sorted(VEHICLES))
def test_every_parameter_has_a_comment_and_validates(vehicle):
    path = CONFIG / f"{vehicle}.yaml"
    lines = path.read_text().splitlines()
    for i, line in enumerate(lines):
        stripped = line.strip()
        is_value = ":" in stripped and not stripped.startswith("#") and not stripped.endswith(":")
        if is_value:
            assert lines[i - 1].strip().startswith("#"), f"{path.name}:{i + 1} has no comment: {stripped}"
    entry, sim = VEHICLES[vehicle], get_simulator(vehicle)
    est_specs = tuple(EstimatorNode.COMMON_SPECS) + tuple(entry.specs)
    sim_specs = tuple(SimulatorNode.COMMON_SPECS) + tuple(sim.specs)
    resolve_parameters(est_specs, load_parameter_file(path, [entry.node_name]), strict=True)
    resolve_parameters(sim_specs, load_parameter_file(path, [sim.node_name]), strict=True)


@pytest.mark.parametrize("vehicle", ["quarter_car", "lrv"])
def test_p0_of_the_stiffness_state_is_checked_against_its_units(vehicle):
    """A k_tot variance left in filter.p0_diag after switching to log_k_s (or the reverse) is an error."""
    from terrain_estimation.ros.soil_stiffness import estimator_config
    from terrain_estimation.vehicles import estimator_parameters

    entry = VEHICLES[vehicle]
    values = estimator_parameters(entry)
    assert estimator_config(values).vehicle_params.stiffness_state == "log_k_s"  # the node's default
    p0 = list(values["filter.p0_diag"])
    with pytest.raises(ValueError, match=r"filter.p0_diag\[-1\] = 2.25 is a k_tot variance"):
        estimator_config({**values, "filter.stiffness_state": "k_tot"})
    with pytest.raises(ValueError, match=r"filter.p0_diag\[-1\] = 2.5e\+09 is the variance of ln"):
        estimator_config({**values, "filter.p0_diag": [*p0[:-1], 50e3**2]})
    cfg = estimator_config({**values, "filter.stiffness_state": "k_tot", "filter.p0_diag": [*p0[:-1], 50e3**2]})
    assert cfg.vehicle_params.stiffness_state == "k_tot"


@pytest.mark.parametrize("vehicle", sorted(VEHICLES))
def test_every_declared_parameter_has_a_description_and_a_range(vehicle):
    """Issue 7 item 4: a number has a finite range on at least one side, a string its choices or a free text."""
    entry, sim = VEHICLES[vehicle], get_simulator(vehicle)
    specs = (
        tuple(EstimatorNode.COMMON_SPECS) + tuple(entry.specs) + tuple(SimulatorNode.COMMON_SPECS) + tuple(sim.specs)
    )
    missing = []
    for spec in specs:
        if len(spec.description.strip()) < 8:
            missing.append(f"{spec.name}: no description")
        if spec.kind in (int, float) and spec.min_value is None and spec.max_value is None:
            missing.append(f"{spec.name}: a number without a range")
    assert not missing, missing


def test_invalid_update_of_a_real_node_is_refused_with_the_reason(rclpy_context):
    """A live quarter-car estimator refuses an out-of-range and a wrong-type update and keeps its value."""
    from rclpy.parameter import Parameter

    entry = VEHICLES["quarter_car"]
    node = EstimatorNode(
        entry.node_name, tuple(entry.specs), entry.make_adapter, namespace="/qc", context=rclpy_context
    )
    try:
        before = node.values["filter.accel_noise_variance"]
        result = node.set_parameters([Parameter("filter.accel_noise_variance", value=-1.0)])[0]
        assert not result.successful and "filter.accel_noise_variance" in result.reason, result.reason
        assert node.values["filter.accel_noise_variance"] == before
    finally:
        node.destroy_node()


def test_sensor_queue_depth_is_a_parameter(rclpy_context):
    """qos.sensor_depth sets every sensor subscription's queue (a fast replay needs the whole backlog queued)."""
    from rclpy.parameter import Parameter

    entry = VEHICLES["quarter_car"]
    node = EstimatorNode(
        entry.node_name,
        tuple(entry.specs),
        entry.make_adapter,
        namespace="/qc",
        parameter_overrides=[Parameter("qos.sensor_depth", value=6000)],
        context=rclpy_context,
    )
    try:
        depths = {s.topic_name: s.qos_profile.depth for s in node.subscriptions if "clock" not in s.topic_name}
        assert depths and set(depths.values()) == {6000}, depths
        assert not node.set_parameters([Parameter("qos.sensor_depth", value=10)])[0].successful  # fixed at start
    finally:
        node.destroy_node()
