"""The rover's force-balance fault test, the repeat-pass floor and the exposed parameters (issue 21)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.estimators.rover import RoverEstimatorConfig, RoverTerrainEstimator
from terrain_estimation.estimators.rover_diagnostics import FaultCheck, ForceBalance, consistency_dof
from terrain_estimation.estimators.rover_noise import RepeatPassError
from terrain_estimation.models.rover import RoverParams

KAPVIK = RoverParams()
CELL_VAR = np.full(3, 0.03255**2 / 10.0)


def _cells(theta: float, q1: float, loads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cell forces (F_L, F_⊥) of world-vertical wheel forces ``loads`` seen in the carrier frames."""
    eps = np.array([theta + q1, theta + q1, theta])
    return loads * np.cos(eps), -loads * np.sin(eps)


def test_balance_of_consistent_cells_is_zero_and_an_offset_is_seen() -> None:
    bal = ForceBalance(KAPVIK.total_mass, KAPVIK.gravity)
    weight = KAPVIK.total_mass * KAPVIK.gravity
    loads = weight * np.array([0.3, 0.3, 0.4])
    state = np.array([0.05, -0.02, 0.0, 0.0])
    axial, perp = _cells(0.05, -0.02, loads)
    r, R = bal.residual(axial, perp, CELL_VAR, state, np.diag([1e-9, 1e-9, 1e-8, 1e-8]))
    np.testing.assert_allclose(r, 0.0, atol=1e-9)
    assert R.shape == (2, 2) and np.all(np.linalg.eigvalsh(R) > 0.0)
    # dH/dθ = ΣV = weight, dH/dq1 = V_rear + V_middle = 0.6 weight; the floor 1e-3 N; dH/dẍ0 = −M.
    expected = float(CELL_VAR.sum()) + 1e-6 + KAPVIK.total_mass**2 * 1e-8 + weight**2 * (1.0 + 0.6**2) * 1e-9
    assert R[0, 0] == pytest.approx(expected)
    # The first residual sets the bias; consistent ones then give a small NIS, a 0.3 N cell offset a large one.
    nis, bias, cov = bal.step(r, R)
    assert nis == 0.0
    bal.commit(bias, cov)
    nis, bias, cov = bal.step(r, R)
    assert nis < 1.0
    bal.commit(bias, cov)
    faulty, _ = bal.residual(axial + np.array([0.3, 0.0, 0.0]), perp, CELL_VAR, state, np.zeros((4, 4)))
    nis, _, _ = bal.step(faulty, R)
    assert nis > 100.0
    bal.reset()
    assert bal.step(faulty, R)[0] == 0.0  # a new start takes the first residual as its bias


def test_balance_bias_follows_a_constant_mass_error_without_a_lasting_alarm() -> None:
    """The side's mass configured 2 % off: the bias takes it, consistent residuals then give χ²₂ values."""
    bal = ForceBalance(1.02 * KAPVIK.total_mass, KAPVIK.gravity)
    rng = np.random.default_rng(5)
    loads = KAPVIK.total_mass * KAPVIK.gravity * np.array([0.3, 0.3, 0.4])
    values = []
    for _ in range(400):
        axial, perp = _cells(0.0, 0.0, loads)
        noise = rng.normal(0.0, math.sqrt(CELL_VAR[0]), (2, 3))
        r, R = bal.residual(axial + noise[0], perp + noise[1], CELL_VAR, np.zeros(4), np.zeros((4, 4)))
        nis, bias, cov = bal.step(r, R)
        bal.commit(bias, cov)
        values.append(nis)
    assert np.mean(values[50:]) == pytest.approx(2.0, rel=0.25)


def test_consistency_dof_counts_the_balance_with_two_axis_cells() -> None:
    assert consistency_dof(2) == 11
    assert consistency_dof(1) == 6


