"""Rover bags replayed into the live rocker-bogie estimator node (in-process, lockstep, no launch file).

For each bag marked ``live_replay`` in ``bags/expectations.yaml``, with the
estimator pair it names (``live_replay: 2`` = Estimators 1 + 2, two-axis load
cells; ``1`` = Estimators 1 + 3, reading only F_L from the same two-axis
bag):

* every ``wheel_terrain`` message is finite and well formed (wheels rear,
  middle, front; variances ≥ 0; stamps increasing) and, from ``settle_time``
  on, within the bag's absolute bounds of ``ground_truth/wheel_terrain`` at
  the same stamp;
* ``terrain_model`` is published, well formed, and its last DP(W, i) and
  τ_R(W, i) predict the true DP and τ_R of the bag's ground-truth samples
  inside the model's validity region (the traversed region) within the
  bag's bound, and within the model's own stated error (``*_prediction_rms``,
  issue 21; :data:`KNOWN_UNDERSTATED` lists where it is not, its bound, and why);
* the live node's messages are identical to the offline runner's
  (``terrain-estimate``) on the same bag;
* no input was rejected.

The bounds, and the errors measured when the bags were recorded, are in
``bags/expectations.yaml``; every rover bag is held to its bounds offline by
the ``slow`` test here (``pytest -m slow``). The adapters are also checked directly (no ROS
graph): bad input is rejected naming topic, field and value, and never
reaches the output; the simulator's messages follow the contract.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import TwistStamped, WrenchStamped
from sensor_msgs.msg import Imu, JointState

from integration.replay import LockstepReplay
from terrain_estimation.bag import read_bag
from terrain_estimation.models.terrain_response import PolynomialModel2D, polynomial_exponents
from terrain_estimation.nodes import make_estimator_node
from terrain_estimation.ros.rover import WHEEL_ORDER, make_adapter
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_ns
from terrain_estimation.tools.estimate import estimate_bag, numeric_fields
from terrain_estimation.vehicles import VEHICLES, estimator_parameters
from vehicle_sim.ros.registry import get_simulator, simulator_parameters

BAGS = Path(__file__).resolve().parents[2] / "bags"
EXPECTATIONS = yaml.safe_load((BAGS / "expectations.yaml").read_text())
ROVER_BAGS = [name for name, e in EXPECTATIONS.items() if e["estimate_topic"] == "wheel_terrain"]
# (bag, load-cell axes the estimator is told): one live replay per estimator pair keeps the test near 40 s.
LIVE_RUNS = [(name, EXPECTATIONS[name]["live_replay"]) for name in ROVER_BAGS if EXPECTATIONS[name].get("live_replay")]
NS = "/rover"
QUANTITIES = ("slip", "normal_load", "drawbar_pull", "resistive_torque", "contact_angle")


def _wheel_values(msg: Any, quantity: str) -> np.ndarray:
    return np.array([getattr(w, quantity) for w in msg.wheels], dtype=float)


def _check_wheel_terrain(msg: Any) -> None:
    assert msg.header.frame_id == "rover/base_link"
    assert [w.wheel for w in msg.wheels] == list(WHEEL_ORDER)
    for w in msg.wheels:
        values = numeric_fields(w)
        assert len(values) == 10 and all(math.isfinite(v) for v in values.values()), values
        assert min(v for k, v in values.items() if k.endswith("_variance")) >= 0.0


def _check_model(msg: Any) -> None:
    assert msg.header.frame_id == "rover/base_link"
    assert msg.order == 2
    assert len(msg.dp_coefficients) == len(msg.tau_coefficients) == len(polynomial_exponents(2))
    values = [*msg.dp_coefficients, *msg.tau_coefficients, *numeric_fields(msg).values()]
    assert all(math.isfinite(v) for v in values)
    assert msg.slip_min <= msg.slip_max and msg.load_min <= msg.load_max
    assert msg.samples >= 12 and msg.dp_rms >= 0.0 and msg.tau_rms >= 0.0
    # The model's error (issue 21): the coefficients' covariance and a held-out error, n x n and finite.
    n = len(msg.dp_coefficients)
    assert len(msg.dp_covariance) == len(msg.tau_covariance) == n * n
    assert all(math.isfinite(v) for v in (*msg.dp_covariance, *msg.tau_covariance))
    assert msg.dp_prediction_rms >= msg.dp_holdout_rms > 0.0 and msg.tau_prediction_rms >= msg.tau_holdout_rms > 0.0
    assert 0 < msg.validation_samples <= msg.samples


#: (bag, load-cell axes) whose last DP model states less than its true error: the true / stated ratio it must
#: stay under (measured 0.607 / 0.539 = 1.13), and why (issue 21).
KNOWN_UNDERSTATED: dict[tuple[str, int], tuple[float, str]] = {
    # Until issue 21, item 2, terrain 1 (E1+E2) needed 1.2: its DP estimates carried a bias the estimator's
    # over-confident DP variances did not state (σ 0.21 N on the middle wheel against a 0.44 N bias). With the
    # contact-angle error considered in the published variances, the stated error covers the true one everywhere.
}


def _check_against_truth(
    bag: str, axes: int, expect: dict[str, Any], wheels: list[Any], models: list[Any], truth: dict[int, Any]
) -> None:
    """The bag's bounds on every estimate after settling and on the last terrain model (module docstring)."""
    bounds, model_bounds = expect["absolute_tolerance"], expect["terrain_model"]
    worst = {q: np.zeros(3) for q in QUANTITIES}
    truth_stamps = np.array(sorted(truth), dtype=np.int64)
    previous = -1
    for msg in wheels:
        _check_wheel_terrain(msg)
        t = stamp_to_ns(msg.header.stamp)
        assert t > previous, "stamps must increase"
        previous = t
        if t * 1e-9 >= expect["settle_time"]:
            # The truth sample at the estimate's stamp, or the last before it (the truth is at 50 Hz).
            k = int(np.searchsorted(truth_stamps, t, side="right")) - 1
            assert k >= 0 and t - truth_stamps[k] < 20_000_000, "no ground truth within 20 ms before the estimate"
            ref = truth[int(truth_stamps[k])]
            for q in QUANTITIES:
                worst[q] = np.maximum(worst[q], np.abs(_wheel_values(msg, q) - _wheel_values(ref, q)))
    report = {q: np.round(w, 4).tolist() for q, w in worst.items()}
    for q in QUANTITIES:
        assert worst[q].max() < bounds[q], f"{q}: worst error (rear, middle, front) {report[q]}; all: {report}"

    assert len(models) >= model_bounds["min_models"], f"{len(models)} terrain models published"
    for msg in models:
        _check_model(msg)
    stamps = [stamp_to_ns(m.header.stamp) for m in models]
    assert stamps == sorted(set(stamps)), "terrain_model stamps must increase"
    last = models[-1]
    slip, load, pull, torque = (
        np.array([getattr(w, q) for m in truth.values() for w in m.wheels])
        for q in ("slip", "normal_load", "drawbar_pull", "resistive_torque")
    )
    inside = (slip >= last.slip_min) & (slip <= last.slip_max) & (load >= last.load_min) & (load <= last.load_max)
    # Most of the traversed (i, W); terrain 6's one model (its later periods are gated out) covers less: the
    # bag names its own floor (min_inside).
    min_inside = model_bounds.get("min_inside", 0.5)
    assert inside.mean() > min_inside, f"the model's validity region covers {inside.mean():.0%} of the traversed (i, W)"
    dp = PolynomialModel2D.from_coefficients(last.dp_coefficients)
    tau = PolynomialModel2D.from_coefficients(last.tau_coefficients)
    dp_rms = dp.residual_rms(slip[inside], load[inside], pull[inside])
    tau_rms = tau.residual_rms(slip[inside], load[inside], torque[inside])
    assert dp_rms < model_bounds["dp_rms"], f"DP model vs truth over the traversed region: RMS {dp_rms:.3f} N"
    assert tau_rms < model_bounds["tau_rms"], f"tau_R model vs truth over the traversed region: RMS {tau_rms:.4f} N m"
    # The stated error covers the model's true error where the rover drove (issue 21); KNOWN_UNDERSTATED
    # holds the one bag where it does not, with the ratio it must stay under and why.
    assert tau_rms <= last.tau_prediction_rms, f"τ_R: true {tau_rms:.4f} N m > stated {last.tau_prediction_rms:.4f}"
    ratio, why = KNOWN_UNDERSTATED.get((bag, axes), (1.0, ""))
    assert dp_rms <= ratio * last.dp_prediction_rms, (
        f"DP: true RMS {dp_rms:.3f} N > {ratio:g} x stated {last.dp_prediction_rms:.3f} N {why}"
    )


