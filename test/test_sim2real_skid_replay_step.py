"""The skid-steer diagnosis's RK4 step (issue 22/23: a 60 s bag diagnosed in under a minute on 2 cores).

The diagnosis replays the bag with :data:`~terrain_analysis.sim2real.skid_steer_replay.DIAGNOSIS_STEP` (5 ms)
instead of the plant's 2 ms; the kernel's stiffness bound still raises the step count where the wheels roll slowly.
Measured on a 60 s bag: the replayed IMU moves by ≤ 0.4 % of the noise σ RMS on every channel and for every
physical effect. The bound here (2 % of σ) is five times that; a change of that size moves a channel's χ² by at most
≈ 2 × 0.02 per sample at the noise level and no verdict threshold (several χ² units over thousands of samples).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from terrain_analysis.sim2real.skid_steer import (
    DIAGNOSIS_STEP,
    Physics,
    bag_data_from_arrays,
    build_model,
    replay_imu,
    vehicle_from_config,
)
from vehicle_sim.effects import effects_for
from vehicle_sim.plants.skid_steer import MANOEUVRES, SkidSteerVehicle, simulate_skid_steer

VEHICLE = vehicle_from_config()
ROOT = Path(__file__).resolve().parent.parent
PHYSICS = {
    "nominal": Physics(),
    "tire_relaxation": Physics(tire_relaxation=True),
    "load_transfer_dynamics": Physics(load_transfer_dynamics=True),
    "turning_resistance": Physics(turning_resistance=0.2),
    "terrain_grade": Physics(terrain_grade=0.05, terrain_bank=-0.03),
    "friction_change": Physics(friction_factor=0.4),
    "cornering_stiffness_change": Physics(cornering_factor=1.8),
}


def _bag(manoeuvre: str):
    scenario = MANOEUVRES[manoeuvre](vehicle=SkidSteerVehicle(), effects=effects_for("skid_steer", {}))
    result = simulate_skid_steer(replace(scenario, duration=8.0), 5)
    return bag_data_from_arrays(
        result.t,
        result.linear_acceleration,
        result.angular_velocity[:, 2],
        result.t,
        result.motor_velocity,
        transmission_ratio=VEHICLE.transmission_ratio,
    )


@pytest.mark.parametrize("manoeuvre", ["small_radius_turn", "s_shape"])
def test_diagnosis_step_moves_the_replay_far_below_the_noise(manoeuvre):
    data = _bag(manoeuvre)
    use = data.t >= 1.0
    sigma = np.array([VEHICLE.accel_noise_std] * 3 + [VEHICLE.gyro_noise_std] * 3)
    for name, physics in PHYSICS.items():
        fine = replay_imu(VEHICLE, data.t, data.omega, physics, integration_step=2.0e-3)
        coarse = replay_imu(VEHICLE, data.t, data.omega, physics, integration_step=DIAGNOSIS_STEP)
        rms = np.sqrt(np.mean((coarse[use] - fine[use]) ** 2, axis=0)) / sigma
        assert np.all(rms < 0.02), f"{manoeuvre}, {name}: RMS change / σ per channel {np.round(rms, 5)}"


def test_the_diagnosis_model_uses_the_diagnosis_step():
    bag = ROOT / "bags" / "skid_steer_s_shape"
    if not bag.exists():
        pytest.skip("shipped bag not present")
    assert build_model(bag).integration_step == DIAGNOSIS_STEP
    assert build_model(bag, integration_step=2.0e-3).integration_step == 2.0e-3
