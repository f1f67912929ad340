"""The rover's error terms of issue 21, H2: wheel damping, τ_R's within-window swing, Estimator 3's split.

* Eq. 48–49 with the damping at the new rate: the window's torque balance
  ``I_wg Δq̇ / T = τ_W − τ_R − b_d q̇_new`` holds exactly (the explicit step put
  ≈ 0.46 q̈ N·m into τ_R, models/rover_general_model.py, "Wheel damping").
* The applied torque of the sample nearest the window's centre (the stamp)
  reaches the step (``WindowMeans.wheel_torque_at_stamp``).
* Estimator 3's split of F_⊥12: the error is ± one value on the bogie wheels,
  the sum untouched, sized by the slips' difference; the published W and DP
  take it rotated by δ.
"""

from __future__ import annotations

import numpy as np
import pytest

from terrain_estimation.estimators.rover import RoverEstimatorConfig
from terrain_estimation.estimators.rover_noise import nearest_covariance, split_considered, split_covariance
from terrain_estimation.estimators.rover_outputs import RoverCounters
from terrain_estimation.estimators.rover_windows import SensorWindows, WindowMeans
from terrain_estimation.models.rover import RoverParams
from terrain_estimation.models.rover_estimators import GeneralEstimatorModel, GeneralIndex, GeneralInput


def test_wheel_rate_step_takes_the_damping_at_the_new_rate() -> None:
    p = RoverParams()
    model = GeneralEstimatorModel(p)
    x = np.zeros(22)
    x[GeneralIndex.WHEEL_RATE] = [0.25, 0.26, 0.27]
    x[GeneralIndex.RESISTIVE_TORQUE] = [0.4, 0.3, 0.35]
    torque = np.array([1.2, 0.95, 1.0])
    dt = 0.2
    out = model.f(x, GeneralInput(torque), dt)
    old, new = x[GeneralIndex.WHEEL_RATE], out[GeneralIndex.WHEEL_RATE]
    balance = p.wheel_gear_inertia * (new - old) / dt + p.wheel_damping * new + x[GeneralIndex.RESISTIVE_TORQUE]
    np.testing.assert_allclose(balance, torque, rtol=0, atol=1e-12)
    # In equilibrium (τ_W = τ_R + b_d q̇) the rate stays.
    x[GeneralIndex.RESISTIVE_TORQUE] = torque - p.wheel_damping * old
    still = model.f(x, GeneralInput(torque), dt)
    np.testing.assert_allclose(still[GeneralIndex.WHEEL_RATE], old, rtol=0, atol=1e-15)


class _Windows(SensorWindows):
    def __init__(self) -> None:
        self.config = RoverEstimatorConfig()
        self._c = dict.fromkeys(RoverCounters.__dataclass_fields__, 0)
        self.steps: list[tuple[float, WindowMeans]] = []
        self._reset_windows()

    def _step(self, t: float, m: WindowMeans) -> None:
        self.steps.append((t, m))


def test_window_keeps_the_torque_at_its_stamp() -> None:
    w = _Windows()
    for k in range(31):
        t = 0.02 * k
        torque = [t, 2.0 * t, -t]
        w.add_imu(t, 0.0, 9.81, 0.0)
        w.add_joint_state(t, 0.0, [0.01 * t] * 3, torque)
        w.add_velocimeter(t, 0.02)
        w.add_load_cells(t, [30.0] * 3, [0.0] * 3)
    w.flush()
    assert len(w.steps) >= 2
    for stamp, m in w.steps[1:]:
        np.testing.assert_allclose(m.wheel_torque_at_stamp, [stamp, 2.0 * stamp, -stamp], atol=1e-12)
        # A linear torque: its mean over the window (stamps end − 0.18 … end) is 0.01 s past the centre.
        np.testing.assert_allclose(m.wheel_torque - m.wheel_torque_at_stamp, [0.01, 0.02, -0.01], atol=1e-12)


def test_split_error_is_opposite_on_the_bogie_wheels_and_sized_by_the_slips() -> None:
    axial = np.array([60.0, 45.0, 41.0])
    slip = np.array([0.23, 0.20, 0.21])
    cov = split_covariance(axial, slip, np.zeros(3), 0.55)
    lever = 60.0 * 45.0 / 105.0
    expected = (lever * 0.55 * 0.03) ** 2
    assert cov[0, 0] == pytest.approx(expected) and cov[1, 1] == pytest.approx(expected)
    assert cov[0, 1] == pytest.approx(-expected)
    total = np.array([1.0, 1.0, 0.0])
    assert total @ cov @ total == pytest.approx(0.0, abs=1e-15)  # F_⊥12 itself is not touched
    assert np.all(cov[2] == 0.0) and np.all(cov[:, 2] == 0.0)  # nor the front wheel
    # The slip estimates' own variances are taken out (an unbiased square), floored at 0.
    less = split_covariance(axial, slip, np.array([2e-4, 2e-4, 0.0]), 0.55)
    assert less[0, 0] == pytest.approx(lever**2 * 0.55**2 * (0.03**2 - 4e-4))
    assert np.all(split_covariance(axial, slip, np.full(3, 1.0), 0.55) == 0.0)
    assert np.all(split_covariance(axial, slip, np.zeros(3), 0.0) == 0.0)
    assert np.all(split_covariance(np.array([-1.0, 45.0, 41.0]), slip, np.zeros(3), 0.55) == 0.0)


def test_split_error_reaches_w_and_dp_rotated_by_delta() -> None:
    load_var, pull_var = np.full(3, 1e-3), np.full(3, 2e-3)
    split = np.array([0.1, 0.1, 0.0])
    delta = np.array([0.0, 0.2, 0.3])
    w, d = split_considered(load_var, pull_var, delta, split)
    np.testing.assert_allclose(w, 1e-3 + np.sin(delta) ** 2 * split)
    np.testing.assert_allclose(d, 2e-3 + np.cos(delta) ** 2 * split)
    assert w[0] == 1e-3 and d[0] == pytest.approx(2e-3 + 0.1)


def test_nearest_covariance_clips_negative_directions_only() -> None:
    a = np.array([[2.0, 0.5], [0.5, 1.0]])
    np.testing.assert_allclose(nearest_covariance(a), a, atol=1e-12)
    b = np.array([[1.0, 0.0], [0.0, -1e-3]])
    out = nearest_covariance(b)
    np.testing.assert_allclose(out, [[1.0, 0.0], [0.0, 0.0]], atol=1e-15)
    assert np.all(np.linalg.eigvalsh(nearest_covariance(np.array([[1.0, 2.0], [2.0, 1.0]]))) >= -1e-12)
