"""The skid-steered vehicle of the replay (:mod:`terrain_analysis.sim2real.skid_steer`): geometry, mass, tires, sensors.

What the replay (:mod:`~terrain_analysis.sim2real.skid_steer_replay`) and the Husky's real-data check
(:mod:`~terrain_analysis.sim2real.husky`) both need of the vehicle: :class:`ReplayVehicle`, its quasi-static wheel
loads and its no-slip kinematics. Units SI (m, s, rad, N, kg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ReplayVehicle",
    "Suspension",
    "equal_spring_loads",
    "no_slip_motion",
    "vehicle_from_config",
    "with_vehicle",
]

FloatArray = NDArray[np.float64]


def equal_spring_loads(
    axle_x: FloatArray, track: float, mass: float, gravity: float, cg_height: float, ax: float, ay: float
) -> FloatArray:
    """Quasi-static wheel loads of a rigid body on equal virtual springs (MODELS.md B.5), any number of axles.

    Axle loads ``F_i = p + q x_i`` with ``n p + q Σx = m g`` and
    ``p Σx + q Σx² = −m a_x H``; lateral transfer ``m a_y H / B`` split
    equally over the axles. Wheel order: left wheels front to rear, then the
    right wheels. Not floored (the replay floors after adding the transfers).
    For three axles this is :func:`terrain_estimation.models.skid_steer.quasi_static_loads`.

    Returns:
        F_z per wheel (N), shape (2 n_axles,).
    """
    xa = np.asarray(axle_x, dtype=float)
    n = len(xa)
    s1, s2 = float(np.sum(xa)), float(np.sum(xa**2))
    d = n * s2 - s1**2
    p0 = mass * (gravity * s2 + ax * cg_height * s1) / d
    q = -mass * (n * ax * cg_height + gravity * s1) / d
    axle = p0 + q * xa
    lateral = mass * ay * cg_height / (n * track)
    return np.concatenate([0.5 * axle - lateral, 0.5 * axle + lateral])


@dataclass(frozen=True)
class ReplayVehicle:
    """What the replay needs of a skid-steered vehicle (any number of axles, one drive per side).

    Attributes:
        name: for the report.
        mass, yaw_inertia, gravity: m (kg), I_z (kg·m²), g (m/s²).
        axle_x: axle positions relative to the CM, front to rear (m).
        track: B (m), wheels at y = ±B/2.
        cg_height: H (m), for the quasi-static loads.
        wheel_radius: R (m); transmission_ratio: motor → wheel i_g.
        longitudinal_stiffness, cornering_stiffness, friction: brush C_x (N),
            C_α (N/rad), μ per wheel; rolling_speed_floor: ε (m/s).
        rolling_resistance: f_rr; rolling_resistance_speed: v_rr (m/s).
        suspension: sprung-mass data for ``load_transfer_dynamics`` or None
            (no suspension: the effect is not offered).
        longitudinal_relaxation_length, lateral_relaxation_length: L_x, L_y (m);
            relaxation_speed_floor (m/s).
        accel_noise_std, gyro_noise_std: IMU noise σ (m/s², rad/s).
        wheel_speed_noise_std: σ of the white noise on a reported *wheel-side* speed (rad/s).
        encoder_step: motor-side encoder quantum (rad) when the reported speed is
            the difference of quantised positions over the report period (0: not).
        speed_step: quantum of the reported wheel-side speed itself (rad/s; 0: not quantised).
    """

    name: str
    mass: float
    yaw_inertia: float
    gravity: float
    axle_x: tuple[float, ...]
    track: float
    cg_height: float
    wheel_radius: float
    transmission_ratio: float
    longitudinal_stiffness: float
    cornering_stiffness: float
    friction: float
    rolling_speed_floor: float
    rolling_resistance: float
    rolling_resistance_speed: float
    suspension: Suspension | None
    longitudinal_relaxation_length: float
    lateral_relaxation_length: float
    relaxation_speed_floor: float
    accel_noise_std: float
    gyro_noise_std: float
    wheel_speed_noise_std: float
    encoder_step: float = 0.0
    speed_step: float = 0.0

    @property
    def n_axles(self) -> int:
        return len(self.axle_x)

    def wheel_positions(self) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """(x, y, side) of every wheel: left side front to rear, then right (side 0 = left)."""
        xa = np.asarray(self.axle_x, dtype=float)
        n = len(xa)
        half = 0.5 * self.track
        return (
            np.concatenate([xa, xa]),
            np.concatenate([np.full(n, half), np.full(n, -half)]),
            np.concatenate([np.zeros(n, dtype=np.int64), np.ones(n, dtype=np.int64)]),
        )


@dataclass(frozen=True)
class Suspension:
    """Sprung-mass roll/pitch model of the plant (SkidSteerVehicle), for ``load_transfer_dynamics``.

    Attributes:
        sprung_mass: m_s (kg); unsprung_mass: total 2 n m_u (kg).
        roll_centre_height, pitch_centre_height: h_rc, h_pc (m).
        roll_arm, pitch_arm: H_s − h_rc, H_s − h_pc (m).
        roll_axis_inertia, pitch_axis_inertia: about the roll/pitch axes (kg·m²).
        roll_stiffness, roll_damping, pitch_stiffness, pitch_damping: K, C (N·m/rad, N·m·s/rad).
    """

    sprung_mass: float
    unsprung_mass: float
    roll_centre_height: float
    pitch_centre_height: float
    roll_arm: float
    pitch_arm: float
    roll_axis_inertia: float
    pitch_axis_inertia: float
    roll_stiffness: float
    roll_damping: float
    pitch_stiffness: float
    pitch_damping: float


def vehicle_from_config(config: str | Path | None = None) -> ReplayVehicle:
    """The 6-wheel skid steer from ``config/skid_steer.yaml`` (or ``config``): vehicle, plant and sensor sections.

    Uses the simulator's own parameter resolution and scenario builder, so the
    replay runs on exactly the plant the config describes (its ``effects.*``
    are ignored: the replay's nominal model has every catalogue effect off).
    """
    from vehicle_sim.ros.registry import get_simulator, simulator_parameters
    from vehicle_sim.ros.skid_steer import make_scenario

    entry = get_simulator("skid_steer")
    values = simulator_parameters(entry, config)
    scenario = make_scenario(values)
    v = scenario.vehicle
    p = v.nominal
    s = scenario.sensors
    from terrain_estimation.models.skid_steer import axle_positions

    step = 2.0 * math.pi / s.encoder_counts_per_revolution
    return ReplayVehicle(
        name="skid_steer",
        mass=p.mass,
        yaw_inertia=p.yaw_inertia,
        gravity=p.gravity,
        axle_x=tuple(float(x) for x in axle_positions(p)),
        track=p.track,
        cg_height=p.cg_height,
        wheel_radius=p.wheel_radius,
        transmission_ratio=p.transmission_ratio,
        longitudinal_stiffness=p.longitudinal_stiffness,
        cornering_stiffness=p.cornering_stiffness,
        friction=p.friction,
        rolling_speed_floor=p.rolling_speed_floor,
        rolling_resistance=v.rolling_resistance,
        rolling_resistance_speed=v.rolling_resistance_speed,
        suspension=Suspension(
            sprung_mass=v.sprung_mass,
            unsprung_mass=v.unsprung_mass,
            roll_centre_height=v.roll_centre_height,
            pitch_centre_height=v.pitch_centre_height,
            roll_arm=v.roll_arm,
            pitch_arm=v.pitch_arm,
            roll_axis_inertia=v.roll_axis_inertia,
            pitch_axis_inertia=v.pitch_axis_inertia,
            roll_stiffness=v.roll_stiffness,
            roll_damping=v.roll_damping,
            pitch_stiffness=v.pitch_stiffness,
            pitch_damping=v.pitch_damping,
        ),
        longitudinal_relaxation_length=v.longitudinal_relaxation_length,
        lateral_relaxation_length=v.lateral_relaxation_length,
        relaxation_speed_floor=v.relaxation_speed_floor,
        accel_noise_std=s.accel_noise_std,
        gyro_noise_std=s.gyro_noise_std,
        wheel_speed_noise_std=s.motor_velocity_noise_std / p.transmission_ratio,
        encoder_step=step,
    )


def with_vehicle(vehicle: ReplayVehicle, **changes: Any) -> ReplayVehicle:
    """A copy of ``vehicle`` with fields changed (dataclasses.replace, for tests and the Husky)."""
    return replace(vehicle, **changes)


def no_slip_motion(omega: FloatArray, radius: float, track: float) -> tuple[FloatArray, FloatArray]:
    """Forward speed R (ω_l + ω_r)/2 (m/s) and yaw rate R (ω_r − ω_l)/B (rad/s) of the side wheel speeds
    ``omega`` (…, 2: left, right; rad/s) if the wheels did not slip: the kinematic (encoder) motion."""
    omega = np.asarray(omega, dtype=float)
    left, right = omega[..., 0], omega[..., 1]
    return radius * 0.5 * (left + right), radius * (right - left) / track
