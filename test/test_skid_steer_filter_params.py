"""The node's filter parameters reach the filter (filter.type adaptive*, strong_tracking.*, adaptive_noise.*)."""

from __future__ import annotations

import numpy as np
import pytest

from terrain_estimation.estimators.skid_steer import SkidSteerEstimator
from terrain_estimation.ros.skid_steer_params import estimator_config
from terrain_estimation.vehicles import VEHICLES, estimator_parameters


def _values(**changes: object) -> dict[str, object]:
    values = dict(estimator_parameters(VEHICLES["skid_steer"], None))
    values.update(changes)
    return values


def test_adaptive_filter_and_its_settings_from_parameters() -> None:
    config = estimator_config(
        _values(
            **{
                "filter.type": "adaptive",
                "strong_tracking.criterion": "whitened",
                "strong_tracking.probability": 0.95,
                "adaptive_noise.adapt_q": False,
                "adaptive_noise.r_forgetting": 0.9,
                "adaptive_noise.r_ceiling": 30.0,
            }
        )
    )
    filt = config.make_filter()
    assert filt.variant == "adaptive"
    assert filt.strong_tracking.criterion == "whitened" and filt.strong_tracking.probability == 0.95
    assert filt.noise.adapt_q is False and filt.noise.r_forgetting == 0.9 and filt.noise.r_ceiling == 30.0
    assert estimator_config(_values()).strong_tracking.criterion is None  # auto: the filter's own choice


def test_adaptive_filter_runs_in_the_estimator() -> None:
    """A 2 s straight run at 2 m/s: finite estimates; the adaptive noise scale is reported."""
    config = estimator_config(_values(**{"filter.type": "adaptive"}))
    est = SkidSteerEstimator(config)
    omega = 2.0 / config.vehicle.wheel_radius * config.vehicle.transmission_ratio
    rng = np.random.default_rng(0)
    out = []
    for k in range(200):
        t = 0.01 * (k + 1)
        est.add_joint_state(t, omega, omega)
        out.append(est.add_imu(t, 0.05 * rng.standard_normal(), 0.05 * rng.standard_normal(), 0.0))
    estimates = [e for e in out if e is not None]
    assert len(estimates) > 150
    assert all(np.isfinite(e.vx) and np.isfinite(e.noise_scale) for e in estimates)
    assert estimates[-1].vx == pytest.approx(2.0, abs=0.2)
    assert any(e.noise_scale != 1.0 for e in estimates)
