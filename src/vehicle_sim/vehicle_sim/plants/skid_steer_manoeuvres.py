"""What the skid steer is asked to do: the feedback driver, the manoeuvres of [SS] (MODELS.md B.11) and the scenario."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from vehicle_sim.plants.checks import check_fields, check_finite, check_positive
from vehicle_sim.plants.skid_steer_ground import SkidSteerGround
from vehicle_sim.plants.skid_steer_vehicle import SkidSteerEffects, SkidSteerSensors, SkidSteerVehicle
from vehicle_sim.plants.stepping import SensorTiming

__all__ = [
    "KMH",
    "MANOEUVRES",
    "Manoeuvre",
    "SkidSteerDriver",
    "SkidSteerScenario",
    "constant_torque",
    "s_shape",
    "small_radius_turn",
    "straight_acceleration",
]

KMH = 1.0 / 3.6
"""One km/h in m/s."""


# ---------------------------------------------------------------------------
# Driver and manoeuvres (MODELS.md B.11)
# ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class SkidSteerDriver:
    """Cascaded feedback driver producing left/right motor torque commands at the sensor rate.

    As on most skid-steered UGVs, an autopilot turns the speed and yaw-rate
    references into side wheel-speed set-points with the zero-slip kinematics
    of B.3, and a motor controller per side tracks its set-point with torque:

    ::

        v_cmd = v_ref + K_v (v_ref − vx) + K_iv ∫(v_ref − vx)          (PI on speed)
        r_cmd = r_ref + K_r (r_ref − r)  + K_ir ∫(r_ref − r)           (PI on yaw rate)
        ω_set,l/r = (v_cmd ∓ r_cmd B/2) / R
        τ_j = τ_ff + K_ω (ω_set,j − ω_j) + K_iω ∫(ω_set,j − ω_j)     (wheel side)
        T_m,j = clip(τ_j / (η i_g), ±T_max)

    The feed-forward ``τ_ff = R (m_eff a_ref + f_rr m g)/2`` covers the
    reference acceleration and the motion resistance. The outer integrals
    learn the slips (the paper's "encoder yaw rate too large" is what
    ``K_ir ∫`` compensates). All integrators freeze while a side saturates
    (anti-windup). The driver reads the true vx, r and wheel speeds (a perfect
    observer), so sensor noise never feeds back into the truth. The gains
    track the three manoeuvres of B.11 within 1 % of the references in steady
    state and stay below the wheel–tire torsional mode (≈ 7 Hz).

    Attributes:
        speed_gain: K_v (dimensionless).
        speed_integral_gain: K_iv (1/s).
        yaw_rate_gain: K_r (dimensionless).
        yaw_rate_integral_gain: K_ir (1/s).
        wheel_speed_gain: K_ω, wheel side (N·m per rad/s).
        wheel_speed_integral_gain: K_iω, wheel side (N·m per rad).
    """

    speed_gain: float = 1.0
    speed_integral_gain: float = 0.5
    yaw_rate_gain: float = 5.0
    yaw_rate_integral_gain: float = 20.0
    wheel_speed_gain: float = 600.0
    wheel_speed_integral_gain: float = 10.0e3

    def __post_init__(self) -> None:
        check_fields(self, rule="non_negative")


@dataclass(frozen=True, kw_only=True)
class Manoeuvre:
    """Reference trajectory for the driver, or constant open-loop motor torques.

    Speed reference: piecewise linear through (``speed_times``, ``speeds``),
    held after the last knot. Yaw-rate reference: piecewise linear through
    (``yaw_rate_times``, ``yaw_rates``) plus
    ``yaw_rate_amplitude · sin(2π (t − yaw_rate_sine_start)/yaw_rate_period)``
    for t ≥ ``yaw_rate_sine_start`` (S-shape).

    Attributes:
        name: manoeuvre name.
        duration: default simulated time (s).
        speed_times, speeds: knots (s, m/s); times strictly increasing from 0.
        yaw_rate_times, yaw_rates: knots (s, rad/s), r > 0 counter-clockwise.
        yaw_rate_amplitude: sine amplitude (rad/s).
        yaw_rate_period: sine period (s), > 0 when the amplitude is not 0.
        yaw_rate_sine_start: sine start time (s).
        initial_speed: vx at t = 0 (m/s), wheels free rolling.
        motor_torque: constant (left, right) motor torques (N·m) applied
            open-loop instead of the driver; None uses the driver.
    """

    name: str
    duration: float
    speed_times: tuple[float, ...] = (0.0,)
    speeds: tuple[float, ...] = (0.0,)
    yaw_rate_times: tuple[float, ...] = (0.0,)
    yaw_rates: tuple[float, ...] = (0.0,)
    yaw_rate_amplitude: float = 0.0
    yaw_rate_period: float = 1.0
    yaw_rate_sine_start: float = 0.0
    initial_speed: float = 0.0
    motor_torque: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        owner = "Manoeuvre"
        check_positive(owner, "duration", self.duration)
        for times_name, values_name in (("speed_times", "speeds"), ("yaw_rate_times", "yaw_rates")):
            times = tuple(float(t) for t in getattr(self, times_name))
            values = tuple(float(v) for v in getattr(self, values_name))
            if not times or len(times) != len(values):
                raise ValueError(f"{owner}.{times_name} and {values_name} need equally many (≥ 1) knots")
            if times[0] != 0.0 or any(b <= a for a, b in zip(times, times[1:], strict=False)):
                raise ValueError(f"{owner}.{times_name} must start at 0 and increase strictly, got {times}")
            if not all(math.isfinite(v) for v in values):
                raise ValueError(f"{owner}.{values_name} must be finite, got {values}")
            object.__setattr__(self, times_name, times)
            object.__setattr__(self, values_name, values)
        check_finite(owner, "yaw_rate_amplitude", self.yaw_rate_amplitude)
        check_positive(owner, "yaw_rate_period", self.yaw_rate_period)
        check_finite(owner, "yaw_rate_sine_start", self.yaw_rate_sine_start)
        check_finite(owner, "initial_speed", self.initial_speed)
        if self.motor_torque is not None:
            torque = tuple(float(t) for t in self.motor_torque)
            if len(torque) != 2 or not all(math.isfinite(t) for t in torque):
                raise ValueError(f"{owner}.motor_torque must be two finite values (left, right), got {torque}")
            object.__setattr__(self, "motor_torque", torque)

    def speed_reference(self, t: float) -> tuple[float, float]:
        """(v_ref (m/s), dv_ref/dt (m/s²)) at time t (s)."""
        times, speeds = self.speed_times, self.speeds
        if t >= times[-1]:
            return speeds[-1], 0.0
        i = int(np.searchsorted(times, t, side="right")) - 1
        slope = (speeds[i + 1] - speeds[i]) / (times[i + 1] - times[i])
        return speeds[i] + slope * (t - times[i]), slope

    def yaw_rate_reference(self, t: float) -> float:
        """r_ref (rad/s) at time t (s)."""
        r = float(np.interp(t, self.yaw_rate_times, self.yaw_rates))
        if self.yaw_rate_amplitude != 0.0 and t >= self.yaw_rate_sine_start:
            r += self.yaw_rate_amplitude * math.sin(
                2.0 * math.pi * (t - self.yaw_rate_sine_start) / self.yaw_rate_period
            )
        return r


# ---------------------------------------------------------------------------
# Scenario
# ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class SkidSteerScenario(SensorTiming):
    """One run: manoeuvre, vehicle, effects, sensors, driver, timing.

    Defaults to the nominal physics (all effects off, brush tire, level
    uniform ground, CONTRACT.md); the manoeuvre builders (:data:`MANOEUVRES`)
    switch on :meth:`SkidSteerEffects.truth_default` and
    :meth:`SkidSteerVehicle.truth_default` for the estimator tests and say so.

    Attributes:
        manoeuvre: what the driver does.
        vehicle: the vehicle.
        effects: unmodelled effects switched on.
        sensors: sensor models.
        driver: the feedback driver.
        ground: slope and terrain patches (:mod:`vehicle_sim.plants.skid_steer_ground`).
        duration: simulated time (s); None takes the manoeuvre's.
        sensor_rate: IMU and joint-state rate (Hz); one
            :meth:`SkidSteerSimulator.step` per period.
        integration_step: largest RK4 step (s); the period is divided into
            the smallest integer number of steps that makes it ≤ this (2 ms:
            converged to ≤ 2e-7 rad/s in yaw rate, see :mod:`~vehicle_sim.plants.skid_steer_dynamics`).
    """

    manoeuvre: Manoeuvre
    vehicle: SkidSteerVehicle = field(default_factory=SkidSteerVehicle)
    effects: SkidSteerEffects = field(default_factory=SkidSteerEffects)
    sensors: SkidSteerSensors = field(default_factory=SkidSteerSensors)
    driver: SkidSteerDriver = field(default_factory=SkidSteerDriver)
    duration: float | None = None
    sensor_rate: float = 100.0
    integration_step: float = 2.0e-3
    ground: SkidSteerGround = field(default_factory=SkidSteerGround)

    def __post_init__(self) -> None:
        owner = "SkidSteerScenario"
        if not isinstance(self.ground, SkidSteerGround):
            raise ValueError(f"{owner}.ground must be a SkidSteerGround, got {self.ground!r}")
        if self.duration is not None:
            check_positive(owner, "duration", self.duration)
        check_positive(owner, "sensor_rate", self.sensor_rate)
        check_positive(owner, "integration_step", self.integration_step)
        if self.sensors.gnss_rate > 0.0:
            ratio = self.sensor_rate / self.sensors.gnss_rate
            if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                raise ValueError(
                    f"SkidSteerSensors.gnss_rate must divide the sensor rate {self.sensor_rate} Hz, "
                    f"got {self.sensors.gnss_rate}"
                )

    @property
    def run_duration(self) -> float:
        """Simulated time (s): ``duration`` or the manoeuvre's."""
        return self.manoeuvre.duration if self.duration is None else self.duration

    @property
    def n_samples(self) -> int:
        """Number of sensor samples of the run."""
        return int(round(self.run_duration * self.sensor_rate))


