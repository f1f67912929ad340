"""The demo's rover summary (``terrain_analysis.tools.demo_kinds.ROVER``) on synthetic messages: no ROS graph.

Ground truth at 50 Hz and estimates at 5 Hz with known errors (large before
the settle time, constant after), two terrain models whose last one is off
the true DP(W, i) by a constant inside a validity region that holds part of
the truth: the rms errors, the model's error and coverage, the counts, the
table and the plot follow.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Time

from terrain_analysis.tools import demo, demo_kinds, demo_record
from terrain_msgs.msg import TerrainResponseModel, WheelTerrain, WheelTerrainArray

DURATION = 10.0
WHEELS = ("rear", "middle", "front")
#: Estimate − truth after the settle time, per wheel (rear, middle, front).
OFFSETS = {
    "slip": np.array([0.01, 0.01, 0.01]),
    "normal_load": np.array([0.1, -0.2, 0.3]),
    "drawbar_pull": np.array([-0.5, 0.5, -0.5]),
    "resistive_torque": np.array([0.001, 0.002, 0.003]),
}
VARIANCE = 0.04
#: The true DP(W, i) = 1 + 20 i + 0.05 W, coefficients [1, i, W, i², i·W, W²].
DP_TRUE = (1.0, 20.0, 0.05, 0.0, 0.0, 0.0)
MODEL_OFFSET = 0.3


def _stamp(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _truth_values(t: float) -> dict[str, np.ndarray]:
    j = np.arange(3)
    slip = 0.05 + 0.01 * j + 0.02 * math.sin(t)
    load = 50.0 + 5.0 * j + t
    return {
        "slip": slip,
        "normal_load": load,
        "drawbar_pull": DP_TRUE[0] + DP_TRUE[1] * slip + DP_TRUE[2] * load,
        "resistive_torque": 0.1 + 0.01 * j + 0.001 * t,
        "contact_angle": 0.01 * j,
    }


def _array(ns: int, values: dict[str, np.ndarray], variance: float, order: tuple[str, ...]) -> WheelTerrainArray:
    msg = WheelTerrainArray()
    msg.header.stamp = _stamp(ns)
    for name in order:
        k = WHEELS.index(name)
        wheel = WheelTerrain(wheel=name)
        for quantity, v in values.items():
            setattr(wheel, quantity, float(v[k]))
            setattr(wheel, f"{quantity}_variance", variance)
        msg.wheels.append(wheel)
    return msg


def _model(ns: int, offset: float, slip_max: float) -> TerrainResponseModel:
    msg = TerrainResponseModel(order=2, slip_min=0.0, slip_max=slip_max, load_min=0.0, load_max=1e3, samples=12)
    msg.header.stamp = _stamp(ns)
    msg.dp_coefficients = [DP_TRUE[0] + offset, *DP_TRUE[1:]]
    msg.tau_coefficients = [0.0] * 6
    msg.dp_prediction_rms = 0.25 + offset  # the error the model states (issue 21)
    return msg


def _run(models: list[Any]) -> demo_record.DemoRun:
    scenario = next(s for s in demo.SCENARIOS if s.vehicle == "rover")
    assert scenario.kind is demo_kinds.ROVER
    scenario = dataclasses.replace(scenario, duration=DURATION)
    # the truth lists its wheels front first: the summary goes by name
    truth = [
        _array(k * 20_000_000, _truth_values(k * 0.02), 0.0, WHEELS[::-1]) for k in range(1, round(DURATION * 50) + 1)
    ]
    estimates = []
    for n in range(1, round(DURATION * 5)):  # 0.2 .. 9.8 s
        t = n * 0.2
        error = 1.0 if t < demo_kinds.ROVER_SETTLE else 0.0  # excluded from the rms
        values = {q: v + error + OFFSETS.get(q, 0.0) for q, v in _truth_values(t).items()}
        estimates.append(_array(n * 200_000_000, values, VARIANCE, WHEELS))
    return demo_record.DemoRun(
        scenario=scenario,
        estimates=estimates,
        truth=truth,
        diagnostic_level="OK",
        diagnostic_message="Estimator 1+2: fine",
        diagnostic_values={"nis_mean": "19.5", "nis_window": "48"},
        wall_time=3.25,
        other_estimates={demo_kinds.ROVER_MODEL_TOPIC: models},
    )


def test_rover_summary_against_known_errors(tmp_path):
    slip_max = 0.08  # holds part of the truth's slip range 0.03 .. 0.09
    models = [_model(9_000_000_000, 5.0, 1.0), _model(9_500_000_000, MODEL_OFFSET, slip_max)]
    r = demo_kinds.ROVER.summarise(_run(models))

    assert r.times.size == r.expected_estimates == 49
    assert r.sim_time == pytest.approx(9.8)
    for quantity, offset in OFFSETS.items():
        np.testing.assert_allclose(r.rms_error(quantity), np.abs(offset), atol=1e-9, err_msg=quantity)
    np.testing.assert_allclose(r.std["normal_load"], math.sqrt(VARIANCE))
    assert r.truth_series["normal_load"].shape == (500, 3)

    np.testing.assert_allclose(r.model_times, [9.0, 9.5])
    assert r.model_dp_rms == pytest.approx(MODEL_OFFSET)  # the last model, not the first
    assert r.model_dp_stated == pytest.approx(0.25 + MODEL_OFFSET)
    truth_slip = r.truth_series["slip"].ravel()
    assert r.model_coverage == pytest.approx(np.mean(truth_slip <= slip_max))
    assert 0.0 < r.model_coverage < 1.0
    assert (r.nis_mean, r.nis_window) == (19.5, 48)

    table = demo_kinds.ROVER.table([r])
    row = table.splitlines()[2]
    for cell in ("49/49", "0.0100", "0.200", "0.500", "0.00200", "2 (9.0)", "0.30 (0.55;", "19.50 (last 48)", "OK: "):
        assert cell in row, (cell, row)

    path = demo_kinds.ROVER.plot(r, tmp_path)
    assert path.name == "rover_wheel_terrain.png" and path.stat().st_size > 0


def test_rover_summary_without_a_terrain_model():
    r = demo_kinds.ROVER.summarise(_run([]))
    assert r.model_times.size == 0 and math.isnan(r.model_dp_rms)
    row = demo_kinds.ROVER.table([r]).splitlines()[2]
    assert "| 0 " in row and "n/a" in row
