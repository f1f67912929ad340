"""Issue 20 item 5: skid-steer geometry for N axles per side (the 4-wheel Husky as 2 axles), and a config
file with an estimator section (``config/husky.yaml``) read by the offline tool without extra code."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from sensor_msgs.msg import Imu, JointState

from terrain_estimation.bag import AtomicBagWriter
from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from terrain_estimation.models.skid_steer import (
    WHEEL_NAMES,
    SkidSteerParams,
    axle_count,
    axle_positions,
    body_forces,
    contact_velocities,
    contract_tire_sideslip,
    quasi_static_loads,
    wheel_names,
    wheel_positions,
)
from terrain_estimation.models.skid_steer_observer import SkidSteerInput, SkidSteerObserverModel, tire_sideslips
from terrain_estimation.ros.skid_steer import estimator_config, husky_overrides
from terrain_estimation.ros.time import ns_to_stamp
from terrain_estimation.tools.estimate import config_values, main
from terrain_estimation.vehicles import get_vehicle

CONFIG = Path(__file__).resolve().parents[1] / "config"
HUSKY = SkidSteerParams(
    mass=50.0,
    yaw_inertia=5.95,
    axle_x=(0.256, -0.256),
    track=0.555,
    cg_height=0.2,
    wheel_radius=0.165,
    transmission_ratio=78.71,
    longitudinal_stiffness=1000.0,
    cornering_stiffness=1000.0,
)
FOUR_AXLES = SkidSteerParams(axle_x=(1.5, 0.5, -0.4, -1.6))


def test_two_axle_geometry_gives_the_rigid_body_contact_velocities():
    assert axle_count(HUSKY) == 2 and wheel_names(HUSKY) == ("FL", "RL", "FR", "RR")
    xw, yw = wheel_positions(HUSKY)
    np.testing.assert_array_equal(xw, [0.256, -0.256, 0.256, -0.256])
    np.testing.assert_array_equal(yw, [0.2775, 0.2775, -0.2775, -0.2775])
    # v_contact = v + r × p for a planar rigid body: (vx − r y, vy + r x) at each wheel.
    vx, vy, r = 0.8, -0.05, 0.6
    cvx, cvy = contact_velocities(vx, vy, r, HUSKY)
    np.testing.assert_allclose(cvx, [vx - r * 0.2775, vx - r * 0.2775, vx + r * 0.2775, vx + r * 0.2775], rtol=1e-15)
    np.testing.assert_allclose(cvy, [vy + r * 0.256, vy - r * 0.256, vy + r * 0.256, vy - r * 0.256], rtol=1e-15)
    assert tire_sideslips(np.array([vx, vy, r]), HUSKY).shape == (4,)
    # The paper's vehicle is unchanged by default.
    assert axle_count(SkidSteerParams()) == 3 and wheel_names(SkidSteerParams()) == WHEEL_NAMES
    np.testing.assert_allclose(axle_positions(SkidSteerParams()), [1.592, -0.244, -1.280], atol=1e-12)


@pytest.mark.parametrize("p", [HUSKY, FOUR_AXLES], ids=["2 axles", "4 axles"])
@pytest.mark.parametrize("ax, ay", [(0.0, 0.0), (1.0, 0.0), (-0.8, 1.5)])
def test_loads_balance_weight_pitch_and_roll_for_any_axle_count(p, ax, ay):
    fz = quasi_static_loads(ax, ay, p)
    n = axle_count(p)
    assert fz.shape == (2 * n,) and np.all(fz > 0.0)
    xw, yw = wheel_positions(p)
    m, g, h = p.mass, p.gravity, p.cg_height
    assert fz.sum() == pytest.approx(m * g, rel=1e-12)
    assert fz @ xw == pytest.approx(-m * ax * h, abs=1e-9 * m * g)
    assert fz @ yw == pytest.approx(-m * ay * h, abs=1e-9 * m * g)


def test_two_axle_observer_forces_are_the_shared_functions():
    model = SkidSteerObserverModel(HUSKY)
    u = SkidSteerInput(3.0, 3.6, 0.2, 0.4)
    x = np.array([[0.45, 0.01, 0.3], [0.5, -0.02, -0.1], [0.0, 0.0, 0.0]])
    for a, b in zip(model.forces(x, u), model.reference_forces(x, u), strict=True):
        np.testing.assert_array_equal(a, b)
    assert model._terms(u).omega_wheel.tolist() == [3.0, 3.0, 3.6, 3.6]
    fx, fy, mz = body_forces(np.ones(4), np.zeros(4), HUSKY)
    assert (fx, fy, mz) == (4.0, 0.0, 0.0)
    assert model.f(x, u, 0.01).shape == (3, 3) and model.h(x, u).shape == (3, 3)


def test_contract_tire_sideslip_maps_any_axle_count_onto_six():
    three = np.arange(6.0)
    np.testing.assert_array_equal(contract_tire_sideslip(three, SkidSteerParams()), three)
    # Two axles: front, mean of front and rear, rear per side.
    np.testing.assert_allclose(contract_tire_sideslip([0.1, 0.3, -0.2, -0.4], HUSKY), [0.1, 0.2, 0.3, -0.2, -0.3, -0.4])
    # Four axles at 1.5, 0.5, −0.4, −1.6: midpoint −0.05 between axles 2 and 3 (weight 0.55/0.9 on axle 3).
    alpha = np.array([0.4, 0.3, 0.2, 0.1, -0.4, -0.3, -0.2, -0.1])
    w = 0.55 / 0.9
    expected = [0.4, 0.3 + w * (0.2 - 0.3), 0.1, -0.4, -0.3 + w * (-0.2 + 0.3), -0.1]
    np.testing.assert_allclose(contract_tire_sideslip(alpha, FOUR_AXLES), expected, rtol=1e-14)
    with pytest.raises(ValueError, match="2N = 4"):
        contract_tire_sideslip(three, HUSKY)


@pytest.mark.parametrize("p", [HUSKY, FOUR_AXLES], ids=["2 axles", "4 axles"])
def test_estimator_publishes_every_wheel_and_the_contract_six(p):
    est = SkidSteerEstimator(SkidSteerEstimatorConfig(vehicle=p))
    rim = 0.5 if p is HUSKY else 2.0
    for k in range(1, 200):
        t = 0.01 * k
        motor = p.transmission_ratio / p.wheel_radius
        est.add_joint_state(t, (rim - 0.05) * motor, (rim + 0.05) * motor)
        est.add_imu(t, 0.0, 0.05, 0.15)
    e = est.last_estimate
    assert e is not None and not e.initialised
    n = axle_count(p)
    assert len(e.wheel_tire_sideslip) == 2 * n and len(e.tire_sideslip) == 6
    np.testing.assert_allclose(e.tire_sideslip, contract_tire_sideslip(e.wheel_tire_sideslip, p), rtol=1e-12)
    np.testing.assert_allclose(e.wheel_tire_sideslip, tire_sideslips(np.array([e.vx, e.vy, e.yaw_rate]), p), rtol=1e-12)
    assert all(math.isfinite(v) for v in (e.vx, e.vy, e.yaw_rate))


@pytest.mark.parametrize("axles", [[0.5, 0.5], [0.1, 0.2], [0.3, math.nan]])
def test_bad_axle_positions_are_refused_naming_them(axles):
    with pytest.raises(ValueError, match="axle_x"):
        SkidSteerParams(axle_x=tuple(axles))


def test_husky_config_is_the_two_axle_husky_for_the_estimator():
    values = config_values(get_vehicle("skid_steer"), CONFIG / "husky.yaml")
    cfg = estimator_config(values)
    assert values["vehicle.kind"] == "skid_steer"
    assert cfg.vehicle.axle_x == (0.256, -0.256) and cfg.vehicle.track == 0.555
    assert (cfg.vehicle.longitudinal_stiffness, cfg.vehicle.cornering_stiffness) == (1000.0, 1000.0)  # per wheel
    assert cfg.vehicle.mass == 50.0 and cfg.max_speed == 1.5
    # The same as the explicit overrides (husky_overrides reads the section over '/**').
    assert estimator_config(config_values(get_vehicle("skid_steer"), None, husky_overrides())) == cfg


def _husky_bag(path: Path, seconds: float = 3.0) -> Path:
    """A Husky driving straight at 0.4 m/s: IMU at 100 Hz, wheel speeds at 6.5 Hz, under /husky."""
    motor = 0.4 / 0.165 * 78.71
    items = []
    for k in range(int(seconds * 100)):
        imu = Imu()
        imu.header.stamp = ns_to_stamp(10_000_000 * k)
        imu.header.frame_id = "husky/imu_link"
        imu.linear_acceleration.z = 9.81
        imu.orientation_covariance[0] = -1.0
        items.append((10_000_000 * k, "/husky/imu", imu))
    for k in range(int(seconds * 6.5)):
        joints = JointState()
        stamp = round(k / 6.5 * 1e9)
        joints.header.stamp = ns_to_stamp(stamp)
        joints.name = ["left_motor", "right_motor"]
        joints.velocity = [motor, motor]
        joints.position = [0.0, 0.0]
        items.append((stamp, "/husky/joint_states", joints))
    with AtomicBagWriter(path) as writer:
        for stamp, topic, msg in sorted(items, key=lambda i: i[0]):
            writer.write(topic, msg, stamp)
    return path


def test_offline_tool_reads_the_husky_config_by_itself(tmp_path, capsys):
    bag = _husky_bag(tmp_path / "husky")
    argv = [str(bag), "--vehicle", "skid_steer", "--namespace", "/husky", "-o", str(tmp_path / "out")]
    assert main([*argv, "--config", str(CONFIG / "husky.yaml")]) == 0
    out = capsys.readouterr().out
    assert "2 axles per side" in out and "6.5 Hz measured" in out, out
    # A typo in the estimator's own section is still refused.
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        (CONFIG / "husky.yaml").read_text().replace("      axle_x: [0.256, -0.256]", "      axle_xx: [0.256, -0.256]")
    )
    assert main([*argv, "--config", str(bad), "--overwrite"]) == 2
    assert "unknown parameter 'vehicle.axle_xx'" in capsys.readouterr().err


def test_node_file_values_read_a_file_of_another_kind_as_rcl_does(tmp_path):
    from terrain_estimation.config_sections import describes_another_kind, node_file_values
    from terrain_estimation.params import ParameterError, load_parameter_file
    from terrain_estimation.ros.framework import EstimatorNode

    entry = get_vehicle("skid_steer")
    specs = tuple(EstimatorNode.COMMON_SPECS) + tuple(entry.specs)
    husky = CONFIG / "husky.yaml"
    assert describes_another_kind(husky, entry.node_name, specs)
    with pytest.raises(ParameterError, match="vehicle.wheelbase"):
        load_parameter_file(husky, [entry.node_name], specs=specs)  # the strict reading refuses the file
    values = node_file_values(husky, entry.node_name, specs)
    assert values["vehicle.kind"] == "skid_steer" and values["vehicle.axle_x"] == [0.256, -0.256]
    assert values["vehicle.mass"] == 50.0 and "vehicle.wheelbase" not in values
    # A file of the estimator's own kind stays strict in '/**'.
    assert not describes_another_kind(CONFIG / "skid_steer.yaml", entry.node_name, specs)
    own = tmp_path / "own.yaml"
    own.write_text('"/**":\n  ros__parameters:\n    vehicle:\n      kind: "skid_steer"\n      wheelbase: 0.5\n')
    with pytest.raises(ParameterError, match="vehicle.wheelbase"):
        node_file_values(own, entry.node_name, specs)