def _sensor_stream(
    est: RoverTerrainEstimator, seconds: float, offset_from: float, offset: float
) -> list[tuple[float, float]]:
    """A rover standing level on three loaded wheels; the rear axial cell gains ``offset`` from ``offset_from``."""
    rng = np.random.default_rng(11)
    p = KAPVIK
    loads = p.total_mass * p.gravity * np.array([0.3, 0.3, 0.4])
    out: list[tuple[float, float]] = []
    for k in range(int(seconds * 50)):
        t = k / 50.0
        est.add_imu(t, rng.normal(0.0, 1.245e-3), p.gravity + rng.normal(0.0, 1.245e-3), rng.normal(0.0, 0.01))
        wheels = 0.02 * t / p.wheel_radius + rng.normal(0.0, 4e-7, 3)
        est.add_joint_state(t, rng.normal(0.0, 1.6e-5), wheels.tolist(), [0.2, 0.2, 0.2])
        est.add_velocimeter(t, 0.02 + rng.normal(0.0, 1e-3))
        axial = loads + rng.normal(0.0, 0.03255, 3)
        if t >= offset_from:
            axial[0] += offset
        est.add_load_cells(t, axial.tolist(), rng.normal(0.0, 0.03255, 3).tolist())
        for e in est.drain_estimates():
            out.append((e.t, math.nan if e.initialised else e.consistency_nis))
            assert e.consistency_dof == 11
    return out


def test_a_load_cell_offset_raises_the_consistency_nis_within_a_step() -> None:
    """The W, DP walks would absorb the offset; the side's balance cannot (estimators.rover_diagnostics)."""
    cfg = RoverEstimatorConfig()
    clean = _sensor_stream(RoverTerrainEstimator(cfg), 8.0, math.inf, 0.0)
    faulty = _sensor_stream(RoverTerrainEstimator(cfg), 8.0, 5.0, 0.5)
    assert [t for t, _ in clean] == [t for t, _ in faulty]
    # The first window holding a faulty sample: (4.8, 5.0], stamped at its centre.
    k = next(i for i, (t, _) in enumerate(faulty) if t + 0.5 * cfg.step_s >= 5.0 - 1e-9)
    assert [v for _, v in clean[1:k]] == [v for _, v in faulty[1:k]]
    check = FaultCheck(consistency_dof(2), 10, 0.9999)
    warned = [check.add(v) for _, v in faulty[1:]]
    first = next(i + 1 for i, w in enumerate(warned) if w is not None)
    assert k <= first <= k + 2  # within 0.4 s of the offset
    # The next window holds 0.5 N on every sample (the first one, on its last sample only).
    assert faulty[k + 1][1] > 100.0 * max(1.0, clean[k + 1][1])
    check.reset()
    assert all(check.add(v) is None for _, v in clean[1:])


def test_repeat_pass_average_is_floored_only_where_it_is_given_out() -> None:
    rp = RepeatPassError(memory=2.0)  # b = 0.5
    spacing = np.array([0.35, 0.35])
    zero = np.zeros(3)
    var = np.full(3, 1e-4)
    # Lead estimates at 0.00 ... 0.70 m, then a trailing pass with differences smaller than the variances.
    for k in range(71):
        rp.update(0.01 * k, zero, var, spacing)
    assert rp.variance == 0.0
    average = rp._average
    assert average < 0.0  # unfloored: each sample is ½(0 − 2e-4) = −1e-4
    d = 0.05
    rp.update(0.72, np.array([d, d, 0.0]), var, spacing)
    expected = 0.5 * average + 0.5 * (0.5 * (d * d - 2e-4))
    assert rp.variance == pytest.approx(max(expected, 0.0))


def test_repeat_pass_parameters_reach_the_estimator() -> None:
    from terrain_estimation.ros.rover_params import PARAMETERS, estimator_config

    values = {s.name: s.default for s in PARAMETERS}
    cfg = estimator_config(values)
    bias = cfg.contact_angle_bias
    assert bias.enabled and not bias.path_error and bias.sigma == 0.01
    assert bias.from_repeat_pass is True
    assert bias.memory_steps == 5.0
    assert bias.sinkage_relative_error == 0.0
    cfg = estimator_config(
        {
            **values,
            "filter.contact_angle_bias_from_repeat_pass": False,
            "filter.contact_angle_bias_memory": 25.0,
            "filter.contact_angle_path_error": True,
            "filter.contact_angle_sinkage_error": 0.5,
        }
    )
    assert cfg.contact_angle_bias.from_repeat_pass is False
    assert cfg.contact_angle_bias.memory_steps == 25.0
    assert cfg.contact_angle_bias.path_error is True
    assert cfg.contact_angle_bias.sinkage_relative_error == 0.5
    off = estimator_config(
        {
            **values,
            "filter.contact_angle_bias": 0.0,
            "filter.contact_angle_path_error": False,
            "filter.contact_angle_sinkage_error": 0.0,
        }
    )
    assert off.contact_angle_bias.enabled is False