def _scenario(
    manoeuvre: Manoeuvre,
    vehicle: SkidSteerVehicle | None,
    effects: SkidSteerEffects | None,
    sensors: SkidSteerSensors | None,
    driver: SkidSteerDriver | None,
) -> SkidSteerScenario:
    """The builders' defaults: the truth's vehicle (magic-formula tire) and, without ``effects``, its effects."""
    if vehicle is None:
        vehicle = SkidSteerVehicle.truth_default()
    return SkidSteerScenario(
        manoeuvre=manoeuvre,
        vehicle=vehicle,
        effects=SkidSteerEffects.truth_default() if effects is None else effects,
        sensors=SkidSteerSensors() if sensors is None else sensors,
        driver=SkidSteerDriver() if driver is None else driver,
    )


def straight_acceleration(
    *,
    vehicle: SkidSteerVehicle | None = None,
    effects: SkidSteerEffects | None = None,
    sensors: SkidSteerSensors | None = None,
    driver: SkidSteerDriver | None = None,
    duration: float = 20.0,
    top_speed: float = 30.0 * KMH,
    acceleration: float = 1.0,
    start: float = 1.0,
) -> SkidSteerScenario:
    """[SS] straight run (B.11): standstill, then 0 → 30 km/h at 1 m/s², then hold.

    Defaults: the truth of the estimator tests, :meth:`SkidSteerVehicle.truth_default`
    (magic-formula tire) and, without ``effects``, :meth:`SkidSteerEffects.truth_default`.
    A sim-to-real experiment on the nominal model passes ``vehicle=SkidSteerVehicle()``
    (brush tire) with its effects.
    With the defaults the speed reference reaches 30 km/h at 9.3 s and holds
    it to 20 s.
    """
    ramp_end = start + top_speed / acceleration
    manoeuvre = Manoeuvre(
        name="straight_acceleration",
        duration=duration,
        speed_times=(0.0, start, ramp_end),
        speeds=(0.0, 0.0, top_speed),
    )
    return _scenario(manoeuvre, vehicle, effects, sensors, driver)