def _offline(bag: str, axes: int) -> tuple[Any, list[Any], list[Any], dict[int, Any]]:
    run = estimate_bag(BAGS / bag, "rover", overrides={"estimator.load_cell_axes": axes})
    truth = {stamp_to_ns(m.header.stamp): m for m in run.truth[f"{NS}/wheel_terrain"]}
    return run, run.messages(f"{NS}/wheel_terrain"), run.messages(f"{NS}/terrain_model"), truth


AXES = pytest.mark.parametrize("axes", [2, 1], ids=["estimators_1_2", "estimators_1_3"])


@pytest.mark.parametrize("bag, axes", LIVE_RUNS, ids=[f"{b}-estimators_1_{2 if a == 2 else 3}" for b, a in LIVE_RUNS])
def test_live_node_tracks_the_truth_and_fits_the_terrain(rclpy_context, bag, axes):
    offline, want_wheels, want_models, truth = _offline(bag, axes)
    assert len(want_wheels) > 50 and truth

    node = make_estimator_node("rover", context=rclpy_context, overrides={"estimator.load_cell_axes": axes})
    replay = LockstepReplay(node, rclpy_context)
    try:
        played = replay.play(read_bag(BAGS / bag))
        wheels = replay.collect(f"{NS}/wheel_terrain", len(want_wheels))
        models = replay.collect(f"{NS}/terrain_model", len(want_models))
        status = node.diagnostic_status()
    finally:
        replay.close()
        node.destroy_node()

    # Live and offline runs go through the same adapter: identical messages.
    assert played == offline.inputs_read
    assert len(wheels) == len(want_wheels) and len(models) == len(want_models)
    for got, want in zip(wheels, want_wheels, strict=True):
        assert got.header == want.header and got.wheels == want.wheels
    for got, want in zip(models, want_models, strict=True):
        assert got == want

    diagnostics = {kv.key: kv.value for kv in status.values}
    assert not [k for k in diagnostics if k.startswith("rejected")], diagnostics
    assert int(diagnostics["estimator"]) == (2 if axes == 2 else 3)
    assert int(diagnostics["model_fits_published"]) == len(models)

    _check_against_truth(bag, axes, EXPECTATIONS[bag], wheels, models, truth)


