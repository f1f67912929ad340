"""Divergence monitor of the skid-steer and rover estimators (issue 7 item 2, "Filter faults").

For each estimator a fault is injected into a shipped bag and the test checks
that (a) the divergence is detected, (b) the filter restarts from its last good
estimate and every output stays finite, (c) the fault clears:

* on the live node (its ``/diagnostics`` status: ERROR naming the divergence,
  then no longer ERROR), with a sensor reading a hundred times too large for
  a while that the node's input checks let through: the skid steer's gyro
  (0.5 s), the rover's velocimeter (2 s);
* on the rover's adapter, with its accelerometer a hundred times too large
  for 2 s (the node's gravity check would reject that; the adapter is what
  a check that misses it feeds): without the monitor Estimator 1 never comes
  back (pitch -1.8e4 rad at the end), with it the estimate re-converges;
* on the estimator cores, with the filter's covariance blown up at one step
  (a filter gone wrong while staying finite) and with a model that returns
  NaN for a few steps.

Every test with the monitor fails with it off (``filter.divergence_window``
0); the tests without it show what happens then.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from robustness_harness import all_finite, bag_items

from terrain_estimation.estimators.rover_noise import considered_variances
from terrain_estimation.filters.base import GaussianState
from terrain_estimation.nodes import make_estimator_node
from terrain_estimation.vehicles import VEHICLES, estimator_parameters

WINDOW = 20
ERROR = DiagnosticStatus.ERROR


# ---------------------------------------------------------------------------
# Live node: ERROR then OK
# ---------------------------------------------------------------------------


Fault = tuple[str, str, float, float]  # input key, field, from, to (s after the first stamp): x100


def _scale(msg: Any, field: str) -> None:
    *path, last = field.split(".")
    for name in path:
        msg = getattr(msg, name)
    setattr(msg, last, 100.0 * getattr(msg, last))


def _node_run(
    context: Any, vehicle: str, window: int, seconds: float, fault: Fault | None
) -> tuple[list[Any], list[tuple[float, bytes, str]], Any]:
    """Feed the bag's inputs to the node through its input checks, with ``fault``.

    Returns the adapter's outputs, ``(t, level, message)`` of the node's
    diagnostics after each IMU message, and the node (destroyed).
    """
    node = make_estimator_node(
        vehicle, context=context, overrides={"diagnostics.period": 60.0, "filter.divergence_window": window}
    )
    try:
        ns = node.get_namespace()
        keys = {f"{ns}/{spec.topic}": spec.key for spec in node.adapter.inputs}
        callbacks = {key: node._callback_for(key, lambda msg: msg) for key in keys.values()}  # messages, not bytes
        outputs: list[Any] = []
        inner = node.adapter.handle

        def spy(key: str, msg: Any) -> list[tuple[str, Any]]:
            out = inner(key, msg)
            outputs.extend(m for _, m in out)
            return out

        node.adapter.handle = spy  # type: ignore[method-assign]
        levels = []
        t0 = None
        for item in bag_items(vehicle, seconds):
            t = item.t
            t0 = t if t0 is None else t0
            key = keys[item.topic]
            if fault is not None and key == fault[0] and fault[2] <= t - t0 < fault[3]:
                _scale(item.msg, fault[1])
            callbacks[key](item.msg)
            if key == "imu":
                status = node.diagnostic_status()
                levels.append((t - t0, status.level, status.message))
        assert not node.outputs_dropped
        return outputs, levels, node
    finally:
        node.destroy_node()


def _error_span(levels: list[tuple[float, bytes, str]]) -> tuple[float, float, str] | None:
    errors = [(t, message) for t, level, message in levels if level == ERROR]
    if not errors:
        return None
    return errors[0][0], errors[-1][0], errors[0][1]


SKID_FAULT = ("imu", "angular_velocity.z", 3.0, 3.5)
ROVER_FAULT = ("velocimeter", "twist.linear.x", 6.0, 8.0)  # ten 0.2 s windows


def test_skid_steer_node_divergence_is_an_error_then_ok(rclpy_context: Any) -> None:
    outputs, levels, node = _node_run(rclpy_context, "skid_steer", WINDOW, 8.0, SKID_FAULT)
    assert outputs and all(all_finite(m) for m in outputs)
    span = _error_span(levels)
    assert span is not None, "the fault must be detected"
    first, last, message = span
    assert "filter diverged" in message and "last good estimate" in message, message
    assert SKID_FAULT[2] <= first < SKID_FAULT[3] + 0.5
    assert last < SKID_FAULT[3] + 2.0 and levels[-1][1] != ERROR, "the error must clear once consistent again"
    assert node.adapter.estimator.counters.divergences >= 1
    assert node.adapter.estimator.fault is None


def test_skid_steer_node_without_the_monitor_is_still_held_to_the_vehicle_limits(rclpy_context: Any) -> None:
    """The NIS monitor off, the gyro fault still drives the yaw rate past vehicle.max_yaw_rate: an ERROR, a restart."""
    outputs, levels, node = _node_run(rclpy_context, "skid_steer", 0, 8.0, SKID_FAULT)
    assert all(all_finite(m) for m in outputs)
    span = _error_span(levels)
    assert span is not None, "an estimate beyond the vehicle's limits must be an error"
    limit = float(node.values["vehicle.max_yaw_rate"])
    assert all(abs(m.twist.twist.angular.z) <= limit for m in outputs if hasattr(m, "twist")), "published beyond limit"
    assert node.adapter.estimator.counters.divergences >= 1


def test_rover_node_divergence_is_an_error_then_ok(rclpy_context: Any) -> None:
    _, _, healthy = _node_run(rclpy_context, "rover", WINDOW, 30.0, None)
    outputs, levels, node = _node_run(rclpy_context, "rover", WINDOW, 30.0, ROVER_FAULT)
    assert outputs and all(all_finite(m) for m in outputs)
    span = _error_span(levels)
    assert span is not None, "the fault must be detected"
    first, last, message = span
    assert "filter diverged (Estimator 1:" in message and "last good estimate" in message, message
    assert ROVER_FAULT[2] <= first < ROVER_FAULT[3] + 1.0
    assert levels[-1][1] != ERROR, "the error must clear once consistent again"
    est = node.adapter.estimator
    assert est.counters.divergences >= 1 and est.fault is None
    # Re-converged: the body pitch and the wheel loads are back on the healthy run's.
    good, got = healthy.adapter.estimator.last_estimate, est.last_estimate
    assert abs(got.body.pitch - good.body.pitch) < 0.01, (got.body.pitch, good.body.pitch)
    assert np.allclose(got.per_wheel("normal_load"), good.per_wheel("normal_load"), atol=3.0)


def test_rover_node_without_the_monitor_raises_no_error(rclpy_context: Any) -> None:
    outputs, levels, node = _node_run(rclpy_context, "rover", 0, 30.0, ROVER_FAULT)
    assert all(all_finite(m) for m in outputs)
    assert _error_span(levels) is None and node.adapter.estimator.counters.divergences == 0


# ---------------------------------------------------------------------------
# Rover adapter: an accelerometer fault that ruins Estimator 1 without the monitor
# ---------------------------------------------------------------------------

ROVER_IMU_FAULT = (("imu", "linear_acceleration.x", 6.0, 8.0), ("imu", "linear_acceleration.z", 6.0, 8.0))


@pytest.fixture(scope="module")
def rover_healthy() -> Any:
    adapter = _adapter("rover", 0)
    _feed(adapter, "rover", 30.0, lambda e: None)
    return adapter.estimator.last_estimate


def test_rover_accelerometer_fault_restarts_and_reconverges(rover_healthy: Any) -> None:
    adapter = _adapter("rover", WINDOW)
    errors: list[bool] = []
    outputs = _feed(adapter, "rover", 30.0, lambda e: None, ROVER_IMU_FAULT, errors)
    assert outputs and all(all_finite(m) for m in outputs)
    est = adapter.estimator
    assert est.counters.divergences >= 1 and any(errors), "the fault must be detected"
    assert not errors[-1] and est.fault is None, "the error must clear once consistent again"
    got = est.last_estimate
    assert abs(got.body.pitch - rover_healthy.body.pitch) < 0.01, (got.body.pitch, rover_healthy.body.pitch)
    assert np.allclose(got.per_wheel("normal_load"), rover_healthy.per_wheel("normal_load"), atol=3.0)


def test_rover_accelerometer_fault_without_the_monitor_loses_estimator_1(rover_healthy: Any) -> None:
    adapter = _adapter("rover", 0)
    errors: list[bool] = []
    outputs = _feed(adapter, "rover", 30.0, lambda e: None, ROVER_IMU_FAULT, errors)
    assert all(all_finite(m) for m in outputs) and not any(errors)
    assert abs(adapter.estimator.last_estimate.body.pitch) > 1.0  # measured: -1.8e4 rad


# ---------------------------------------------------------------------------
# Estimator cores: covariance blow-up, non-finite model output
# ---------------------------------------------------------------------------


Corruption = Callable[[str, Any, GaussianState], GaussianState]


class FaultyFilter:
    """Wraps an estimator's filter; ``corrupt(method, model, state)`` may replace a step's posterior."""

    def __init__(self, inner: Any, corrupt: Corruption) -> None:
        self.inner = inner
        self.corrupt = corrupt

    def initial_state(self, x0: Any, P0: Any) -> GaussianState:  # noqa: N803
        return self.inner.initial_state(x0, P0)

    def predict(self, state: Any, model: Any, u: Any, dt: float, **kw: Any) -> GaussianState:
        return self.inner.predict(state, model, u, dt, **kw)

    def update(self, prior: Any, z: Any, model: Any, u: Any, **kw: Any) -> tuple[GaussianState, Any]:
        post, info = self.inner.update(prior, z, model, u, **kw)
        return self.corrupt("update", model, post), info

    def step(self, state: Any, z: Any, model: Any, u: Any, dt: float, memory: Any = None) -> tuple[Any, Any]:
        post, res = self.inner.step(state, z, model, u, dt, memory)
        return self.corrupt("step", model, post), res


def _adapter(vehicle: str, window: int, **overrides: Any) -> Any:
    entry = VEHICLES[vehicle]
    values = dict(estimator_parameters(entry, None, overrides))
    values["filter.divergence_window"] = window
    return entry.make_adapter(values, entry.namespace)


def _feed(
    adapter: Any,
    vehicle: str,
    seconds: float,
    on_estimate: Callable[[Any], None],
    faults: tuple[Fault, ...] = (),
    errors: list[bool] | None = None,
) -> list[Any]:
    """Bag inputs up to ``seconds`` through the adapter (no input checks) with ``faults``.

    ``on_estimate`` sees each estimate as it is drained; ``errors`` gets
    whether the adapter's health holds an error after each output.
    """
    est = adapter.estimator
    inner = est.drain_estimates

    def drain() -> list[Any]:
        out = inner()
        for e in out:
            on_estimate(e)
        return out

    est.drain_estimates = drain
    keys = {f"{VEHICLES[vehicle].namespace}/{spec.topic}": spec.key for spec in adapter.inputs}
    outputs = []
    t0 = None
    for item in bag_items(vehicle, seconds):
        t0 = item.t if t0 is None else t0
        key = keys[item.topic]
        for fault in faults:
            if key == fault[0] and fault[2] <= item.t - t0 < fault[3]:
                _scale(item.msg, fault[1])
        out = [m for _, m in adapter.handle(key, item.msg)]
        outputs.extend(out)
        if errors is not None and out:
            errors.append(bool(adapter.health.errors))
    return outputs


def _blow_up(at: Callable[[], bool], which: Callable[[Any], bool]) -> Corruption:
    def corrupt(method: str, model: Any, post: GaussianState) -> GaussianState:
        if which(model) and at():
            return replace(post, P=np.asarray(post.P) * 1e12)
        return post

    return corrupt


def test_skid_steer_covariance_blow_up_restarts_from_the_last_good_estimate() -> None:
    adapter = _adapter("skid_steer", WINDOW)
    est = adapter.estimator
    seen: list[Any] = []
    good: list[Any] = []
    fault_step = 300  # 3 s in: converged, moving

    def record(e: Any) -> None:
        seen.append(e)
        if len(seen) == fault_step:  # the last good estimate before the faulty step
            good.append(est._monitor.last_good if est._monitor is not None else None)

    est.filter = FaultyFilter(est.filter, _blow_up(lambda: len(seen) == fault_step, lambda m: True))
    outputs = _feed(adapter, "skid_steer", 6.0, record)
    assert outputs and all(all_finite(m) for m in outputs)
    c = est.counters
    assert c.divergences == 1 and c.recoveries == 0, c
    hit = seen[fault_step]
    assert hit.initialised and not hit.accepted
    assert good[0] is not None
    np.testing.assert_allclose((hit.vx, hit.vy, hit.yaw_rate), good[0].x[:3])  # [vx, vy, r, scale states]
    np.testing.assert_allclose((hit.vx_variance, hit.vy_variance, hit.yaw_rate_variance), est.config.p0_diag)
    assert max(e.vx_variance for e in seen) <= 1.0  # the blown-up covariance never came out
    assert est.fault is None and not adapter.health.errors


def test_skid_steer_non_finite_model_output_is_a_divergence(monkeypatch: pytest.MonkeyPatch) -> None:
    adapter = _adapter("skid_steer", WINDOW)
    est = adapter.estimator
    # The model's Python f is broken below: run the Python step (the compiled one does not call it; its own
    # non-finite outputs hand the step back to the Python step, test_skid_steer_compiled.py).
    est.use_compiled = False
    seen: list[Any] = []
    f = type(est.model).f

    def broken_f(self: Any, x: Any, u: Any, dt: float) -> Any:
        out = np.asarray(f(self, x, u, dt), dtype=float)
        return out * np.nan if 300 <= len(seen) < 303 else out

    monkeypatch.setattr(type(est.model), "f", broken_f)
    faults: list[str | None] = []
    good: list[Any] = []

    def record(e: Any) -> None:
        seen.append(e)
        faults.append(est.fault)
        if len(seen) == 300:
            good.append(est._monitor.last_good if est._monitor is not None else None)

    outputs = _feed(adapter, "skid_steer", 6.0, record)
    assert outputs and all(all_finite(m) for m in outputs)
    assert est.counters.divergences == 3 and est.counters.recoveries == 0
    assert faults[300] is not None and "filter step failed" in faults[300]
    for k in (300, 301, 302):  # each failed step restarts from the same last good estimate
        assert seen[k].initialised
        np.testing.assert_allclose((seen[k].vx, seen[k].vy, seen[k].yaw_rate), good[0].x[:3])
    assert est.fault is None


def test_rover_wheel_force_blow_up_restarts_estimator_2_only() -> None:
    adapter = _adapter("rover", WINDOW)
    est = adapter.estimator
    seen: list[Any] = []
    faults: list[str | None] = []
    fault_step = 50  # 10 s in: both windows full and consistent
    good: list[Any] = []

    def at() -> bool:
        if est.counters.steps == fault_step and not good:
            mons = est._monitors
            good.append((mons[0].last_good, mons[1].last_good) if mons is not None else (None, None))
            return True
        return False

    est.filter = FaultyFilter(est.filter, _blow_up(at, lambda m: m is est.wheel_force_model))
    outputs = _feed(adapter, "rover", 20.0, lambda e: (seen.append(e), faults.append(est.fault)))
    assert outputs and all(all_finite(m) for m in outputs)
    assert est.counters.divergences == 1
    k = next(i for i, f in enumerate(faults) if f)
    assert faults[k].startswith("Estimator 2: covariance blow-up"), faults[k]
    hit = seen[k]
    assert hit.initialised and not hit.accepted
    good1, good2 = good[0]
    assert good2 is not None
    # Estimator 2 restarts from its last good estimate, 100 x its initial covariance; Estimator 1 goes on.
    x2 = np.array([[w.contact_angle, w.normal_load, w.drawbar_pull] for w in hit.wheels]).T.ravel()
    np.testing.assert_allclose(x2, good2.x)
    v2 = np.array([[w.contact_angle_variance, w.normal_load_variance, w.drawbar_pull_variance] for w in hit.wheels])
    # Published with the contact-angle error considered (issue 21): σ_b², DP² σ_b², W² σ_b² on top.
    p2 = 100.0 * np.diag(est._p2)
    considered = considered_variances(p2[0:3], x2[3:6], p2[3:6], x2[6:9], p2[6:9], est.config.contact_angle_bias)
    np.testing.assert_allclose(v2.T.ravel(), np.concatenate(considered))
    assert good1 is not None and est._monitors[0].divergences == 0  # Estimator 1 went on
    assert est.fault is None and not adapter.health.errors


def test_rover_failed_step_restarts_both_from_the_last_good_estimate(monkeypatch: pytest.MonkeyPatch) -> None:
    adapter = _adapter("rover", WINDOW)
    est = adapter.estimator
    seen: list[Any] = []
    faults: list[str | None] = []
    model = est.general_model
    f = type(model).f

    def broken_f(self: Any, x: Any, u: Any, dt: float) -> Any:
        out = np.asarray(f(self, x, u, dt), dtype=float)
        return out * np.nan if 50 <= est.counters.steps + est.counters.failed_steps < 52 else out

    monkeypatch.setattr(type(model), "f", broken_f)
    good: list[Any] = []

    def record(e: Any) -> None:
        seen.append(e)
        faults.append(est.fault)
        if est.counters.steps == 50 and not good:
            mons = est._monitors
            good.append((mons[0].last_good, mons[1].last_good) if mons is not None else (None, None))

    outputs = _feed(adapter, "rover", 20.0, record)
    assert outputs and all(all_finite(m) for m in outputs)
    c = est.counters
    assert c.divergences == 2 and c.failed_steps == 2 and c.initialisations == 1 and c.restarts == 0, c
    k = next(i for i, f in enumerate(faults) if f)
    assert faults[k].startswith("Estimator 1: filter step failed"), faults[k]
    good1, good2 = good[0]
    for hit in seen[k : k + 2]:  # both filters restart from their last good estimates
        assert hit.initialised and not hit.accepted
        np.testing.assert_allclose((hit.body.pitch, hit.body.forward_speed), good1.x[[6, 18]])
        np.testing.assert_allclose(hit.per_wheel("normal_load"), good2.x[3:6])
    assert est.fault is None and not adapter.health.errors


@pytest.mark.parametrize("vehicle", ["skid_steer", "rover"])
def test_the_monitor_changes_nothing_on_a_healthy_bag(vehicle: str) -> None:
    """Quiet on healthy data (the default settings, the low side of the band off): same estimates and counters."""
    runs = []
    for window in (0, WINDOW):
        adapter = _adapter(vehicle, window)
        seen: list[Any] = []
        _feed(adapter, vehicle, 10.0, seen.append)
        runs.append((seen, adapter.estimator.counters))
    (off, counters_off), (on, counters_on) = runs
    assert counters_on.divergences == 0 and counters_on == counters_off
    assert on == off


def test_rover_gate_lock_out_is_detected() -> None:
    """A gate far too tight (NIS 6 on 11 and 9 measurements) rejects every update from the start: a lock-out.

    The restart cannot cure a wrong gate, so the error stays; without the
    monitor the filters silently run on predictions only.
    """
    faults: list[str | None] = []
    adapter = _adapter("rover", WINDOW, **{"filter.gate_threshold": 6.0})
    est = adapter.estimator
    outputs = _feed(adapter, "rover", 10.0, lambda e: faults.append(est.fault))
    assert outputs and all(all_finite(m) for m in outputs)
    assert est.counters.divergences >= 1 and est.counters.gated_general > 0
    found = [f for f in faults if f]
    assert found and "consecutive measurements rejected by the gate" in found[0], found[:1]
    assert adapter.health.errors
