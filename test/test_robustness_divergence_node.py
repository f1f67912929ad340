"""The soil-stiffness node's divergence monitor (issue 7 item 2, wired into the node's adapter).

A burst of accelerometer readings a hundred times too large (a loose sensor)
drives the filter off; with ``filter.divergence_window`` set the adapter's
health shows an ERROR naming the divergence while the filter re-converges from
the last good estimate, clears it afterwards, and every estimate stays finite.
Without the monitor (window 0) no error is ever raised.
"""

from __future__ import annotations

import math
from pathlib import Path

from terrain_estimation.bag import read_bag
from terrain_estimation.vehicles import VEHICLES, estimator_parameters

BAG = Path(__file__).resolve().parents[1] / "bags" / "quarter_car_graneville_iso_d_10ms"


def _run(window: int) -> tuple[list[float], list[bool], int]:
    entry = VEHICLES["quarter_car"]
    values = dict(estimator_parameters(entry, None))
    values["filter.divergence_window"] = window
    adapter = entry.make_adapter(values, entry.namespace)
    keys = {f"{entry.namespace}/{spec.topic}": spec.key for spec in adapter.inputs}
    k_s, errors = [], []
    t0 = None
    for item in read_bag(BAG, list(keys)):
        msg = item.msg
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        t0 = t if t0 is None else t0
        if keys[item.topic] in ("imu_body", "imu_wheel") and 2.0 <= t - t0 < 2.5:
            msg.linear_acceleration.z *= 100.0  # the fault
        for _key, out in adapter.handle(keys[item.topic], msg):
            k_s.append(float(out.k_s))
            errors.append(bool(adapter.health.errors))
    return k_s, errors, adapter.estimator.counters.divergences


def test_divergence_gives_error_then_ok_and_finite_estimates() -> None:
    k_s, errors, divergences = _run(20)
    assert k_s and all(math.isfinite(v) for v in k_s)
    assert divergences >= 1 and any(errors), "the fault must be detected"
    assert not errors[-1], "the error must clear once the filter is consistent again"
    before = k_s[150]  # 1.5 s in: converged, before the fault
    assert abs(k_s[-1] / before - 1.0) < 0.05, (before, k_s[-1])


def test_without_the_monitor_no_error_is_raised_and_the_estimate_is_lost() -> None:
    k_s, errors, divergences = _run(0)
    assert divergences == 0 and not any(errors)
    assert k_s[-1] < 0.1 * k_s[150]  # the fault ruins k_s (measured: 661 -> 1.75 kN/m)