@pytest.mark.slow
@AXES
@pytest.mark.parametrize("bag", ROVER_BAGS)
def test_every_rover_bag_offline(bag, axes):
    """The same bounds on every rover bag, offline (terrain-estimate's runner; slow: about 6 s each)."""
    run, wheels, models, truth = _offline(bag, axes)
    assert wheels
    _check_against_truth(bag, axes, EXPECTATIONS[bag], wheels, models, truth)


# ---------------------------------------------------------------------------
# Adapters, directly (no ROS graph)
# ---------------------------------------------------------------------------


def _sim_messages(seconds: float, **overrides: Any) -> list[tuple[str, Any]]:
    entry = get_simulator("rover")
    adapter = entry.make_adapter(simulator_parameters(entry, overrides=overrides), NS)
    out: list[tuple[str, Any]] = []
    t = 0.0
    while t < seconds - 1e-9:
        t, messages = adapter.step()
        out.extend(messages)
    return out


_SENSOR_KEYS = ("imu", "joint_states", "velocimeter", "load_front", "load_middle", "load_rear")


def test_every_setting_of_the_core_is_a_parameter_with_the_core_default():
    from terrain_estimation.estimators.rover import RoverEstimatorConfig, TerrainResponseConfig
    from terrain_estimation.ros import rover

    assert set(rover.CONFIG_PARAMETERS) == set(RoverEstimatorConfig.__dataclass_fields__)
    values = estimator_parameters(VEHICLES["rover"])
    config = rover.estimator_config(values)
    assert config == RoverEstimatorConfig()  # config/rover.yaml holds the core's defaults
    assert rover.terrain_response_config(values) == TerrainResponseConfig()
    for group, obj in (
        ("noise", config.sensor_noise),
        ("floors", config.floors),
        ("process_noise", config.general_process_noise),
        ("process_noise", config.wheel_force_process_noise),
    ):
        for name in type(obj).__dataclass_fields__:
            assert f"{group}.{name}" in values
    for name in type(config.rover).__dataclass_fields__:
        assert f"vehicle.{name}" in values
    specs = {s.name: s for s in rover.PARAMETERS}
    assert all(s.description for s in specs.values())
    assert all(s.min_value is not None for s in specs.values() if s.kind in (int, float))


