"""Issue 20 item 3: tire-model error the filter can absorb. Tire-parameter scale states (brush and kinematic
process) converge to the true cornering-stiffness scale and remove the lateral-velocity bias that no Q/R
setting removes; the IMU-driven kinematic model with the tire forces as pseudo-measurements."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.models.skid_steer_kinematic import KinematicInput, SkidSteerKinematicModel
from terrain_estimation.models.skid_steer_observer import SkidSteerInput, SkidSteerObserverModel
from terrain_estimation.models.skid_steer_scales import (
    SkidSteerTireScaleModel,
    TireScaleConfig,
    scaled_force_sums,
)

P = SkidSteerParams()
DT = 0.01


def _turn(factor: float, seconds: float = 15.0, seed: int = 2):
    """A 2 m/s left turn of the observer's model whose true C_α is ``factor`` × nominal (finer Euler)."""
    rng = np.random.default_rng(seed)
    truth = SkidSteerObserverModel(replace(P, cornering_stiffness=P.cornering_stiffness * factor), max_euler_gain=0.1)
    x = np.array([2.0, 0.0, 0.0])
    a = (0.0, 0.0)
    rows = []
    for k in range(1, round(seconds / DT) + 1):
        t = k * DT
        dv = 0.4 * min(1.0, max(0.0, t - 1.0))
        wl, wr = (2.0 - dv) / P.wheel_radius, (2.0 + dv) / P.wheel_radius
        u = SkidSteerInput(wl, wr, *a)
        x = truth.f(x, u, DT)
        z = truth.h(x, u)
        a = (float(z[0]), float(z[1]))
        rows.append((t, wl, wr, z + rng.normal(scale=[0.05, 0.05, 0.002]), x.copy()))
    return rows


def _estimate(rows, model: str):
    est = SkidSteerEstimator(SkidSteerEstimatorConfig(model=model))  # type: ignore[arg-type]
    errors = []
    for t, wl, wr, z, x in rows:
        est.add_joint_state(t - DT, wl * P.transmission_ratio, wr * P.transmission_ratio)
        e = est.add_imu(t, *z)
        assert e is not None
        if t > 8.0:
            errors.append(e.vy - x[1])
    return est, math.sqrt(float(np.mean(np.square(errors))))


@pytest.mark.parametrize("factor", [1.3, 0.7])
def test_scale_states_converge_to_the_true_cornering_stiffness_scale(factor):
    rows = _turn(factor)
    _, plain = _estimate(rows, "brush")
    for model in ("brush_scales", "kinematic_scales"):
        est, rms = _estimate(rows, model)
        scale = est.tire_scales["cornering_stiffness"]
        assert scale == pytest.approx(factor, rel=0.05), (model, scale)
        assert est.last_estimate is not None and est.last_estimate.tire_scales == (pytest.approx(scale),)
        assert rms < 0.5 * plain, (model, rms, plain)
        assert est.counters.recoveries == 0 and est.counters.divergences == 0


def test_nominal_tires_keep_the_scale_at_one_and_the_kinematic_model_tracks():
    rows = _turn(1.0, seconds=10.0)
    est, rms = _estimate(rows, "kinematic_scales")
    assert est.tire_scales["cornering_stiffness"] == pytest.approx(1.0, abs=0.03)
    _, kin = _estimate(rows, "kinematic")
    assert rms < 0.005 and kin < 0.005


def test_scaled_forces_are_the_brush_forces_of_the_scaled_parameters():
    base = SkidSteerObserverModel(P)
    u = SkidSteerInput(5.0, 6.0, 0.3, 0.8, 0.6)
    rng = np.random.default_rng(0)
    c = rng.normal([1.9, 0.0, 0.2], [0.2, 0.1, 0.1], size=(5, 3)).T.copy()
    terms = base._terms(u)
    np.testing.assert_array_equal(scaled_force_sums(base, c, terms, None), base._force_sums(c, terms))
    np.testing.assert_allclose(scaled_force_sums(base, c, terms, np.ones((3, 5))), base._force_sums(c, terms))
    mult = np.array([[0.5] * 5, [1.3] * 5, [0.8] * 5])  # μ, C_α, C_x
    cx, ca = 0.8 * P.longitudinal_stiffness, 1.3 * P.cornering_stiffness
    other = SkidSteerObserverModel(replace(P, cornering_stiffness=ca, longitudinal_stiffness=cx))
    expected = other._force_sums(c, other._terms(SkidSteerInput(5.0, 6.0, 0.3, 0.8, 0.3)))
    np.testing.assert_allclose(scaled_force_sums(base, c, terms, mult), expected, rtol=1e-12, atol=1e-9)


