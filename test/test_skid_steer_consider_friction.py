"""Issue 20: what an unestimated friction does to the skid-steer estimate (the friction as a consider parameter,
estimators/skid_steer_consider.py "Friction").

The brush force's sensitivity to mu is ~0 while the tire patch sticks and 1 when it slides. A straight run keeps
the observer's tires at low utilisation, so a friction term leaves its variances alone; a skid-steer vehicle turns
by sliding the tires of one side, so in a turn the lateral velocity depends on mu, and the first-order
sensitivity the consider recursion carries is what the filter does when its mu is wrong."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from terrain_analysis.tools.skid_compare import run_filter_on
from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from terrain_estimation.estimators.skid_steer_consider import ConsiderConfig
from terrain_estimation.models.skid_steer import brush_tire_forces
from terrain_estimation.ros.skid_steer_params import estimator_config
from terrain_estimation.vehicles import VEHICLES, estimator_parameters

DEFAULT = SkidSteerEstimatorConfig()
WITH_FRICTION = ("friction", *DEFAULT.consider.parameters)


def _with_friction(std: float, config: SkidSteerEstimatorConfig = DEFAULT) -> SkidSteerEstimatorConfig:
    return replace(config, consider=replace(config.consider, parameters=WITH_FRICTION, friction_std=std))


def _truth_run(name: str, duration: float):
    from vehicle_sim.plants.skid_steer import simulate_skid_steer
    from vehicle_sim.plants.skid_steer_scenarios import reproduction_scenarios

    return simulate_skid_steer(replace(reproduction_scenarios()[name], duration=duration), 1000)


@pytest.mark.parametrize("t", [0.01, 0.05, 0.2, 0.5, 0.8, 0.95])
def test_the_brush_force_depends_on_the_friction_by_the_sliding_fraction(t):
    """At a fixed slip, d ln F / d ln mu = t (3 - 2t) / (3 - 3t + t^2), t the sliding fraction of the patch:
    ~t at low utilisation (a sticking patch hardly feels mu), 1 once the whole patch slides (F = mu F_z)."""
    fz, mu, c = 5000.0, 0.8, 40000.0
    sigma = t * 3.0 * mu * fz / c  # pure lateral slip with gamma = t 3 mu F_z
    h = 1e-6
    f_lo = brush_tire_forces(0.0, sigma, fz, longitudinal_stiffness=c, cornering_stiffness=c, friction=mu)[1]
    f_hi = brush_tire_forces(0.0, sigma, fz, longitudinal_stiffness=c, cornering_stiffness=c, friction=mu * np.exp(h))[
        1
    ]
    sensitivity = (np.log(f_hi) - np.log(f_lo)) / h
    assert sensitivity == pytest.approx(t * (3 - 2 * t) / (3 - 3 * t + t * t), rel=1e-4)
    sliding = brush_tire_forces(0.0, 2 * sigma / t, fz, longitudinal_stiffness=c, cornering_stiffness=c, friction=mu)
    assert sliding[1] == pytest.approx(mu * fz)  # beyond t = 1 the force is mu F_z: sensitivity 1


def test_friction_terms_leave_a_straight_run_alone_and_widen_a_skid_steer_turn():
    """Straight acceleration: the observer's tires at t ~ 0.01, the friction's share of the v_y variance
    nil. The 7 m turn at 5 km/h: the inner side slides (t = 1), the friction's term widens v_y."""
    config = _with_friction(0.3)
    widening = {}
    for name, duration, start in (("straight_acceleration", 12.0, 2.0), ("nominal", 14.0, 10.0)):
        sim = _truth_run(name, duration)
        off, on = run_filter_on(sim, DEFAULT), run_filter_on(sim, config)
        np.testing.assert_array_equal(on.state, off.state)  # a consider term leaves the estimate as it is
        late = on.t >= start
        widening[name] = float(np.median(on.covariance[late, 1, 1] / off.covariance[late, 1, 1]))
    assert widening["straight_acceleration"] < 1.01
    assert widening["nominal"] > 1.1


def test_the_friction_sensitivity_is_the_filters_response_to_a_wrong_friction():
    """First order holds where the friction matters most: in the sharp turn (3 m/s, 0.6 rad/s) a filter whose
    mu is 10 % off moves its v_y by what the consider sensitivity (friction_std 0.1) says, about 5x the
    filter's own sigma (measured on 45 s: 0.045 and 0.035 m/s RMS for mu x 0.9, x 1.1 against 0.040)."""
    sim = _truth_run("sharp_turn", 14.0)
    base = run_filter_on(sim, DEFAULT)
    considered = run_filter_on(sim, _with_friction(0.1))
    late = base.t >= 10.0
    predicted = np.sqrt(np.mean(considered.covariance[late, 1, 1] - base.covariance[late, 1, 1]))
    own = np.sqrt(np.mean(base.covariance[late, 1, 1]))
    assert predicted > 3.0 * own
    for factor in (np.exp(-0.1), np.exp(0.1)):
        vehicle = replace(DEFAULT.vehicle, friction=DEFAULT.vehicle.friction * factor)
        moved = run_filter_on(sim, replace(DEFAULT, vehicle=vehicle))
        actual = np.sqrt(np.mean((moved.state[late, 1] - base.state[late, 1]) ** 2))
        assert 0.7 < actual / predicted < 1.4


def test_the_friction_has_its_own_size():
    config = ConsiderConfig(parameters=WITH_FRICTION, scale_std=0.15, friction_std=0.3, resistance_rms=0.02)
    assert config.variance("friction") == pytest.approx(0.09)
    assert config.variance("longitudinal_stiffness") == pytest.approx(0.0225)
    assert config.variance("motion_resistance") == pytest.approx(4e-4)
    est = SkidSteerEstimator(replace(DEFAULT, consider=config))
    assert est._consider is not None
    assert np.diag(est._consider._C).tolist() == pytest.approx([0.09, 0.0225, 4e-4])
    with pytest.raises(ValueError, match="friction_std"):
        ConsiderConfig(friction_std=-0.1)
    values = dict(estimator_parameters(VEHICLES["skid_steer"], None))
    assert estimator_config(values).consider == DEFAULT.consider
    values.update({"consider.friction": True, "consider.friction_std": 0.2})
    c = estimator_config(values).consider
    assert "friction" in c.parameters and c.friction_std == 0.2 and c.scale_std == DEFAULT.consider.scale_std