def test_simulator_messages_follow_the_contract():
    messages = _sim_messages(0.1, **{"sensors.load_cell_axes": 1})
    by_key: dict[str, list[Any]] = {}
    for key, msg in messages:
        by_key.setdefault(key, []).append(msg)
    assert {k: len(v) for k, v in by_key.items()} == {k: 6 for k in (*_SENSOR_KEYS, "truth_wheel_terrain")}
    imu = by_key["imu"][0]
    assert imu.header.frame_id == "rover/imu_link" and imu.orientation_covariance[0] == -1.0
    assert 9.5 < imu.linear_acceleration.z < 10.1  # REP 145: +g along z, nearly level
    joints = by_key["joint_states"][-1]
    assert joints.name == ["bogie", "rear_wheel", "middle_wheel", "front_wheel"]
    assert len(joints.position) == len(joints.velocity) == len(joints.effort) == 4 and joints.effort[0] == 0.0
    # 2 cm/s on a 75 mm wheel: about 0.27 rad/s by encoder differences.
    assert all(0.2 < v < 0.35 for v in joints.velocity[1:])
    for wheel in ("front", "middle", "rear"):
        cell = by_key[f"load_{wheel}"][0]
        assert cell.header.frame_id == f"rover/{wheel}_load_cell"
        assert cell.wrench.force.x == 0.0 and 20.0 < cell.wrench.force.z < 100.0  # single-axis: F_perp not sent
    truth = by_key["truth_wheel_terrain"][0]
    assert [w.wheel for w in truth.wheels] == list(WHEEL_ORDER)
    assert all(math.isfinite(v) for w in truth.wheels for v in numeric_fields(w).values())
    stamps = {stamp_to_ns(m.header.stamp) for key, m in messages if key == "imu"}
    assert stamps == {round(k * 0.02 * 1e9) for k in range(6)}  # t = 0 ... 0.1 s


def _adapter(**overrides: Any) -> Any:
    return make_adapter(estimator_parameters(VEHICLES["rover"], overrides=overrides), NS)