def test_scale_model_layout_bounds_and_noise():
    model = SkidSteerTireScaleModel(P, TireScaleConfig(states=("cornering_stiffness", "friction"), walk_std=0.1))
    assert model.scales.states == ("friction", "cornering_stiffness")  # stored in SCALE_NAMES order
    assert model.state_dim == 5 and model.measurement_dim == 3
    u = SkidSteerInput(5.0, 5.0)
    x = np.array([[1.9, 0.0, 0.0, 5.0, -5.0], [1.9, 0.0, 0.0, 0.0, 0.0]])
    out = model.f(x, u, 0.01)
    assert out.shape == (2, 5)
    np.testing.assert_allclose(out[0, 3:], [math.log(4.0), math.log(0.25)])  # clipped to the bounds
    assert model.scale_values(x[0]) == pytest.approx((4.0, 0.25))
    L = model.process_noise_sqrt(x[1], u, 0.04)
    np.testing.assert_allclose(np.diag(L)[3:], [0.1 * 0.2] * 2)
    assert model.h(x, u).shape == (2, 3) and model.tire_sideslip(x[1]).shape == (6,)
    for kwargs, name in [
        ({"states": ("mu",)}, "states"),
        ({"walk_std": -1.0}, "walk_std"),
        ({"min_scale": 1.5}, "min_scale"),
    ]:
        with pytest.raises(ValueError, match=name):
            TireScaleConfig(**kwargs)  # type: ignore[arg-type]


def test_kinematic_process_is_the_imu_driven_rigid_body():
    model = SkidSteerKinematicModel(P)
    u = KinematicInput(SkidSteerInput(5.0, 5.0), 0.0, 0.0, 0.0)
    x = np.array([2.0, 0.3, 0.5])
    out = model.f(x, u, 0.1)
    assert math.hypot(out[0], out[1]) == pytest.approx(math.hypot(2.0, 0.3), rel=1e-14)  # a rotation
    assert out[2] == 0.5
    # v̇x = a_x + r v_y, v̇y = a_y − r v_x (small step).
    u = KinematicInput(SkidSteerInput(5.0, 5.0), 0.4, -0.2, 0.0)
    small = model.f(x, u, 1e-4)
    np.testing.assert_allclose((small[:2] - x[:2]) / 1e-4, [0.4 + 0.5 * 0.3, -0.2 - 0.5 * 2.0], rtol=1e-4)
    fx, fy, mz = model.base.forces(x, u.wheels)
    z = model.h(np.vstack([x, x]), u)
    assert z.shape == (2, 3) and model.measurement_noise_sqrt().shape == (3, 3)
    np.testing.assert_allclose(z[0], [fx / P.mass, fy / P.mass, 0.5], rtol=1e-12)
    # With scale states the yaw-moment pseudo-measurement M_z/I_z − ṙ_gyro joins (what makes them observable).
    scaled = SkidSteerKinematicModel(P, TireScaleConfig())
    u = KinematicInput(SkidSteerInput(5.0, 5.0), 0.4, -0.2, 0.7)
    z = scaled.h(np.append(x, 0.0), u)
    np.testing.assert_allclose(z, [fx / P.mass, fy / P.mass, 0.5, mz / P.yaw_inertia - 0.7], rtol=1e-12)
    assert scaled.measurement_noise_sqrt().shape == (4, 4)
    with pytest.raises(ValueError, match="KinematicInput"):
        model.f(x, SkidSteerInput(5.0, 5.0), 0.01)
    with pytest.raises(ValueError, match="tire_model_std"):
        SkidSteerKinematicModel(P, tire_model_std=-1.0)


def test_a_restart_keeps_the_learned_scales():
    rows = _turn(1.3, seconds=12.0)
    est = SkidSteerEstimator(SkidSteerEstimatorConfig(model="kinematic_scales", max_step_s=0.1))
    for t, wl, wr, z, _ in rows[:1000]:
        est.add_joint_state(t - DT, wl * P.transmission_ratio, wr * P.transmission_ratio)
        est.add_imu(t, *z)
    learned = est.tire_scales["cornering_stiffness"]
    for t, wl, wr, z, _ in rows[1050:]:  # a 0.5 s gap: restart
        est.add_joint_state(t - DT, wl * P.transmission_ratio, wr * P.transmission_ratio)
        e = est.add_imu(t, *z)
        if e is not None and e.initialised:
            assert e.tire_scales == (pytest.approx(learned),)
    assert est.counters.restarts == 1 and abs(learned - 1.3) < 0.1
