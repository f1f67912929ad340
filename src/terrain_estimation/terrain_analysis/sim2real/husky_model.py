"""The Husky A200 as a skid-steer replay model (:mod:`terrain_analysis.sim2real.husky`).

The 4-wheel Husky of ``config/husky.yaml`` (two axles at ±wheelbase/2, rigid chassis) in the replay of
:mod:`terrain_analysis.sim2real.skid_steer`, on a bag imported from BorealTC: yaw rate and lateral specific force
compared, side speeds taken as instantaneous, noise budget from the IMU's own high-frequency noise plus the
wheel-speed quantisation, the tire scales as nuisance parameters.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import candidates_from_catalogue
from terrain_analysis.sim2real.skid_steer_bag import read_skid_steer_bag
from terrain_analysis.sim2real.skid_steer_replay import SkidSteerReplay
from terrain_analysis.sim2real.skid_steer_vehicle import ReplayVehicle

__all__ = ["CHANNELS", "NUISANCE_NAMES", "build_husky_model", "husky_vehicle", "imu_noise_std"]

FloatArray = NDArray[np.float64]

NUISANCE_NAMES = ("longitudinal_stiffness_scale", "cornering_stiffness_scale", "friction_scale")
CHANNELS = ("yaw_rate", "ay")


def imu_noise_std(x: FloatArray) -> float:
    """Robust white-noise σ of a 100 Hz signal: 1.4826 × MAD of first differences / √2."""
    d = np.diff(np.asarray(x, dtype=float))
    mad = float(np.median(np.abs(d - np.median(d))))
    return max(1.4826 * mad / math.sqrt(2.0), 1e-6)


#: The :class:`ReplayVehicle` fields that are the config's ``vehicle.<field>`` as they are.
_FROM_CONFIG = (
    "mass",
    "yaw_inertia",
    "gravity",
    "track",
    "cg_height",
    "wheel_radius",
    "transmission_ratio",
    "longitudinal_stiffness",
    "cornering_stiffness",
    "friction",
    "rolling_speed_floor",
    "rolling_resistance",
    "rolling_resistance_speed",
    "longitudinal_relaxation_length",
    "lateral_relaxation_length",
    "relaxation_speed_floor",
)


def husky_vehicle(config: str | Path | None = None, *, accel_noise_std: float, gyro_noise_std: float) -> ReplayVehicle:
    """The Husky of ``config/husky.yaml`` as a :class:`ReplayVehicle` (rigid chassis, two axles)."""
    from vehicle_sim.tools.borealtc import read_husky_config

    c = read_husky_config(config)
    half = 0.5 * c["vehicle.wheelbase"]
    radius = c["vehicle.wheel_radius"]
    return ReplayVehicle(
        name="husky",
        axle_x=(half, -half),
        suspension=None,
        accel_noise_std=accel_noise_std,
        gyro_noise_std=gyro_noise_std,
        wheel_speed_noise_std=0.0,
        speed_step=c["sensors.wheel_speed_step"] / radius,
        **{name: c[f"vehicle.{name}"] for name in _FROM_CONFIG},
    )


def build_husky_model(
    bag: str | Path, config: str | Path | None = None, *, namespace: str = "/husky", warmup: float = 1.0
) -> SkidSteerReplay:
    """Replay model of one imported Husky bag (module docstring)."""
    from vehicle_sim.tools.borealtc import read_husky_config

    ratio = read_husky_config(config)["vehicle.transmission_ratio"]
    data = read_skid_steer_bag(bag, namespace=namespace, transmission_ratio=ratio, wheel_speed_timing="instantaneous")
    vehicle = husky_vehicle(
        config, accel_noise_std=imu_noise_std(data.accel[:, 1]), gyro_noise_std=imu_noise_std(data.yaw_rate)
    )
    # μ and C_α are nuisance parameters here (fitted in every model): their catalogue effects would duplicate them.
    duplicates = ("friction_change", "cornering_stiffness_change", "load_transfer_dynamics")
    candidates = candidates_from_catalogue("skid_steer", exclude=duplicates)
    model = SkidSteerReplay(
        data, vehicle, nuisance=NUISANCE_NAMES, channels=CHANNELS, warmup=warmup, candidates=candidates
    )
    model.notes.append(
        "Husky: friction_change and cornering_stiffness_change not offered (μ and C_α are fitted as nuisance); "
        "load_transfer_dynamics not offered (rigid chassis)"
    )
    model.notes.append(
        "Husky: side speeds at 6.5 Hz interpolated to the IMU; noise budget = IMU high-frequency σ + quantisation"
    )
    return model