def test_bad_input_is_rejected_by_topic_field_and_value_and_never_published():
    adapter = _adapter()
    messages = _sim_messages(2.5)
    published: list[tuple[str, Any]] = []
    for key, msg in messages:
        if key == "truth_wheel_terrain":
            continue
        stamp = stamp_to_ns(msg.header.stamp)
        if key == "imu" and stamp == round(0.3e9):
            msg.linear_acceleration.x = math.nan
        if key == "joint_states" and stamp == round(0.5e9):
            msg.effort = [0.0, math.inf, 1.0, 1.0]
        if key == "load_middle" and stamp == round(0.7e9):
            msg.wrench.force.x = math.nan
        published.extend(adapter.handle(key, msg))
    # A joint state without the bogie and a stamp out of order.
    bad_joints = JointState(name=["rear_wheel"], position=[0.0], effort=[0.0])
    bad_joints.header.stamp = sec_to_stamp(2.6)
    published.extend(adapter.handle("joint_states", bad_joints))
    late = TwistStamped()
    late.header.stamp = sec_to_stamp(0.1)
    published.extend(adapter.handle("velocimeter", late))

    rejected = adapter.health.rejected
    assert rejected.get("imu: linear_acceleration.x = nan is not finite") == 1, rejected
    assert rejected.get("joint_states: effort[rear_wheel] = inf is not finite") == 1, rejected
    assert rejected.get("wheel/middle/load: wrench.force.x = nan is not finite") == 1, rejected
    assert any(r.startswith("joint_states: name = ['rear_wheel'] lacks bogie") for r in rejected), rejected
    assert rejected.get("velocimeter: header.stamp = 0.1 is not after the previous sample's") == 1, rejected
    assert len(rejected) == 5
    wheel_msgs = [m for key, m in published if key == "wheel_terrain"]
    assert len(wheel_msgs) >= 10
    for msg in wheel_msgs:
        _check_wheel_terrain(msg)


def test_single_axis_cells_are_flagged_when_two_axes_are_configured():
    adapter = _adapter()
    for key, msg in _sim_messages(1.5, **{"sensors.load_cell_axes": 1}):
        if key != "truth_wheel_terrain":
            adapter.handle(key, msg)
    assert any("set estimator.load_cell_axes: 1" in w for w in adapter.health.warnings)
    single = _adapter(**{"estimator.load_cell_axes": 1})
    cell = WrenchStamped()
    cell.header.stamp = sec_to_stamp(0.0)
    cell.wrench.force.z, cell.wrench.force.x = 50.0, math.nan  # force.x is not read with one axis
    single.handle("load_front", cell)
    imu = Imu()
    imu.header.stamp = sec_to_stamp(0.0)
    single.handle("imu", imu)
    assert not single.health.rejected and not single.health.warnings


def test_innovation_test_is_consistent_on_a_nominal_run_and_flags_a_load_cell_offset_within_2_s():
    """Issue 21: the diagnostics' NIS has its χ² mean on a nominal run; a 0.3 N load-cell offset WARNs within 2 s.

    The NIS is over the channels whose S is sensor noise plus state uncertainty (slips, load cells and the
    side's force balance, ``estimators.rover_diagnostics``); before, the 20 channels of both filters gave about
    half their dof on every nominal run and no check looked at the last 2 s.
    """
    fault_at, offset = 40.0, 0.3
    adapter = _adapter()
    nominal: list[float] = []
    warned_at = None
    for key, msg in _sim_messages(fault_at + 4.0):
        if key == "truth_wheel_terrain":
            continue
        t = stamp_to_ns(msg.header.stamp) * 1e-9
        if key == "load_middle" and t >= fault_at:
            msg.wrench.force.z += offset
        if adapter.handle(key, msg):
            jumped = [w for w in adapter.health.warnings if w.startswith("innovations jumped")]
            if t < fault_at:
                assert not jumped, (t, jumped)
                nominal = list(adapter.health.nis)
            elif jumped and warned_at is None:
                warned_at = t
    assert adapter.health.nis_dof == 11
    # Settled estimates only (the first 2 s describe the start); 2-40 s of terrain 1: 8.4 of 10 when written,
    # 9.0 once the process noise was sized per step; 10.0-10.4 of 11 with the slips (not the velocimeter, whose
    # noise is theirs) and the force balance.
    assert len(nominal) >= 180
    assert 0.8 * 11 <= float(np.mean(nominal)) <= 1.2 * 11, np.mean(nominal)
    assert warned_at is not None and warned_at - fault_at <= 2.0, warned_at