def small_radius_turn(
    *,
    vehicle: SkidSteerVehicle | None = None,
    effects: SkidSteerEffects | None = None,
    sensors: SkidSteerSensors | None = None,
    driver: SkidSteerDriver | None = None,
    duration: float = 45.0,
    speed: float = 5.0 * KMH,
    yaw_rate: float = 0.2,
) -> SkidSteerScenario:
    """[SS] small-radius turn (B.11, D.2): ≈ 5 km/h, 0.2 rad/s counter-clockwise, R ≈ 7 m.

    Standstill to 1 s, speed ramp at 0.5 m/s², straight run-in to 6 s, yaw
    rate ramped to its final value over 6–8 s and held to the end (the
    paper's analysis window is 20–40 s). Vehicle and effects default as for
    :func:`straight_acceleration` (the truth when no effects are given).
    """
    manoeuvre = Manoeuvre(
        name="small_radius_turn",
        duration=duration,
        speed_times=(0.0, 1.0, 1.0 + speed / 0.5),
        speeds=(0.0, 0.0, speed),
        yaw_rate_times=(0.0, 6.0, 8.0),
        yaw_rates=(0.0, 0.0, yaw_rate),
    )
    return _scenario(manoeuvre, vehicle, effects, sensors, driver)


def s_shape(
    *,
    vehicle: SkidSteerVehicle | None = None,
    effects: SkidSteerEffects | None = None,
    sensors: SkidSteerSensors | None = None,
    driver: SkidSteerDriver | None = None,
    duration: float = 30.0,
    speed: float = 30.0 * KMH,
    yaw_rate_amplitude: float = 0.15,
    period: float = 10.0,
) -> SkidSteerScenario:
    """[SS] S-shaped path at 30 km/h (B.11, D.2): alternating left/right large-radius turns.

    Starts rolling at 30 km/h; yaw-rate reference 0.15 sin(2π t / 10 s) rad/s
    (radius ≥ 55 m, lateral acceleration ≤ 1.25 m/s²), so 20–25 s (the
    paper's window) is one whole left lobe. Vehicle and effects default as
    for :func:`straight_acceleration` (the truth when no effects are given).
    """
    manoeuvre = Manoeuvre(
        name="s_shape",
        duration=duration,
        speed_times=(0.0,),
        speeds=(speed,),
        yaw_rate_amplitude=yaw_rate_amplitude,
        yaw_rate_period=period,
        initial_speed=speed,
    )
    return _scenario(manoeuvre, vehicle, effects, sensors, driver)


