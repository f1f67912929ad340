"""The rover estimator's own sinkage model and the diagnostics' innovation test (issue 21, item 2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.estimators.rover_diagnostics import FaultCheck, consistency_channels, subset_nis
from terrain_estimation.models.rover import RoverParams, wheel_centres
from terrain_estimation.models.rover_estimators import (
    configuration,
    contact_angle_measurement,
    contact_angles_with_vertical_speed,
    path_tangent_angles,
)
from terrain_estimation.models.rover_sinkage import SinkageSoil, SinkageTracker, static_sinkage

KAPVIK = RoverParams()


def test_bekker_sinkage_of_table_ii_soil() -> None:
    """z* ≈ 16.8 mm at 50 N; dz*/dW = (2/(2n+1)) z*/W ≈ 0.21 mm/N; monotone; 0 unloaded."""
    soil = SinkageSoil()
    z = static_sinkage(soil, [0.0, 40.0, 50.0, 60.0], KAPVIK.wheel_radius, KAPVIK.wheel_width)
    assert z[0] == 0.0 and np.all(np.diff(z) > 0.0)
    assert z[2] == pytest.approx(0.0168, abs=3e-4)
    slope = (z[3] - z[1]) / 20.0
    assert slope == pytest.approx(2.0 / 3.2 * z[2] / 50.0, rel=0.03)
    stiffer = SinkageSoil(
        frictional_modulus=2.0 * soil.frictional_modulus, cohesive_modulus=2.0 * soil.cohesive_modulus
    )
    ratio = static_sinkage(stiffer, 50.0, KAPVIK.wheel_radius, KAPVIK.wheel_width) / z[2]
    assert float(ratio) == pytest.approx(2.0 ** (-2.0 / 3.2), rel=1e-9)
    with pytest.raises(ValueError, match="sinkage_exponent"):
        SinkageSoil(sinkage_exponent=3.0)


def test_tracker_loads_at_once_and_unloads_over_a_contact_length() -> None:
    tracker = SinkageTracker(SinkageSoil(), KAPVIK.wheel_radius, KAPVIK.wheel_width)
    s0, rate0 = tracker.step([50.0, 50.0, 50.0], 0.004, 0.2)
    assert np.all(rate0 == 0.0)
    s1, rate1 = tracker.step([60.0, 50.0, 40.0], 0.004, 0.2)
    high = static_sinkage(SinkageSoil(), 60.0, KAPVIK.wheel_radius, KAPVIK.wheel_width)
    assert s1[0] == pytest.approx(float(high)) and rate1[0] == pytest.approx((s1[0] - s0[0]) / 0.2)
    assert s1[1] == pytest.approx(s0[1]) and rate1[1] == 0.0
    # The unloaded wheel stays in its rut: after 4 mm of travel it has climbed 4 mm / l of the way, l = √(2 r s).
    low = float(static_sinkage(SinkageSoil(), 40.0, KAPVIK.wheel_radius, KAPVIK.wheel_width))
    length = KAPVIK.wheel_radius * math.sin(math.acos(1.0 - s0[2] / KAPVIK.wheel_radius))
    assert s1[2] == pytest.approx(low + (s0[2] - low) * math.exp(-0.004 / length))
    assert s0[2] > s1[2] > low and rate1[2] < 0.0
    for _ in range(200):  # 0.8 m later it is out of the rut
        s, _ = tracker.step([60.0, 50.0, 40.0], 0.004, 0.2)
    assert s[2] == pytest.approx(low, rel=1e-6)


def test_sunk_wheels_on_level_ground_give_level_contact_angles() -> None:
    """Wheels sunk by different depths tilt the rover; lifted by their sinkage the path is level again.

    Rear 18 mm, middle 14.5 mm, front 13.6 mm (the plant's terrain-1 means) on level ground: the body
    pitches by the difference over the wheelbase, and without the sinkage the path fitted through the
    centres is bent and tilted (the rear wheel's angle by 0.8°); the estimator's sinkage-aware fit finds 0.
    """
    sink = np.array([0.018, 0.0145, 0.0136])
    # The configuration that puts the three centres at z = r − s_j (level ground at z = 0): solve for θ, q1.
    pitch, bogie = 0.0, 0.0
    for _ in range(50):
        centres = wheel_centres(KAPVIK, configuration(pitch, bogie))
        residual = centres[:, 1] - centres[0, 1] + (sink - sink[0])
        jac = np.empty((3, 2))
        for col, (dp, db) in enumerate(((1e-7, 0.0), (0.0, 1e-7))):
            moved = wheel_centres(KAPVIK, configuration(pitch + dp, bogie + db))
            jac[:, col] = ((moved[:, 1] - moved[0, 1]) - (centres[:, 1] - centres[0, 1])) / 1e-7
        step = np.linalg.lstsq(jac, -residual, rcond=None)[0]
        pitch, bogie = pitch + step[0], bogie + step[1]
    assert abs(pitch) > 1e-3  # the sinkage difference pitches the body
    rigid = path_tangent_angles(KAPVIK, pitch, bogie)[0]
    sunk = path_tangent_angles(KAPVIK, pitch, bogie, sink)[0]
    assert np.max(np.abs(rigid)) > 0.01  # the rear wheel's γ̌ off by 0.8°, ≈ 0.7 N of DP at 60 N
    np.testing.assert_allclose(sunk, 0.0, atol=1e-9)
    # Rolling at 2 cm/s with a steady sinkage: the contact angles with ż0^R from the lifted path are level.
    inputs = np.array([pitch, bogie, 0.02 / math.cos(pitch), 0.0, 0.0])
    vs = contact_angles_with_vertical_speed(KAPVIK, inputs, np.eye(5) * 1e-12, sinkage=sink, sinkage_rate=np.zeros(3))
    np.testing.assert_allclose(vs.contact_angle, 0.0, atol=1e-6)
    # A wheel sinking at ṡ moves at atan(ṡ/v) off the surface: eq. 79 with ṡ added back to its v_z.
    rate = np.array([0.0, 2e-4, 0.0])
    args = (KAPVIK, pitch, bogie, 0.02 / math.cos(pitch), 0.0, 0.0, 0.0)
    shift = contact_angle_measurement(*args, sinkage_rate=rate) - contact_angle_measurement(*args)
    np.testing.assert_allclose(shift, [0.0, -math.atan(2e-4 / 0.02), 0.0], atol=1e-4)


def test_subset_nis_and_channels() -> None:
    assert consistency_channels(2) == ((8, 9, 10), (3, 4, 5, 6, 7, 8))
    assert consistency_channels(1) == ((8, 9, 10), (3, 4, 5))
    S = np.diag([1.0, 4.0, 9.0])
    S[0, 2] = S[2, 0] = 0.5
    nu = np.array([1.0, 2.0, 3.0])
    assert subset_nis(nu, S, [1]) == pytest.approx(1.0)
    assert subset_nis(nu, S, [0, 2]) == pytest.approx(
        float(nu[[0, 2]] @ np.linalg.solve(S[np.ix_([0, 2], [0, 2])], nu[[0, 2]]))
    )
    assert math.isnan(subset_nis(nu, np.zeros((3, 3)), [0]))


def test_fault_check_warns_on_a_jump_and_not_on_chi_square_values() -> None:
    rng = np.random.default_rng(3)
    check = FaultCheck(dof=10, window=10, probability=0.9999)
    warnings = [check.add(float(v)) for v in rng.chisquare(10, 2000)]
    assert sum(w is not None for w in warnings) <= 2
    check.reset()
    for v in rng.chisquare(10, 9):
        assert check.add(float(v)) is None
    jumped = check.add(200.0)  # one step of a 0.3 N offset on a cell of σ ≈ 0.02 N
    assert jumped is not None and "innovations jumped" in jumped
    with pytest.raises(ValueError):
        FaultCheck(dof=0, window=10, probability=0.99)
