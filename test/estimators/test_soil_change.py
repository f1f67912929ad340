"""Soil-change detector (estimators.soil_change) and its use by SoilStiffnessEstimator (issue 21, item 4).

The detector alone, on a scalar Kalman filter of a random-walk parameter
measured directly, where the innovation-implied jump has a closed form. The
estimator with it (armed without convergence, re-open sized by the jump) is
tested on the fine RK4 truth in ``test/models/test_models_soil_stiffness_estimator.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.estimators.soil_change import ChangeAlarm, SoilChangeDetector
from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimatorConfig


def _scalar_filter(
    truth: np.ndarray, r: float, q: float, p0: float, det: SoilChangeDetector, *, reopen: bool = False
) -> tuple[list[tuple[int, ChangeAlarm]], np.ndarray]:
    """Scalar KF of s (random walk q) from y = s + N(0, r); feeds the detector; the alarms and the estimates."""
    rng = np.random.default_rng(3)
    x, p = 0.0, p0
    alarms = []
    est = np.empty(truth.size)
    for k, s in enumerate(truth):
        p += q
        gain = p / (p + r)
        x_post = x + gain * (s + math.sqrt(r) * rng.standard_normal() - x)
        p_post = (1.0 - gain) * p
        alarm = det.update(x, p, x_post, p_post)
        x, p = x_post, p_post
        if alarm is not None:
            alarms.append((k, alarm))
            if reopen:
                x += alarm.jump
                p += alarm.reopen_std**2
        est[k] = x
    return alarms, est


def test_no_alarm_on_a_consistent_filter_and_the_implied_jump_on_a_step() -> None:
    # one update carries I = 1/r = 100 of information; the converged std is (q r)^¼ = 0.01
    r, q = 0.01, 1e-6
    det = SoilChangeDetector()
    alarms, _ = _scalar_filter(np.zeros(100_000), r, q, 1.0, det)
    assert alarms == []  # 1e5 white N(0, 1) corrections stay below 20σ
    assert det.statistic < 20.0
    # A step of 0.5: the corrections' mean becomes ≈ 0.5 √I = 5σ; one alarm, the implied jump is the step.
    truth = np.r_[np.zeros(5000), np.full(3000, 0.5)]
    det = SoilChangeDetector()
    alarms, est = _scalar_filter(truth, r, q, 1.0, det, reopen=True)
    assert len(alarms) == 1
    k, alarm = alarms[0]
    assert 5000 < k <= 5000 + 10
    assert alarm.direction == 1 and alarm.run_length >= 2
    # ŝ* − ŝ⁺ estimates the step still to be made, within its own std (plus a margin for a random walk)
    remaining = 0.5 - est[k - 1]
    assert abs(alarm.jump - remaining) < 4.0 * alarm.jump_std + 0.02
    assert alarm.reopen_std == pytest.approx(0.5 * abs(alarm.jump))  # the default scale
    # moved and re-opened: the filter sits on the new value right after the alarm
    assert abs(est[k + 20] - 0.5) < 0.1


def test_a_smaller_step_is_seen_by_the_drift_and_the_old_settings_miss_it() -> None:
    """A step shifting the corrections by ≈ 1.2σ: the defaults see it; ν = 1, h = 50 (former defaults) far later."""
    r, q = 0.01, 1e-6
    truth = np.r_[np.zeros(5000), np.full(5000, 0.12)]
    new, _ = _scalar_filter(truth, r, q, 1.0, SoilChangeDetector())
    old, _ = _scalar_filter(truth, r, q, 1.0, SoilChangeDetector(1.0, 50.0))
    assert len(new) == 1 and new[0][0] >= 5000
    assert not old or old[0][0] - 5000 > 3 * (new[0][0] - 5000)


def test_one_outlier_cannot_raise_an_alarm_two_can() -> None:
    det = SoilChangeDetector(0.5, 20.0, clip=20.0)
    assert det.update(0.0, 1.0, 100.0, 0.5) is None  # e ≈ 141σ, clipped to 20: 19.5 < 20
    alarm = det.update(0.0, 1.0, 100.0, 0.5)
    assert alarm is not None and alarm.direction == 1
    assert det.statistic == 0.0  # restarts after an alarm
    # a non-finite or uninformative update is ignored
    assert det.update(math.nan, 1.0, 0.0, 0.5) is None
    assert det.update(0.0, 1.0, 5.0, 1.0) is None and det.statistic == 0.0


def test_reopen_is_bounded() -> None:
    det = SoilChangeDetector(0.5, 1.0, reopen_min_std=0.3, reopen_max_std=1.5)
    a = det.update(0.0, 1e-4, 0.01, 0.9e-4)  # implied jump 0.09: the floor
    assert a is not None and a.reopen_std == pytest.approx(0.3)
    a = det.update(0.0, 1e-4, -1.0, 0.9e-4)  # huge implied jump: the cap
    assert a is not None and a.direction == -1 and a.jump < -5.0 and a.reopen_std == pytest.approx(1.5)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"drift": -1.0},
        {"threshold": 0.0},
        {"reopen_scale": -1.0},
        {"reopen_min_std": 2.0, "reopen_max_std": 1.0},
        {"drift": 5.0, "clip": 5.0},
    ],
)
def test_invalid_arguments(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        SoilChangeDetector(**kwargs)


def test_config_rejects_a_clip_below_the_drift_and_a_gain_outside_0_1() -> None:
    with pytest.raises(ValueError):
        SoilStiffnessEstimatorConfig(change_drift=3.0, change_clip=2.0)
    with pytest.raises(ValueError):
        SoilStiffnessEstimatorConfig(change_jump_gain=1.5)