def constant_torque(
    left: float,
    right: float,
    *,
    vehicle: SkidSteerVehicle | None = None,
    effects: SkidSteerEffects | None = None,
    sensors: SkidSteerSensors | None = None,
    duration: float = 10.0,
    initial_speed: float = 0.0,
) -> SkidSteerScenario:
    """Open-loop constant motor torques (N·m, motor side), no driver: for checks and diagnosis.

    Unlike the paper manoeuvres, effects default to :meth:`SkidSteerEffects.nominal`
    and the vehicle to the nominal :class:`SkidSteerVehicle` (brush tire).
    """
    manoeuvre = Manoeuvre(
        name="constant_torque",
        duration=duration,
        initial_speed=initial_speed,
        motor_torque=(left, right),
    )
    return SkidSteerScenario(
        manoeuvre=manoeuvre,
        vehicle=SkidSteerVehicle() if vehicle is None else vehicle,
        effects=SkidSteerEffects.nominal() if effects is None else effects,
        sensors=SkidSteerSensors() if sensors is None else sensors,
    )


MANOEUVRES: dict[str, Callable[..., SkidSteerScenario]] = {
    "straight_acceleration": straight_acceleration,
    "small_radius_turn": small_radius_turn,
    "s_shape": s_shape,
}
"""The paper's three experiments (MODELS.md B.11) by name; each returns a scenario."""
