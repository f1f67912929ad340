"""Truth plant of the six-wheel skid-steered vehicle ([SS], MODELS.md B.2–B.6, B.11).

The observer of [SS] (MODELS.md B.7) is a 3-state planar model: flat ground,
quasi-static loads (B.5), instantaneous brush tire forces (B.4), wheel speeds
as inputs. This plant generates the truth it is tested against and
deliberately has more physics (DESIGN.md: a filter tested against its own
model proves nothing):

* wheel-side rotational dynamics driven by motor torques through the
  transmission (B.6, "optional wheel-side dynamics"), with the reflected motor
  inertia and a transmission efficiency;
* motion resistance of the soil on every wheel (terramechanics: drawbar pull =
  thrust − motion resistance), so the tires must slip to keep a steady speed;
* switchable *effects* (:class:`SkidSteerEffects`, CONTRACT.md "Nominal model
  and effects"): sprung-mass roll/pitch dynamics that make the vertical loads
  come from suspension forces and lag the accelerations, first-order tire
  force relaxation, sensor biases and scale factors per axis, IMU and
  wheel-encoder stream delays (each buffered on its own), wrong rolling
  radius, friction and cornering-stiffness changes, a road grade (helical)
  or a world-fixed ground plane in grade and bank, the lateral soil
  resistance of deformable ground (skid-steer turning resistance);
* a tire law of its own (:mod:`vehicle_sim.plants.tire_laws`,
  ``SkidSteerVehicle.tire_law``): the truth (:meth:`SkidSteerVehicle.truth_default`,
  the manoeuvre builders' default vehicle) runs a
  combined-slip magic-formula tire with load-dependent stiffness and
  friction; ``"brush"`` keeps the paper's idealised law (the dataclass default,
  i.e. the nominal model of the sim-to-real catalogue);
* a ground of its own (:mod:`vehicle_sim.plants.skid_steer_ground`,
  ``SkidSteerScenario.ground``): a plane with grade and cross slope, and
  terrain patches changing μ, tire stiffness and rolling resistance under each
  wheel.

Only geometry and kinematics are shared with the observer
(``terrain_estimation.models.skid_steer``: contact velocities, wheel
positions, the brush model's theoretical slips, force sums, slip ratio, ICR);
force laws (tires, loads) are the plant's own.

The plant is split by concept: the vehicle, its effects and sensors
(:mod:`~vehicle_sim.plants.skid_steer_vehicle`), the driver, manoeuvres and
scenario (:mod:`~vehicle_sim.plants.skid_steer_manoeuvres`), the state, its
integration and the equations of motion
(:mod:`~vehicle_sim.plants.skid_steer_dynamics`), the tire laws
(:mod:`~vehicle_sim.plants.tire_laws`) and the ground
(:mod:`~vehicle_sim.plants.skid_steer_ground`). This module runs them: the
sensors, the truth and :class:`SkidSteerSimulator`; it also re-exports the
configuration names (:data:`__all__`) so that a caller needs one import.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.models.skid_steer import (
    WHEEL_NAMES,
    body_sideslip,
    instantaneous_centre_of_rotation,
    side_slip_ratios,
    tire_sideslip_angles,
)
from vehicle_sim.plants.skid_steer_dynamics import (
    _ANGLE_L,
    _ANGLE_R,
    _FY,
    _N_STATES,
    _OMEGA_L,
    _OMEGA_R,
    _PITCH,
    _PITCH_RATE,
    _R,
    _ROLL,
    _ROLL_RATE,
    _VX,
    _VY,
    _X,
    _Y,
    _YAW,
    _EquationsOfMotion,
    _Evaluation,
    _rk4,
)
from vehicle_sim.plants.skid_steer_manoeuvres import (
    MANOEUVRES,
    Manoeuvre,
    SkidSteerDriver,
    SkidSteerScenario,
    constant_torque,
    s_shape,
    small_radius_turn,
    straight_acceleration,
)
from vehicle_sim.plants.skid_steer_vehicle import (
    TURNING_RESISTANCE_SPEED,
    SkidSteerEffects,
    SkidSteerSensors,
    SkidSteerVehicle,
)
from vehicle_sim.plants.stepping import FiniteRun, stack_fields

__all__ = [
    "TURNING_RESISTANCE_SPEED",
    "WHEEL_NAMES",
    "MANOEUVRES",
    "GnssReading",
    "GnssReadings",
    "Manoeuvre",
    "SkidSteerDriver",
    "SkidSteerEffects",
    "SkidSteerSample",
    "SkidSteerScenario",
    "SkidSteerSensors",
    "SkidSteerSimulationResult",
    "SkidSteerSimulator",
    "SkidSteerTruth",
    "SkidSteerVehicle",
    "constant_torque",
    "s_shape",
    "simulate_skid_steer",
    "small_radius_turn",
    "straight_acceleration",
]

Array = NDArray[np.float64]


# ---------------------------------------------------------------------------
# Samples and results
# ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class GnssReading:
    """One RTK-GNSS reference (``gnss/odom``): body-frame twist and odom-frame pose with noise.

    Attributes:
        t: time (s).
        vx, vy: body-frame velocity (m/s).
        x, y: position (m).
        yaw: heading (rad), wrapped to (−π, π].
    """

    t: float
    vx: float
    vy: float
    x: float
    y: float
    yaw: float


@dataclass(frozen=True, slots=True)
class GnssReadings:
    """All GNSS readings of a run, arrays (M,); fields as :class:`GnssReading`."""

    t: Array
    vx: Array
    vy: Array
    x: Array
    y: Array
    yaw: Array


@dataclass(frozen=True, slots=True)
class SkidSteerTruth:
    """What only the simulator knows. Scalars / small arrays in a sample, stacked (N, …) in a result.

    Per-side arrays are (left, right); per-wheel arrays follow :data:`WHEEL_NAMES`.

    Attributes:
        vx, vy: body-frame velocity of the CM (m/s).
        yaw_rate: r (rad/s).
        x, y, yaw: pose in the odom frame (m, m, rad; yaw unwrapped).
        body_sideslip: β = atan2(vy, vx) (rad, eq. 40).
        slip: per-side slip κ (B.3) with the true rolling radius, (2,).
        tire_sideslip: α per wheel (rad, eq. 6), (6,).
        icr_x, icr_y: ICR in body axes (m, eq. 41); 0 when not valid.
        icr_valid: |r| > 0.02 rad/s.
        normal_load: F_z per wheel (N), (6,).
        tire_force_x, tire_force_y: tire forces acting (N), (6,) (lagged with
            relaxation).
        steady_tire_force_x, steady_tire_force_y: forces F_ss of the tire law
            for the current slips (N), (6,); equal to the acting forces without
            relaxation.
        motion_resistance: rolling resistance per wheel (N), (6,), opposing
            the contact's longitudinal velocity.
        friction: μ of the surface under each wheel (6,) (effects and patches
            included; the magic formula lowers it further with load).
        specific_force_x, specific_force_y: ground force / m in the road frame
            (m/s²); on level ground the CM accelerations v̇x − vy r, v̇y + vx r.
        roll, pitch: sprung-mass attitude relative to the road (rad; roll > 0
            left side up, pitch > 0 nose down, REP 103).
        roll_rate, pitch_rate: their rates (rad/s).
        wheel_speed: wheel-side angular speeds (rad/s), (2,).
        motor_torque: applied motor torques (N·m, motor side), (2,).
        speed_reference, yaw_rate_reference: driver references (m/s, rad/s).
    """

    vx: Any
    vy: Any
    yaw_rate: Any
    x: Any
    y: Any
    yaw: Any
    body_sideslip: Any
    slip: Any
    tire_sideslip: Any
    icr_x: Any
    icr_y: Any
    icr_valid: Any
    normal_load: Any
    tire_force_x: Any
    tire_force_y: Any
    steady_tire_force_x: Any
    steady_tire_force_y: Any
    motion_resistance: Any
    friction: Any
    specific_force_x: Any
    specific_force_y: Any
    roll: Any
    pitch: Any
    roll_rate: Any
    pitch_rate: Any
    wheel_speed: Any
    motor_torque: Any
    speed_reference: Any
    yaw_rate_reference: Any


@dataclass(frozen=True, slots=True)
class SkidSteerSample:
    """Everything the sensors report for one sensor period, plus the truth at its end.

    Attributes:
        t: time at the end of the period (s).
        linear_acceleration: IMU specific force (x, y, z) in the IMU frame
            (m/s², REP 145: +g on z at rest), noise, bias and delay included.
        angular_velocity: IMU angular rate (x, y, z) (rad/s).
        motor_position: quantised motor angles (left, right) (rad, motor side).
        motor_velocity: reported motor speeds (rad/s, motor side).
        motor_effort: reported motor torques (N·m, motor side).
        gnss: the GNSS reading taken at t, or None.
        truth: plant state at t.
    """

    t: float
    linear_acceleration: Array
    angular_velocity: Array
    motor_position: Array
    motor_velocity: Array
    motor_effort: Array
    gnss: GnssReading | None
    truth: SkidSteerTruth


@dataclass(frozen=True)
class SkidSteerSimulationResult:
    """Stacked samples of one run at the sensor rate (N = duration × rate).

    Attributes:
        scenario: the scenario.
        seed: sensor-noise seed.
        t: (N,) sample times (s): period … duration.
        linear_acceleration: (N, 3) m/s².
        angular_velocity: (N, 3) rad/s.
        motor_position, motor_velocity, motor_effort: (N, 2) motor side.
        gnss: GNSS readings (M,) at the GNSS rate.
        truth: truth with arrays (N,), (N, 2) or (N, 6).
    """

    scenario: SkidSteerScenario
    seed: int
    t: Array
    linear_acceleration: Array
    angular_velocity: Array
    motor_position: Array
    motor_velocity: Array
    motor_effort: Array
    gnss: GnssReadings
    truth: SkidSteerTruth

    def window(self, start: float, stop: float) -> NDArray[np.bool_]:
        """Mask of the samples with start ≤ t ≤ stop (s)."""
        return (self.t >= start - 1e-9) & (self.t <= stop + 1e-9)


# ---------------------------------------------------------------------------
# Simulator
# ---------------------------------------------------------------------------


class SkidSteerSimulator(FiniteRun):
    """Stepping truth simulator of the skid-steered vehicle.

    Each :meth:`step` runs the driver once (torques held over the period),
    advances one sensor period with RK4 and returns a :class:`SkidSteerSample`.

    Args:
        scenario: manoeuvre, vehicle, effects, sensors.
        seed: seed of the sensor noise. Accelerometer, gyroscope, encoder
            velocity, motor effort and GNSS draw from independent streams
            spawned from it; the truth never depends on it.
    """

    def __init__(self, scenario: SkidSteerScenario, seed: int) -> None:
        self.scenario = scenario
        self.seed = seed
        self._equations = _EquationsOfMotion(scenario)
        self._period = scenario.sensor_period
        self._base_substeps = scenario.substeps
        self._n_samples = scenario.n_samples
        streams = np.random.SeedSequence(seed).spawn(5)
        self._accel_rng, self._gyro_rng, self._velocity_rng, self._effort_rng, self._gnss_rng = (
            np.random.default_rng(s) for s in streams
        )
        sensors = scenario.sensors
        self._encoder_step = 2.0 * math.pi / sensors.encoder_counts_per_revolution
        self._gnss_every = int(round(scenario.sensor_rate / sensors.gnss_rate)) if sensors.gnss_rate > 0.0 else 0
        ratio = scenario.vehicle.nominal.transmission_ratio
        self._ratio = ratio

        state = np.zeros(_N_STATES)
        v0 = scenario.manoeuvre.initial_speed
        state[_VX] = v0
        state[_OMEGA_L] = state[_OMEGA_R] = v0 / self._equations.radius
        if scenario.effects.tire_relaxation and not self._equations.ground.level:
            # On a slope the lagged lateral forces start holding the vehicle (shares ∝ the static loads), not at 0.
            _, gravity_y, _ = self._equations.ground.gravity(1.0, 0.0)
            static = self._equations.static_load_per_gravity
            state[_FY] = -self._equations.mass * gravity_y * static / float(np.sum(static))
        self._state = state
        self._hold = (0.0, 0.0)
        self._speed_integral = 0.0
        self._yaw_integral = 0.0
        self._wheel_integral = [0.0, 0.0]
        self._motor_torque = (0.0, 0.0)
        self._step_index = 0
        self._last_substeps = self._base_substeps
        self._previous_position = self._quantised_position(state)
        # Noise-free IMU history at the sensor rate, from t = 0, for the sensor delay.
        delay_samples = scenario.effects.sensor_delay / self._period
        self._imu_history: deque[Array] = deque(maxlen=int(math.ceil(delay_samples)) + 2)
        self._imu_history.append(self._measure(state, self._equations.evaluate(state, (0.0, 0.0), self._hold))[0])
        # True motor angles at the sensor rate, from t = 0, for the encoder-stream delay (wheel_speed_delay).
        wheel_delay_samples = scenario.effects.wheel_speed_delay / self._period
        self._angle_history: deque[Array] = deque(maxlen=int(math.ceil(wheel_delay_samples)) + 3)
        self._angle_history.append(ratio * state[_ANGLE_L : _ANGLE_R + 1].copy())
        self._initial_motor_speed = ratio * state[_OMEGA_L : _OMEGA_R + 1].copy()
        if scenario.effects.wheel_speed_delay > 0.0:
            self._previous_position = self._delayed_position(0.0)

    # --- public state (t, step_index, done: FiniteRun) -----------------------

    @property
    def state(self) -> Array:
        """Copy of the 26 plant states (see :mod:`vehicle_sim.plants.skid_steer_dynamics`)."""
        return self._state.copy()

    @property
    def last_substeps(self) -> int:
        """RK4 steps used in the last period (more than the base count when stiff)."""
        return self._last_substeps

    # --- driver -------------------------------------------------------------

    def _drive(self, t: float) -> tuple[float, float]:
        """Motor torque commands (N·m, motor side) for the coming period (:class:`SkidSteerDriver`)."""
        scenario = self.scenario
        manoeuvre = scenario.manoeuvre
        vehicle = scenario.vehicle
        limit = vehicle.motor_torque_limit
        if manoeuvre.motor_torque is not None:
            left, right = manoeuvre.motor_torque
            return min(max(left, -limit), limit), min(max(right, -limit), limit)
        driver = scenario.driver
        p = vehicle.nominal
        speed_ref, accel_ref = manoeuvre.speed_reference(t)
        yaw_rate_ref = manoeuvre.yaw_rate_reference(t)
        speed_error = speed_ref - float(self._state[_VX])
        yaw_error = yaw_rate_ref - float(self._state[_R])
        speed_cmd = speed_ref + driver.speed_gain * speed_error + driver.speed_integral_gain * self._speed_integral
        yaw_rate_cmd = (
            yaw_rate_ref + driver.yaw_rate_gain * yaw_error + driver.yaw_rate_integral_gain * self._yaw_integral
        )
        half_track = 0.5 * p.track
        wheel_errors = (
            (speed_cmd - yaw_rate_cmd * half_track) / p.wheel_radius - float(self._state[_OMEGA_L]),
            (speed_cmd + yaw_rate_cmd * half_track) / p.wheel_radius - float(self._state[_OMEGA_R]),
        )
        effective_mass = p.mass + 2.0 * vehicle.side_inertia / p.wheel_radius**2
        resistance = vehicle.rolling_resistance * p.mass * p.gravity * math.tanh(speed_ref / 0.1)
        feed_forward = 0.5 * p.wheel_radius * (effective_mass * accel_ref + resistance)
        to_motor = 1.0 / (vehicle.transmission_efficiency * p.transmission_ratio)
        commands = [
            (feed_forward + driver.wheel_speed_gain * error + driver.wheel_speed_integral_gain * integral) * to_motor
            for error, integral in zip(wheel_errors, self._wheel_integral, strict=True)
        ]
        if all(abs(c) <= limit for c in commands):
            self._speed_integral += speed_error * self._period
            self._yaw_integral += yaw_error * self._period
            self._wheel_integral = [
                i + e * self._period for i, e in zip(self._wheel_integral, wheel_errors, strict=True)
            ]
        left, right = (min(max(c, -limit), limit) for c in commands)
        return left, right

    # --- sensors ------------------------------------------------------------

    def _quantised_position(self, state: Array) -> Array:
        motor_angle = self._ratio * state[_ANGLE_L : _ANGLE_R + 1]
        return np.floor(motor_angle / self._encoder_step) * self._encoder_step

    def _measure(self, state: Array, evaluation: _Evaluation) -> tuple[Array, float, float]:
        """Noise-free IMU (f_x, f_y, f_z, ω_x, ω_y, ω_z) in the tilted IMU frame, plus roll/pitch accelerations.

        The IMU sits on the sprung mass at the CM (height H_s). Road-frame
        specific force ``(f_x, f_y, g_n)`` (g_n: gravity normal to the ground,
        ``g cos γ`` on a grade) plus the lever-arm acceleration
        of the CM rotating about the roll/pitch axes, rotated into the body
        frame tilted by pitch θ then roll φ (ZYX Euler). Angular rate: ZYX
        Euler rates with ψ̇ = r.
        """
        roll, roll_rate, pitch, pitch_rate = state[_ROLL : _PITCH_RATE + 1].tolist()
        roll_accel = float(evaluation.derivative[_ROLL_RATE])
        pitch_accel = float(evaluation.derivative[_PITCH_RATE])
        r = float(state[_R])
        vehicle = self.scenario.vehicle
        d_r, d_p = vehicle.roll_arm, vehicle.pitch_arm
        cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
        road_x = evaluation.specific_force_x + d_p * (cp * pitch_accel - sp * pitch_rate**2)
        road_y = evaluation.specific_force_y - d_r * (cr * roll_accel - sr * roll_rate**2)
        road_z = (
            evaluation.normal_gravity
            - d_r * (sr * roll_accel + cr * roll_rate**2)
            - d_p * (sp * pitch_accel + cp * pitch_rate**2)
        )
        # R_y(θ)ᵀ then R_x(φ)ᵀ.
        px = cp * road_x - sp * road_z
        pz = sp * road_x + cp * road_z
        imu = np.array(
            (
                px,
                cr * road_y + sr * pz,
                -sr * road_y + cr * pz,
                roll_rate - sp * r,
                cr * pitch_rate + sr * cp * r,
                -sr * pitch_rate + cr * cp * r,
            )
        )
        return imu, roll_accel, pitch_accel

    def _delayed_position(self, t: float) -> Array:
        """Quantised motor angles (rad) the encoders counted ``wheel_speed_delay`` before ``t``.

        The true motor angle at t − d, linear between the sensor-rate samples of
        ``_angle_history`` (the newest at ``t``); before t = 0 extrapolated at the
        initial motor speed.
        """
        lag = self.scenario.effects.wheel_speed_delay / self._period
        history = self._angle_history
        newest = len(history) - 1
        back = newest - lag  # fractional index into history of t − d
        if back < 0.0:
            oldest_t = t - newest * self._period
            angle = history[0] + self._initial_motor_speed * (t - self.scenario.effects.wheel_speed_delay - oldest_t)
        else:
            i = int(math.floor(back))
            frac = back - i
            angle = history[i] if frac <= 1e-12 or i + 1 > newest else (1.0 - frac) * history[i] + frac * history[i + 1]
        return np.floor(np.asarray(angle) / self._encoder_step) * self._encoder_step

    def _delayed_imu(self, current: Array) -> Array:
        """IMU reading ``sensor_delay`` ago, linearly interpolated; the t = 0 reading before that."""
        self._imu_history.append(current)
        delay = self.scenario.effects.sensor_delay
        if delay == 0.0:
            return current
        lag = delay / self._period
        whole = int(math.floor(lag + 1e-9))
        frac = max(lag - whole, 0.0)
        needed = whole + (1 if frac > 1e-9 else 0)
        if needed > len(self._imu_history) - 1:
            return self._imu_history[0].copy()
        newer = self._imu_history[-1 - whole]
        if frac <= 1e-9:
            return newer.copy()
        older = self._imu_history[-2 - whole]
        return (1.0 - frac) * newer + frac * older

    # --- stepping -----------------------------------------------------------

    def step(self) -> SkidSteerSample:
        """Advance one sensor period and report the sensors and the truth at its end."""
        t0 = self._step_index * self._period
        torque = self._drive(t0)
        self._motor_torque = torque
        wheel_torque = (self._equations.drive_gain * torque[0], self._equations.drive_gain * torque[1])
        substeps = max(self._base_substeps, self._equations.stiff_substeps(self._state, self._period))
        self._last_substeps = substeps
        self._state, self._hold = _rk4(
            self._equations, self._state, wheel_torque, self._hold, self._period / substeps, substeps
        )
        self._step_index += 1
        t1 = self._step_index * self._period
        state = self._state
        evaluation = self._equations.evaluate(state, wheel_torque, self._hold)

        sensors = self.scenario.sensors
        effects = self.scenario.effects
        imu_true, _, _ = self._measure(state, evaluation)
        imu = self._delayed_imu(imu_true)
        accel = (
            (1.0 + np.asarray(effects.accel_scale)) * imu[:3]
            + np.asarray(effects.accel_bias)
            + sensors.accel_noise_std * self._accel_rng.standard_normal(3)
        )
        gyro_true = imu[3:].copy()
        gyro_true[2] *= 1.0 + effects.gyro_scale
        gyro = gyro_true + sensors.gyro_noise_std * self._gyro_rng.standard_normal(3)
        gyro[2] += effects.gyro_bias
        gyro[:2] += np.asarray(effects.gyro_bias_xy)

        if effects.wheel_speed_delay > 0.0:
            self._angle_history.append(self._ratio * state[_ANGLE_L : _ANGLE_R + 1].copy())
            position = self._delayed_position(t1)
        else:
            position = self._quantised_position(state)
        velocity = (position - self._previous_position) / self._period
        velocity = velocity + sensors.motor_velocity_noise_std * self._velocity_rng.standard_normal(2)
        self._previous_position = position
        effort = np.asarray(torque) + sensors.motor_effort_noise_std * self._effort_rng.standard_normal(2)

        gnss = None
        if self._gnss_every and self._step_index % self._gnss_every == 0:
            noise = self._gnss_rng.standard_normal(5)
            yaw = float(state[_YAW]) + sensors.gnss_yaw_noise_std * noise[4]
            gnss = GnssReading(
                t=t1,
                vx=float(state[_VX]) + sensors.gnss_velocity_noise_std * noise[0],
                vy=float(state[_VY]) + sensors.gnss_velocity_noise_std * noise[1],
                x=float(state[_X]) + sensors.gnss_position_noise_std * noise[2],
                y=float(state[_Y]) + sensors.gnss_position_noise_std * noise[3],
                yaw=math.atan2(math.sin(yaw), math.cos(yaw)),
            )
        return SkidSteerSample(
            t=t1,
            linear_acceleration=accel,
            angular_velocity=gyro,
            motor_position=position,
            motor_velocity=velocity,
            motor_effort=effort,
            gnss=gnss,
            truth=self._truth(t1, state, evaluation, torque),
        )

    def _truth(self, t: float, state: Array, evaluation: _Evaluation, torque: tuple[float, float]) -> SkidSteerTruth:
        p = self._equations.params
        vx, vy, r = float(state[_VX]), float(state[_VY]), float(state[_R])
        wheel_speed = state[_OMEGA_L : _OMEGA_R + 1].copy()
        half = 0.5 * p.track
        slip = side_slip_ratios(wheel_speed, np.array((vx - r * half, vx + r * half)), p)
        icr_x, icr_y, icr_valid = instantaneous_centre_of_rotation(vx, vy, r)
        manoeuvre = self.scenario.manoeuvre
        return SkidSteerTruth(
            vx=vx,
            vy=vy,
            yaw_rate=r,
            x=float(state[_X]),
            y=float(state[_Y]),
            yaw=float(state[_YAW]),
            body_sideslip=float(body_sideslip(vx, vy)),
            slip=slip,
            tire_sideslip=tire_sideslip_angles(evaluation.contact_vx, evaluation.contact_vy),
            icr_x=float(icr_x),
            icr_y=float(icr_y),
            icr_valid=bool(icr_valid),
            normal_load=evaluation.normal_load,
            tire_force_x=evaluation.tire_force_x.copy(),
            tire_force_y=evaluation.tire_force_y.copy(),
            steady_tire_force_x=evaluation.steady_tire_force_x,
            steady_tire_force_y=evaluation.steady_tire_force_y,
            motion_resistance=evaluation.motion_resistance,
            friction=evaluation.friction,
            specific_force_x=evaluation.specific_force_x,
            specific_force_y=evaluation.specific_force_y,
            roll=float(state[_ROLL]),
            pitch=float(state[_PITCH]),
            roll_rate=float(state[_ROLL_RATE]),
            pitch_rate=float(state[_PITCH_RATE]),
            wheel_speed=wheel_speed,
            motor_torque=np.asarray(torque, dtype=float),
            speed_reference=manoeuvre.speed_reference(t)[0] if manoeuvre.motor_torque is None else math.nan,
            yaw_rate_reference=manoeuvre.yaw_rate_reference(t) if manoeuvre.motor_torque is None else math.nan,
        )


def simulate_skid_steer(scenario: SkidSteerScenario, seed: int) -> SkidSteerSimulationResult:
    """Run a :class:`SkidSteerSimulator` to the end of the scenario and stack the samples.

    Args:
        scenario: the scenario (``run_duration`` rounded to whole sensor periods).
        seed: sensor-noise seed.

    Returns:
        Arrays of N = round(duration × sensor_rate) samples at t = period … duration.
    """
    simulator = SkidSteerSimulator(scenario, seed=seed)
    if simulator.done:
        raise ValueError(f"duration {scenario.run_duration} s is shorter than one sensor period")
    samples: list[SkidSteerSample] = []
    while not simulator.done:
        samples.append(simulator.step())

    readings = [sample.gnss for sample in samples if sample.gnss is not None]
    return SkidSteerSimulationResult(
        scenario=scenario,
        seed=seed,
        **{name: np.array([getattr(s, name) for s in samples]) for name in _STACKED},
        gnss=stack_fields(GnssReadings, readings, dtype=float),
        truth=stack_fields(SkidSteerTruth, [sample.truth for sample in samples]),
    )


#: Sample fields stacked as they are into a :class:`SkidSteerSimulationResult`.
_STACKED = ("t", "linear_acceleration", "angular_velocity", "motor_position", "motor_velocity", "motor_effort")
