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

State (26 values, SI units)
    pose ``x, y, yaw`` in the odom frame (the ground plane's axes on a slope);
    body-frame ``vx, vy, r``; wheel-side speeds ``ω_l, ω_r`` and wheel angles
    (rad); sprung-mass ``roll, roll rate, pitch, pitch rate``; lagged tire
    forces ``F_x`` (6) and ``F_y`` (6) (used only with tire relaxation; on a
    slope ``F_y`` starts holding the vehicle against it). Wheel order FL, ML,
    RL, FR, MR, RR.

Integration
    Classical fixed-step RK4; motor torques are held over the 10 ms sensor
    period (the drive controller runs at the sensor rate). The default step is
    2 ms (five per period), not 1 ms: the fastest mode of the truth plant is
    the wheel–tire torsional mode through the relaxation spring C_x/L_x,
    ≈ 7 Hz rolling and ≈ 18 Hz at standstill (ω Δt ≤ 0.23 at 2 ms), and
    halving the cost keeps the 45 s turn at ≈ 3 s of wall time. Measured
    against 0.25 ms steps on the three manoeuvres of B.11: with the truth
    effects |Δvx| ≤ 2e-6 m/s, |Δr| ≤ 2e-9 rad/s, |Δα| ≤ 2e-9 rad,
    |ΔF_z| ≤ 0.01 N; with the nominal physics (one-step load-transfer hold,
    below) |Δvx| ≤ 1e-6 m/s, |Δr| ≤ 3e-7 rad/s, |ΔF_z| ≤ 25 N (of ≈ 4900 N)
    right after a step in acceleration, zero in steady states. Starting from
    rest with large torques (slips saturating within milliseconds) the errors
    reach 3e-5 m/s in speed and 0.05 % in wheel speed for a moment; a 1 ms
    step (``SkidSteerScenario.integration_step``) cuts them twentyfold. With
    the magic-formula truth (12 s of each manoeuvre against 0.25 ms steps):
    |Δvx| ≤ 1.7e-5 m/s (from rest), |Δr| ≤ 2e-9 rad/s, |Δα| ≤ 3e-9 rad,
    |ΔF_z| ≤ 0.04 N; the torque step from rest 3e-5 m/s and 0.02 % in wheel
    speed.
    Without tire relaxation the slip equations become stiff at low rolling
    speed (the slip denominator V_r shrinks to ε = 0.05 m/s), so the number
    of steps of a period is raised until ``λ_max Δt ≤ 2`` for a bound
    λ_max ∝ 1/V_r of the fastest tire mode (RK4 is stable up to 2.78 on the
    negative real axis): ≈ 0.06 ms steps when starting from rest.

Algebraic loop
    Loads depend on the body acceleration, which depends on the tire forces,
    which depend on the loads. With tire relaxation the forces are states and
    the only loop left (loads → motion resistance → f_x) is linear: it is
    solved exactly at every stage. Without relaxation the load transfer uses
    the specific force of the first RK4 stage of the current step (that stage
    reuses the value of the previous step): a delay of at most one step, far
    below the 0.5 s roll/pitch periods and without effect in a steady state.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.models.skid_steer import (
    WHEEL_NAMES,
    SkidSteerParams,
    body_forces,
    body_sideslip,
    contact_velocities,
    instantaneous_centre_of_rotation,
    side_slip_ratios,
    theoretical_slips,
    tire_sideslip_angles,
    wheel_positions,
)
from vehicle_sim.plants.skid_steer_ground import GroundContact, SkidSteerGround, Surface, equal_spring_loads
from vehicle_sim.plants.tire_laws import TIRE_LAWS, MagicFormulaTire, MagicFormulaWheels, brush_forces

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

KMH = 1.0 / 3.6
"""One km/h in m/s."""

TURNING_RESISTANCE_SPEED = 0.05
"""Lateral contact speed v_b (m/s) over which the soil's lateral resistance of the effect
``turning_resistance`` builds up (``tanh(v_y / v_b)``): a few centimetres per second, the lateral
slip speed at which a rut's shear resistance is mobilised (Janosi–Hanamoto shear deformation
K ≈ 1–5 cm over a contact passage of ≈ 0.5 s)."""


def _check_finite(owner: str, name: str, value: float) -> None:
    if not math.isfinite(value):
        raise ValueError(f"{owner}.{name} must be finite, got {value}")


def _check_positive(owner: str, name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{owner}.{name} must be finite and > 0, got {value}")


def _check_non_negative(owner: str, name: str, value: float) -> None:
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"{owner}.{name} must be finite and ≥ 0, got {value}")


# ---------------------------------------------------------------------------
# Vehicle
# ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class SkidSteerVehicle:
    """The [SS] vehicle: Table 1 (``nominal``) plus the physics only the truth plant has.

    The paper gives neither inertias of the drive line nor suspension data; the
    defaults below are realistic values for a 3 t six-wheel UGV with rocker-arm
    suspension, chosen from first principles (not fitted to any result).

    Attributes:
        nominal: Table 1 parameters shared with the observer (MODELS.md B.2).
        wheel_inertia: rotational inertia of one wheel with tire and hub about
            its axle (kg·m²). A 0.75 m off-road wheel of ≈ 40 kg with most
            mass in the tread: ≈ 0.35 · 40 · 0.375² ≈ 2 kg·m².
        motor_inertia: rotor inertia of one side motor, motor side (kg·m²).
            ≈ 0.02 kg·m² for a 150–200 N·m permanent-magnet traction motor; it
            is reflected to the wheels multiplied by i_g² = 736, i.e. ≈ 14.7
            kg·m² per side, more than the three wheels together (3 × 2).
        transmission_efficiency: η, wheel torque = η i_g T_m in both power
            directions (a constant-factor loss model; gearbox + chain ≈ 0.9).
        motor_torque_limit: |T_m| limit at the motor shaft (N·m). 200 N·m
            gives 200 · 27.13 · 0.9 / 0.375 ≈ 13 kN of thrust per side, more
            than the friction limit μ m g / 2 ≈ 11.8 kN, as a skid-steer needs
            to turn on the spot.
        rolling_resistance: motion-resistance coefficient f_rr (force per unit
            normal load) of firm unpaved ground (0.02). The resistance
            ``f_rr F_z tanh(v_x / v_rr)`` acts at each contact against its
            longitudinal velocity; the tire thrust (brush F_x) must overcome it.
        rolling_resistance_speed: v_rr, smoothing speed of the resistance sign
            (m/s); keeps it continuous through standstill.
        unsprung_mass_per_wheel: wheel, hub and arm mass below the springs
            (kg). The sprung mass is ``m − 6 m_u``.
        roll_inertia: sprung-mass roll inertia about its own centre of mass
            (kg·m²). Scaled from the paper's I_z = 6390 kg·m² (minus the
            unsprung corner masses, ≈ 5280 kg·m² sprung) by the box ratio
            (W² + h²)/(L² + W²) with L = 4.7, W = 2.06, h = 1.2 m.
        pitch_inertia: sprung-mass pitch inertia about its own centre of mass
            (kg·m²), same scaling with (L² + h²)/(L² + W²).
        roll_centre_height: height of the roll axis above the ground (m).
            Lateral forces reach the sprung mass through the links at this
            height; their load transfer is instantaneous (geometric), the rest
            goes through the springs and lags. Rocker-arm suspensions pivot
            below the hub height: 0.25 m.
        pitch_centre_height: height of the pitch axis (m), 0.30 m likewise.
        roll_stiffness: suspension roll stiffness K_φ (N·m/rad); with the
            defaults the roll mode is 1.7 Hz with damping ratio 0.40.
        roll_damping: suspension roll damping C_φ (N·m·s/rad).
        pitch_stiffness: suspension pitch stiffness K_θ (N·m/rad); pitch mode
            1.6 Hz, damping ratio 0.40.
        pitch_damping: suspension pitch damping C_θ (N·m·s/rad).
        longitudinal_relaxation_length: L_x of the tire force lag (m), about
            the radius of a stiff off-road tire.
        lateral_relaxation_length: L_y (m); lateral relaxation lengths are
            typically 1–2 tire radii.
        relaxation_speed_floor: lowest speed in the lag rate V/L (m/s): the
            lag stays finite at standstill instead of freezing the forces.
        tire_law: ``"brush"`` (the paper's idealised law, MODELS.md B.4: the
            nominal model, default) or ``"magic_formula"`` (the plant's own
            tire, :mod:`vehicle_sim.plants.tire_laws`; :meth:`truth_default`).
        magic_formula: shape, load sensitivity and low-speed floor of the
            magic-formula tire; its stiffnesses at the nominal wheel load
            m g / 6 are ``nominal``'s C_x and C_α (with the effects' changes).
    """

    nominal: SkidSteerParams = field(default_factory=SkidSteerParams)
    wheel_inertia: float = 2.0
    motor_inertia: float = 0.02
    transmission_efficiency: float = 0.9
    motor_torque_limit: float = 200.0
    rolling_resistance: float = 0.02
    rolling_resistance_speed: float = 0.05
    unsprung_mass_per_wheel: float = 75.0
    roll_inertia: float = 1140.0
    pitch_inertia: float = 4720.0
    roll_centre_height: float = 0.25
    pitch_centre_height: float = 0.30
    roll_stiffness: float = 190.0e3
    roll_damping: float = 13.5e3
    pitch_stiffness: float = 520.0e3
    pitch_damping: float = 40.0e3
    longitudinal_relaxation_length: float = 0.3
    lateral_relaxation_length: float = 0.5
    relaxation_speed_floor: float = 0.3
    tire_law: str = "brush"
    magic_formula: MagicFormulaTire = field(default_factory=MagicFormulaTire)

    def __post_init__(self) -> None:
        owner = "SkidSteerVehicle"
        if not isinstance(self.nominal, SkidSteerParams):
            raise ValueError(f"{owner}.nominal must be a SkidSteerParams, got {self.nominal!r}")
        if self.tire_law not in TIRE_LAWS:
            raise ValueError(f"{owner}.tire_law must be one of {', '.join(TIRE_LAWS)}, got {self.tire_law!r}")
        if not isinstance(self.magic_formula, MagicFormulaTire):
            raise ValueError(f"{owner}.magic_formula must be a MagicFormulaTire, got {self.magic_formula!r}")
        for name in (
            "wheel_inertia",
            "motor_torque_limit",
            "rolling_resistance_speed",
            "roll_inertia",
            "pitch_inertia",
            "roll_stiffness",
            "pitch_stiffness",
            "longitudinal_relaxation_length",
            "lateral_relaxation_length",
            "relaxation_speed_floor",
        ):
            _check_positive(owner, name, getattr(self, name))
        for name in (
            "motor_inertia",
            "rolling_resistance",
            "unsprung_mass_per_wheel",
            "roll_damping",
            "pitch_damping",
            "roll_centre_height",
            "pitch_centre_height",
        ):
            _check_non_negative(owner, name, getattr(self, name))
        eta = self.transmission_efficiency
        if not (math.isfinite(eta) and 0.0 < eta <= 1.0):
            raise ValueError(f"{owner}.transmission_efficiency must be in (0, 1], got {eta}")
        if not self.sprung_mass > 0.0:
            raise ValueError(
                f"{owner}.unsprung_mass_per_wheel leaves no sprung mass: 6 × {self.unsprung_mass_per_wheel} kg "
                f"≥ mass {self.nominal.mass} kg"
            )
        if not self.sprung_cg_height > self.roll_centre_height:
            raise ValueError(
                f"{owner}.roll_centre_height must be below the sprung CM ({self.sprung_cg_height:.3f} m), "
                f"got {self.roll_centre_height}"
            )
        if not self.sprung_cg_height > self.pitch_centre_height:
            raise ValueError(
                f"{owner}.pitch_centre_height must be below the sprung CM ({self.sprung_cg_height:.3f} m), "
                f"got {self.pitch_centre_height}"
            )
        g = self.nominal.gravity
        if not self.roll_stiffness > self.sprung_mass * g * self.roll_arm:
            raise ValueError(
                f"{owner}.roll_stiffness must exceed the gravity de-stiffening m_s g (H_s − h_rc) = "
                f"{self.sprung_mass * g * self.roll_arm:.1f} N·m/rad, got {self.roll_stiffness}"
            )
        if not self.pitch_stiffness > self.sprung_mass * g * self.pitch_arm:
            raise ValueError(
                f"{owner}.pitch_stiffness must exceed the gravity de-stiffening m_s g (H_s − h_pc) = "
                f"{self.sprung_mass * g * self.pitch_arm:.1f} N·m/rad, got {self.pitch_stiffness}"
            )

    @classmethod
    def truth_default(cls, **changes: Any) -> SkidSteerVehicle:
        """The truth of the estimator tests: this vehicle on the plant's own magic-formula tire.

        Args:
            changes: other fields (as for the constructor).
        """
        return cls(**{"tire_law": "magic_formula", **changes})

    @property
    def nominal_wheel_load(self) -> float:
        """F_z0 = m g / 6 (N): the load at which the magic formula's stiffnesses are the datasheet's."""
        return self.nominal.mass * self.nominal.gravity / 6.0

    # --- derived masses and geometry --------------------------------------

    @property
    def unsprung_mass(self) -> float:
        """Total unsprung mass 6 m_u (kg)."""
        return 6.0 * self.unsprung_mass_per_wheel

    @property
    def sprung_mass(self) -> float:
        """m_s = m − 6 m_u (kg)."""
        return self.nominal.mass - self.unsprung_mass

    @property
    def sprung_cg_height(self) -> float:
        """H_s (m): keeps the whole vehicle's CM at Table 1's H, ``m H = m_s H_s + 6 m_u R``."""
        p = self.nominal
        return (p.mass * p.cg_height - self.unsprung_mass * p.wheel_radius) / self.sprung_mass

    @property
    def roll_arm(self) -> float:
        """H_s − h_rc (m)."""
        return self.sprung_cg_height - self.roll_centre_height

    @property
    def pitch_arm(self) -> float:
        """H_s − h_pc (m)."""
        return self.sprung_cg_height - self.pitch_centre_height

    @property
    def roll_axis_inertia(self) -> float:
        """Sprung roll inertia about the roll axis, I_xx + m_s (H_s − h_rc)² (kg·m²)."""
        return self.roll_inertia + self.sprung_mass * self.roll_arm**2

    @property
    def pitch_axis_inertia(self) -> float:
        """Sprung pitch inertia about the pitch axis, I_yy + m_s (H_s − h_pc)² (kg·m²)."""
        return self.pitch_inertia + self.sprung_mass * self.pitch_arm**2

    @property
    def side_inertia(self) -> float:
        """Inertia of one drive side at the wheel, 3 I_w + i_g² J_m (kg·m²)."""
        return 3.0 * self.wheel_inertia + self.nominal.transmission_ratio**2 * self.motor_inertia

    def _mode(self, stiffness: float, damping: float, arm: float, inertia: float) -> tuple[float, float]:
        k_eff = stiffness - self.sprung_mass * self.nominal.gravity * arm
        omega = math.sqrt(k_eff / inertia)
        return omega / (2.0 * math.pi), damping / (2.0 * inertia * omega)

    @property
    def roll_natural_frequency(self) -> float:
        """Undamped roll frequency √((K_φ − m_s g (H_s − h_rc)) / I_roll) / 2π (Hz)."""
        return self._mode(self.roll_stiffness, self.roll_damping, self.roll_arm, self.roll_axis_inertia)[0]

    @property
    def roll_damping_ratio(self) -> float:
        """ζ_φ = C_φ / (2 I_roll ω_φ)."""
        return self._mode(self.roll_stiffness, self.roll_damping, self.roll_arm, self.roll_axis_inertia)[1]

    @property
    def pitch_natural_frequency(self) -> float:
        """Undamped pitch frequency (Hz), as for roll."""
        return self._mode(self.pitch_stiffness, self.pitch_damping, self.pitch_arm, self.pitch_axis_inertia)[0]

    @property
    def pitch_damping_ratio(self) -> float:
        """ζ_θ = C_θ / (2 I_pitch ω_θ)."""
        return self._mode(self.pitch_stiffness, self.pitch_damping, self.pitch_arm, self.pitch_axis_inertia)[1]


# ---------------------------------------------------------------------------
# Effects (CONTRACT.md "Nominal model and effects")
# ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class SkidSteerEffects:
    """Unmodelled effects of the sim-to-real catalogue, each switchable, all off by default.

    The default instance (:meth:`nominal`) is the vehicle's nominal physics:
    quasi-static loads (B.5), instantaneous forces of the vehicle's tire law
    (the brush of B.4 for the nominal :class:`SkidSteerVehicle`), perfect
    sensors apart from noise. :meth:`truth_default` is the truth plant of the
    estimator test ([SS] ISSUE: "at least body roll/pitch load-transfer
    dynamics and tire force lag"), with :meth:`SkidSteerVehicle.truth_default`
    (the plant's own magic-formula tire). The tire law and the ground are not
    effects of the catalogue: they belong to the vehicle and the scenario.

    Attributes:
        load_transfer_dynamics: sprung-mass roll and pitch dynamics; the loads
            come from suspension forces and lag the accelerations, the IMU tilts
            with the body. Off: quasi-static loads, level IMU.
        tire_relaxation: first-order tire force lag
            ``dF/dt = (V/L)(F_ss − F)`` with V the larger of the tread speed
            R|ω| and the contact speed, floored (Pacejka ch. 7's relaxation
            length). Off: F = F_ss.
        gyro_bias: constant yaw-gyro bias (rad/s).
        accel_bias: constant accelerometer bias (x, y, z) (m/s²).
        sensor_delay: IMU latency (s); linear interpolation between samples.
        wheel_radius_error: true rolling radius = nominal · (1 + e).
        friction_change: true μ = nominal μ · factor.
        cornering_stiffness_change: true C_α = nominal C_α · factor.
        terrain_grade: road grade along the path (rad, > 0 uphill): every
            heading climbs by this angle (a helical ramp), so gravity has the
            component −g sin γ along the body x axis and g cos γ normal to the
            road. The pose stays in the road plane.
        gyro_bias_xy: constant roll- and pitch-gyro biases (x, y) (rad/s).
        accel_scale: accelerometer scale-factor errors (x, y, z): each axis
            reads (1 + s) × its true specific force (before the bias).
        gyro_scale: yaw-gyro scale-factor error s: it reads (1 + s) × r.
        wheel_speed_delay: latency of the wheel-encoder stream (s): the
            ``joint_states`` report stamped t carries the encoder counts of
            t − d (the motor angle at t − d, linear between integration
            steps, quantised to the encoder step), its velocity the difference
            of two such counts over the report period. Before t = 0 the angle
            is extrapolated at the initial speed (the vehicle was already
            moving at it). Relative to ``sensor_delay`` (the IMU stream) only
            the difference of the two is observable in a bag.
        terrain_slope: (grade, bank) (rad) of a plane fixed in the world, seen
            at the start heading: grade > 0 rises ahead, bank > 0 the left
            side up. The plane is :class:`~vehicle_sim.plants.skid_steer_ground.SkidSteerGround`
            with ``grade``, ``cross_slope`` (the vehicle starts at heading 0),
            so gravity in the body frame turns with the heading; on a scenario
            ground that is already inclined it is refused.
        turning_resistance: lateral soil resistance coefficient c_b (–) of
            deformable ground (skid-steer turning resistance): a wheel sliding
            sideways pushes soil aside (Bekker's bulldozing of the sunk tire's
            side wall) and shears the rut, a force
            ``F_b = −c_b F_z tanh(v_y / v_b)`` per wheel against its lateral
            contact velocity v_y (v_b = :data:`TURNING_RESISTANCE_SPEED`),
            on top of the tire force. In a skid-steer turn it is a resistive
            yaw moment Σ x_i F_b,i: the vehicle turns less for the same
            side-speed difference. c_b grows with sinkage: ≈ 0 on firm
            ground, 0.1–0.3 on loam and sand, up to ≈ 1 in deep snow or sand
            (Wong, *Theory of Ground Vehicles*, ch. 7: lateral resistance
            coefficients μ_t of tracks 0.5–0.9 on soils against 0.4–0.6 on
            firm ground).
    """

    load_transfer_dynamics: bool = False
    tire_relaxation: bool = False
    gyro_bias: float = 0.0
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sensor_delay: float = 0.0
    wheel_radius_error: float = 0.0
    friction_change: float = 1.0
    cornering_stiffness_change: float = 1.0
    terrain_grade: float = 0.0
    gyro_bias_xy: tuple[float, float] = (0.0, 0.0)
    accel_scale: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_scale: float = 0.0
    wheel_speed_delay: float = 0.0
    terrain_slope: tuple[float, float] = (0.0, 0.0)
    turning_resistance: float = 0.0

    def __post_init__(self) -> None:
        owner = "SkidSteerEffects"
        for name, size in (("gyro_bias_xy", 2), ("accel_scale", 3), ("terrain_slope", 2)):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != size or not all(math.isfinite(v) for v in values):
                raise ValueError(f"{owner}.{name} must be {size} finite values, got {getattr(self, name)}")
            object.__setattr__(self, name, values)
        if not all(-1.0 < v < 1.0 for v in self.accel_scale):
            raise ValueError(f"{owner}.accel_scale must lie in (−1, 1) per axis, got {self.accel_scale}")
        if not (math.isfinite(self.gyro_scale) and -1.0 < self.gyro_scale < 1.0):
            raise ValueError(f"{owner}.gyro_scale must be in (−1, 1), got {self.gyro_scale}")
        _check_non_negative(owner, "wheel_speed_delay", self.wheel_speed_delay)
        _check_non_negative(owner, "turning_resistance", self.turning_resistance)
        if not all(abs(v) < math.pi / 4.0 for v in self.terrain_slope):
            raise ValueError(f"{owner}.terrain_slope must be in (−π/4, π/4) rad per axis, got {self.terrain_slope}")
        bias = tuple(float(b) for b in self.accel_bias)
        if len(bias) != 3 or not all(math.isfinite(b) for b in bias):
            raise ValueError(f"{owner}.accel_bias must be 3 finite values (x, y, z), got {self.accel_bias}")
        object.__setattr__(self, "accel_bias", bias)
        _check_finite(owner, "gyro_bias", self.gyro_bias)
        _check_non_negative(owner, "sensor_delay", self.sensor_delay)
        e = self.wheel_radius_error
        if not (math.isfinite(e) and -0.5 < e < 0.5):
            raise ValueError(f"{owner}.wheel_radius_error must be in (−0.5, 0.5), got {e}")
        _check_positive(owner, "friction_change", self.friction_change)
        _check_positive(owner, "cornering_stiffness_change", self.cornering_stiffness_change)
        grade = self.terrain_grade
        if not (math.isfinite(grade) and abs(grade) < math.pi / 4.0):
            raise ValueError(f"{owner}.terrain_grade must be in (−π/4, π/4) rad, got {grade}")

    @classmethod
    def nominal(cls) -> SkidSteerEffects:
        """Everything off: the plant is the nominal model plus wheel dynamics and motion resistance."""
        return cls()

    @classmethod
    def truth_default(cls) -> SkidSteerEffects:
        """Truth for the estimator tests: roll/pitch load-transfer dynamics and tire relaxation on."""
        return cls(load_transfer_dynamics=True, tire_relaxation=True)

    @property
    def active(self) -> tuple[str, ...]:
        """Names of the effects that are switched on (differ from :meth:`nominal`)."""
        reference = SkidSteerEffects()
        return tuple(name for name in self.__dataclass_fields__ if getattr(self, name) != getattr(reference, name))

    def true_params(self, nominal: SkidSteerParams) -> SkidSteerParams:
        """The physical parameters the plant runs on: nominal with radius, μ and C_α changed."""
        return replace(
            nominal,
            wheel_radius=nominal.wheel_radius * (1.0 + self.wheel_radius_error),
            friction=nominal.friction * self.friction_change,
            cornering_stiffness=nominal.cornering_stiffness * self.cornering_stiffness_change,
        )


# ---------------------------------------------------------------------------
# Sensors
# ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class SkidSteerSensors:
    """Sensor models (CONTRACT.md "Skid-steer vehicle"); every noise is white Gaussian.

    Attributes:
        accel_noise_std: accelerometer noise σ per axis (m/s²); a MEMS IMU of
            ≈ 150 µg/√Hz sampled at 100 Hz with a 50 Hz bandwidth.
        gyro_noise_std: gyroscope noise σ per axis (rad/s) (≈ 0.01 °/s/√Hz).
        encoder_counts_per_revolution: motor encoder resolution; positions are
            quantised to 2π/N rad (motor side).
        motor_velocity_noise_std: noise σ on the drive's velocity report (rad/s,
            motor side), added to the differenced quantised position.
        motor_effort_noise_std: noise σ on the reported motor torque (N·m,
            motor side; current sensing).
        gnss_rate: RTK-GNSS reference rate (Hz); 0 disables it. Must divide
            the sensor rate.
        gnss_velocity_noise_std: σ on body-frame vx, vy (m/s).
        gnss_position_noise_std: σ on x, y (m).
        gnss_yaw_noise_std: σ on the dual-antenna heading (rad).
    """

    accel_noise_std: float = 0.05
    gyro_noise_std: float = 0.002
    encoder_counts_per_revolution: int = 4096
    motor_velocity_noise_std: float = 0.02
    motor_effort_noise_std: float = 0.5
    gnss_rate: float = 10.0
    gnss_velocity_noise_std: float = 0.02
    gnss_position_noise_std: float = 0.02
    gnss_yaw_noise_std: float = 0.005

    def __post_init__(self) -> None:
        owner = "SkidSteerSensors"
        for name in (
            "accel_noise_std",
            "gyro_noise_std",
            "motor_velocity_noise_std",
            "motor_effort_noise_std",
            "gnss_rate",
            "gnss_velocity_noise_std",
            "gnss_position_noise_std",
            "gnss_yaw_noise_std",
        ):
            _check_non_negative(owner, name, getattr(self, name))
        counts = self.encoder_counts_per_revolution
        if isinstance(counts, bool) or not isinstance(counts, int) or counts < 1:
            raise ValueError(f"{owner}.encoder_counts_per_revolution must be an integer ≥ 1, got {counts}")

    @classmethod
    def noiseless(cls) -> SkidSteerSensors:
        """No noise anywhere (encoders still quantised)."""
        return cls(
            accel_noise_std=0.0,
            gyro_noise_std=0.0,
            motor_velocity_noise_std=0.0,
            motor_effort_noise_std=0.0,
            gnss_velocity_noise_std=0.0,
            gnss_position_noise_std=0.0,
            gnss_yaw_noise_std=0.0,
        )


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
        for name in self.__dataclass_fields__:
            _check_non_negative("SkidSteerDriver", name, getattr(self, name))


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
        _check_positive(owner, "duration", self.duration)
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
        _check_finite(owner, "yaw_rate_amplitude", self.yaw_rate_amplitude)
        _check_positive(owner, "yaw_rate_period", self.yaw_rate_period)
        _check_finite(owner, "yaw_rate_sine_start", self.yaw_rate_sine_start)
        _check_finite(owner, "initial_speed", self.initial_speed)
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
class SkidSteerScenario:
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
            converged to ≤ 2e-7 rad/s in yaw rate, see the module docstring).
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
            _check_positive(owner, "duration", self.duration)
        _check_positive(owner, "sensor_rate", self.sensor_rate)
        _check_positive(owner, "integration_step", self.integration_step)
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
    def sensor_period(self) -> float:
        """1 / sensor_rate (s)."""
        return 1.0 / self.sensor_rate

    @property
    def substeps(self) -> int:
        """RK4 steps per sensor period at travel speed."""
        return max(1, math.ceil(self.sensor_period / self.integration_step - 1e-9))

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
# Equations of motion
# ---------------------------------------------------------------------------

_X, _Y, _YAW, _VX, _VY, _R = 0, 1, 2, 3, 4, 5
_OMEGA_L, _OMEGA_R, _ANGLE_L, _ANGLE_R = 6, 7, 8, 9
_ROLL, _ROLL_RATE, _PITCH, _PITCH_RATE = 10, 11, 12, 13
_FX = slice(14, 20)
_FY = slice(20, 26)
_N_STATES = 26

#: Largest λ_max Δt of the stiffness-limited step (RK4 is stable to 2.78).
_STIFF_STEP_LIMIT = 2.0
#: Most RK4 steps in one sensor period.
_MAX_SUBSTEPS = 400


@dataclass(frozen=True, slots=True)
class _Evaluation:
    """Intermediate quantities of one evaluation of the equations of motion."""

    derivative: Array
    normal_load: Array
    tire_force_x: Array
    tire_force_y: Array
    steady_tire_force_x: Array
    steady_tire_force_y: Array
    motion_resistance: Array
    friction: Array
    contact_vx: Array
    contact_vy: Array
    specific_force_x: float
    specific_force_y: float
    normal_gravity: float


def effective_ground(scenario: SkidSteerScenario) -> SkidSteerGround:
    """The scenario's ground with the effect ``terrain_slope`` (grade, bank at the start heading) applied.

    Raises:
        ValueError: the effect asks for a slope on a ground that is already inclined.
    """
    grade, bank = scenario.effects.terrain_slope
    if grade == 0.0 and bank == 0.0:
        return scenario.ground
    if not scenario.ground.level:
        raise ValueError(
            f"SkidSteerEffects.terrain_slope {scenario.effects.terrain_slope} on a ground already inclined "
            f"(grade {scenario.ground.grade}, cross_slope {scenario.ground.cross_slope}): give one of the two"
        )
    return replace(scenario.ground, grade=grade, cross_slope=bank)


class _EquationsOfMotion:
    """Planar 3-DOF body, wheel sides, sprung roll/pitch, tire lag (MODELS.md B.4–B.6 plus effects).

    ::

        m (v̇x − vy r) = Σ (F_x − F_rr) + m g_bx                (B.6, gravity, motion resistance)
        m (v̇y + vx r) = Σ F_y + m g_by
        I_z ṙ         = Σ x_i F_y − y_j (F_x − F_rr)
        I_side ω̇_j    = η i_g T_m,j − R Σ_i F_x,ij            (B.6 wheel-side dynamics)
        I_φ φ̈ = m_s f_y (H_s − h_rc) + m_s g_n (H_s − h_rc) sin φ − K_φ φ − C_φ φ̇
        I_θ θ̈ = −m_s f_x (H_s − h_pc) + m_s g_n (H_s − h_pc) sin θ − K_θ θ − C_θ θ̇
        Ḟ = (V/L)(F_ss − F),   V = max(R|ω|, |v_contact|, V_floor)       (relaxation)

    f = Σ ground forces / m is the specific force of the road frame; g_bx,
    g_by, g_n are gravity along body x, y and normal to the ground
    (:class:`~vehicle_sim.plants.skid_steer_ground.GroundContact`: ``−g sin γ,
    0, g cos γ`` for the effect ``terrain_grade`` γ on a level plane). F, F_ss
    come from the vehicle's tire law with μ, stiffness scale and f_rr of the
    surface under each wheel. Loads:
    quasi-static (B.5) as ``F_z = F_z0 g_n/g + ∂F_z/∂a_x f_x + ∂F_z/∂a_y f_y``
    (the exact affine decomposition of the equal-spring loads), or, with
    load-transfer dynamics, the static loads plus the roll and pitch moments
    through the suspension springs/dampers (``∓(K φ + C φ̇)``), the links at the
    roll/pitch centres (``m_s f h_c``, instantaneous) and the unsprung masses
    (``m_u f R``), distributed like rigid-body equal-spring deflections: equal
    per axle laterally, linear in x_i longitudinally. In a steady state both
    give the same loads apart from the CM shift of the tilted body.
    """

    def __init__(self, scenario: SkidSteerScenario) -> None:
        vehicle, effects = scenario.vehicle, scenario.effects
        nominal = vehicle.nominal
        self.params = effects.true_params(nominal)
        p = self.params
        self.load_dynamics = effects.load_transfer_dynamics
        self.relaxation = effects.tire_relaxation
        self.magic_formula = vehicle.tire_law == "magic_formula"
        self.mass = p.mass
        self.yaw_inertia = p.yaw_inertia
        self.radius = p.wheel_radius
        self.gravity = p.gravity
        self.grade_accel = p.gravity * math.sin(effects.terrain_grade)
        self.normal_gravity = p.gravity * math.cos(effects.terrain_grade)
        self.drive_gain = vehicle.transmission_efficiency * p.transmission_ratio
        self.side_inertia = vehicle.side_inertia
        self.cx, self.ca, self.mu = p.longitudinal_stiffness, p.cornering_stiffness, p.friction
        self.rr, self.rr_speed = vehicle.rolling_resistance, vehicle.rolling_resistance_speed
        self.lx, self.ly = vehicle.longitudinal_relaxation_length, vehicle.lateral_relaxation_length
        self.relax_floor = vehicle.relaxation_speed_floor
        self.inverse_lx = 1.0 / vehicle.longitudinal_relaxation_length
        self.inverse_ly = 1.0 / vehicle.lateral_relaxation_length
        self.inverse_rr_speed = 1.0 / vehicle.rolling_resistance_speed

        # The kinematics (eqs. 3, 5) and the force sums (B.6) are linear: their matrices are taken from the shared
        # functions once (unit inputs), so the RK4 stage applies exactly contact_velocities and body_forces
        # at the cost of one matrix product each.
        identity = np.eye(3)
        unit_vx, unit_vy = contact_velocities(identity[0], identity[1], identity[2], p)
        self.contact_map = np.vstack((unit_vx.T, unit_vy.T))  # (12, 3): (vx, vy, r) → (v_x contact, v_y contact)
        unit = np.eye(12)
        self.force_map = np.vstack(body_forces(unit[:, :6], unit[:, 6:], p))  # (3, 12): (F_x, F_y) → (ΣF_x, ΣF_y, M_z)
        self.side_map = np.kron(np.eye(2), np.ones(3))  # (2, 6): per-wheel → per-side sums

        # Loads: exact affine decomposition of B.5 (the equal-spring loads are affine in g, a_x, a_y before the floor).
        cos_grade = math.cos(effects.terrain_grade)
        xw, yw = wheel_positions(nominal)

        def quasi_static_loads(f_x: float, f_y: float) -> Array:
            return equal_spring_loads(xw[:3], nominal.track, nominal.mass, nominal.gravity, nominal.cg_height, f_x, f_y)

        static = quasi_static_loads(0.0, 0.0)
        self.static_load = static * cos_grade
        self.static_load_per_gravity = static / nominal.gravity
        # Unit moment distributions: Σ u = 0, Σ y u_roll = 1, Σ x u_pitch = 1 (equal springs, rigid body).
        self.roll_unit = yw / float(np.sum(yw**2))
        x_dev = xw - xw.mean()
        self.pitch_unit = x_dev / float(np.sum(x_dev**2))
        self.roll_stiffness, self.roll_damping = vehicle.roll_stiffness, vehicle.roll_damping
        self.pitch_stiffness, self.pitch_damping = vehicle.pitch_stiffness, vehicle.pitch_damping
        m_s, m_u, radius = vehicle.sprung_mass, vehicle.unsprung_mass, nominal.wheel_radius
        # Load sensitivity to the specific force (N per m/s²): instantaneous parts of the load transfer.
        if self.load_dynamics:
            # Links at the roll/pitch centres and the unsprung masses at the wheel centres.
            self.load_per_fx = -(m_s * vehicle.pitch_centre_height + m_u * radius) * self.pitch_unit
            self.load_per_fy = -(m_s * vehicle.roll_centre_height + m_u * radius) * self.roll_unit
        else:
            self.load_per_fx = quasi_static_loads(1.0, 0.0) - static
            self.load_per_fy = quasi_static_loads(0.0, 1.0) - static
        self.roll_drive = m_s * vehicle.roll_arm
        self.pitch_drive = m_s * vehicle.pitch_arm
        self.roll_axis_inertia = vehicle.roll_axis_inertia
        self.pitch_axis_inertia = vehicle.pitch_axis_inertia

        # Ground: surfaces under the wheels (the vehicle's own unless patched) and gravity on the slope.
        base = Surface(name="vehicle", friction=self.mu, rolling_resistance=self.rr)
        self.ground = GroundContact(
            effective_ground(scenario), base, effects.friction_change, xw, yw, p.gravity, effects.terrain_grade
        )
        self.turning_resistance = effects.turning_resistance
        self.inverse_turning_speed = 1.0 / TURNING_RESISTANCE_SPEED
        self.gravity_x = -self.grade_accel
        # The tire law: the plant's magic formula (stiffnesses C_x, C_α at m g / 6) or the brush (B.4).
        self.tire = (
            MagicFormulaWheels(vehicle.magic_formula, vehicle.nominal_wheel_load, self.cx, self.ca, 6)
            if self.magic_formula
            else None
        )

        # Bound on the fastest tire mode without relaxation, times the slip denominator (1/s · m/s): the
        # brush's V_r, or the magic formula's V (its stiffnesses bounded for loads up to twice F_z0).
        half_track2 = (0.5 * p.track) ** 2
        x2 = float(np.sum(xw**2))
        cx, ca = self.cx, self.ca
        if self.tire is not None:
            cx, ca = vehicle.magic_formula.max_stiffnesses(
                vehicle.nominal_wheel_load, self.cx, self.ca, 2.0 * vehicle.nominal_wheel_load
            )
        cx, ca = cx * self.ground.max_stiffness_scale, ca * self.ground.max_stiffness_scale
        self.stiffness_times_speed = (
            3.0 * p.wheel_radius**2 * cx / self.side_inertia
            + 6.0 * (cx + ca) / p.mass
            + (6.0 * cx * half_track2 + ca * x2) / p.yaw_inertia
        )

    def derivative(
        self, state: Array, wheel_torque: tuple[float, float], hold: tuple[float, float]
    ) -> tuple[Array, float, float, tuple[Any, ...]]:
        """Derivative of the state (the RK4 stage function).

        Args:
            state: the 26 states.
            wheel_torque: η i_g T_m per side (N·m at the wheel), held over the step.
            hold: specific force (f_x, f_y) used by the load transfer without tire
                relaxation (m/s²); with relaxation the loop is solved exactly.

        Returns:
            ``(derivative, f_x, f_y, forces)`` with f the specific force of the
            road frame (m/s²) and ``forces`` = (F_z, F_x, F_y, F_x,ss, F_y,ss,
            F_rr, v_x contact, v_y contact), each (6,), then μ (scalar or (6,))
            and g_n (m/s²).
        """
        x, y, yaw, vx, vy, r, omega_l, omega_r, _, _, roll, roll_rate, pitch, pitch_rate = state[:14].tolist()
        cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
        ground = self.ground
        mu: Any = self.mu
        scale: Any = 1.0
        rr: Any = self.rr
        if not ground.uniform:
            mu, scale, rr = ground.surfaces(x, y, cos_yaw, sin_yaw)
        if ground.level:
            gravity_x, gravity_y, normal_gravity = self.gravity_x, 0.0, self.normal_gravity
            static_load = self.static_load
        else:
            gravity_x, gravity_y, normal_gravity = ground.gravity(cos_yaw, sin_yaw)
            static_load = self.static_load_per_gravity * normal_gravity
        contact = self.contact_map @ np.array((vx, vy, r))
        cvx, cvy = contact[:6], contact[6:]
        omega = np.array((omega_l, omega_l, omega_l, omega_r, omega_r, omega_r))
        if self.load_dynamics:
            # Suspension springs and dampers; the links and unsprung masses add the f-dependent part below.
            load = (
                static_load
                - self.roll_unit * (self.roll_stiffness * roll + self.roll_damping * roll_rate)
                + self.pitch_unit * (self.pitch_stiffness * pitch + self.pitch_damping * pitch_rate)
            )
        else:
            load = static_load
        resistance_per_load = rr * np.tanh(cvx * self.inverse_rr_speed)
        derivative = np.zeros(_N_STATES)
        if self.relaxation:
            # The tire forces are states: solve the loop loads → motion resistance → f_x exactly (linear).
            fx, fy = state[_FX], state[_FY]
            load = load + self.load_per_fy * (float(np.sum(fy)) / self.mass)
            load_f_x = (float(np.sum(fx)) - float(resistance_per_load @ load)) / (
                self.mass + float(resistance_per_load @ self.load_per_fx)
            )
            load = np.maximum(load + self.load_per_fx * load_f_x, 0.0)
            steady_fx, steady_fy = self._tire_forces(omega, cvx, cvy, load, mu, scale)
            speed = np.maximum(np.maximum(self.radius * np.abs(omega), np.hypot(cvx, cvy)), self.relax_floor)
            derivative[_FX] = speed * (steady_fx - fx) * self.inverse_lx
            derivative[_FY] = speed * (steady_fy - fy) * self.inverse_ly
        else:
            hold_fx, hold_fy = hold
            load = np.maximum(load + self.load_per_fx * hold_fx + self.load_per_fy * hold_fy, 0.0)
            steady_fx, steady_fy = self._tire_forces(omega, cvx, cvy, load, mu, scale)
            fx, fy = steady_fx, steady_fy
        resistance = resistance_per_load * load
        lateral = fy
        if self.turning_resistance > 0.0:
            # Lateral soil resistance (effect turning_resistance): against each wheel's lateral sliding, ∝ its load.
            lateral = fy - self.turning_resistance * load * np.tanh(cvy * self.inverse_turning_speed)
        sum_fx, sum_fy, yaw_moment = (self.force_map @ np.concatenate((fx - resistance, lateral))).tolist()
        f_x = sum_fx / self.mass
        f_y = sum_fy / self.mass
        thrust_l, thrust_r = (self.side_map @ fx).tolist()
        if ground.level:
            accel_x, accel_y = f_x - self.grade_accel + vy * r, f_y - vx * r
        else:
            accel_x, accel_y = f_x + gravity_x + vy * r, f_y + gravity_y - vx * r
        derivative[:10] = (
            vx * cos_yaw - vy * sin_yaw,
            vx * sin_yaw + vy * cos_yaw,
            r,
            accel_x,
            accel_y,
            yaw_moment / self.yaw_inertia,
            (wheel_torque[0] - self.radius * thrust_l) / self.side_inertia,
            (wheel_torque[1] - self.radius * thrust_r) / self.side_inertia,
            omega_l,
            omega_r,
        )
        if self.load_dynamics:
            gn = normal_gravity
            derivative[_ROLL : _PITCH_RATE + 1] = (
                roll_rate,
                (
                    self.roll_drive * (f_y + gn * math.sin(roll))
                    - self.roll_stiffness * roll
                    - self.roll_damping * roll_rate
                )
                / self.roll_axis_inertia,
                pitch_rate,
                (
                    self.pitch_drive * (gn * math.sin(pitch) - f_x)
                    - self.pitch_stiffness * pitch
                    - self.pitch_damping * pitch_rate
                )
                / self.pitch_axis_inertia,
            )
        return derivative, f_x, f_y, (load, fx, fy, steady_fx, steady_fy, resistance, cvx, cvy, mu, normal_gravity)

    def _tire_forces(
        self, omega: Array, cvx: Array, cvy: Array, load: Array, mu: Any, scale: Any
    ) -> tuple[Array, Array]:
        """Steady forces (F_x, F_y) of the vehicle's tire law per wheel (N); μ, scale scalars or per wheel."""
        if self.tire is not None:
            return self.tire.forces(self.radius * omega, cvx, cvy, load, mu, scale)
        sigma_x, sigma_y = theoretical_slips(omega, cvx, cvy, self.params)
        return brush_forces(
            sigma_x,
            sigma_y,
            load,
            longitudinal_stiffness=self.cx * scale,
            cornering_stiffness=self.ca * scale,
            friction=mu,
        )

    def evaluate(self, state: Array, wheel_torque: tuple[float, float], hold: tuple[float, float]) -> _Evaluation:
        """:meth:`derivative` with its intermediate forces named (for the sensors and the truth)."""
        derivative, f_x, f_y, forces = self.derivative(state, wheel_torque, hold)
        load, fx, fy, steady_fx, steady_fy, resistance, cvx, cvy, mu, normal_gravity = forces
        return _Evaluation(
            derivative=derivative,
            normal_load=load,
            tire_force_x=np.array(fx, dtype=float),
            tire_force_y=np.array(fy, dtype=float),
            steady_tire_force_x=steady_fx,
            steady_tire_force_y=steady_fy,
            motion_resistance=resistance,
            friction=np.broadcast_to(np.asarray(mu, dtype=float), (6,)).copy(),
            contact_vx=cvx.copy(),
            contact_vy=cvy.copy(),
            specific_force_x=f_x,
            specific_force_y=f_y,
            normal_gravity=float(normal_gravity),
        )

    def stiff_substeps(self, state: Array, period: float) -> int:
        """RK4 steps per period that keep λ_max Δt ≤ 2 for the instantaneous (unrelaxed) tire model.

        λ_max ≈ (3R²C_x/I_side + 6(C_x + C_α)/m + (6C_x B²/4 + C_α Σx_i²)/I_z) / V_r
        bounds the slip-stiffness eigenvalues (Gershgorin); V_r is the smallest
        side rolling speed, halved for the speed change within the period. For
        the magic formula V_r is its slip denominator max(|v_x|, V_low) at the
        slowest contact and C_x, C_α its largest stiffnesses (loads up to 2 F_z0,
        the stiffest surface).
        """
        if self.relaxation:
            return 1
        if self.tire is not None:
            # The magic formula's slip denominator: the contact speed, floored at V_low.
            contact_vx = self.contact_map[:6] @ state[_VX : _R + 1]
            floor = self.tire.tire.low_speed
            rolling = max(0.5 * float(np.min(np.abs(contact_vx))), floor)
        else:
            omega_min = min(abs(float(state[_OMEGA_L])), abs(float(state[_OMEGA_R])))
            rolling = max(0.5 * self.radius * omega_min, self.params.rolling_speed_floor)
        rate = self.stiffness_times_speed / rolling
        return min(_MAX_SUBSTEPS, math.ceil(rate * period / _STIFF_STEP_LIMIT))


def _rk4(
    equations: _EquationsOfMotion,
    state: Array,
    wheel_torque: tuple[float, float],
    hold: tuple[float, float],
    dt: float,
    steps: int,
) -> tuple[Array, tuple[float, float]]:
    """``steps`` classical RK4 steps of ``dt``; returns the state and the updated load-transfer hold."""
    half = 0.5 * dt
    sixth = dt / 6.0
    for _ in range(steps):
        k1, f_x, f_y, _ = equations.derivative(state, wheel_torque, hold)
        hold = (f_x, f_y)
        k2 = equations.derivative(state + half * k1, wheel_torque, hold)[0]
        k3 = equations.derivative(state + half * k2, wheel_torque, hold)[0]
        k4 = equations.derivative(state + dt * k3, wheel_torque, hold)[0]
        state = state + sixth * (k1 + 2.0 * (k2 + k3) + k4)
    return state, hold


# ---------------------------------------------------------------------------
# Simulator
# ---------------------------------------------------------------------------


class SkidSteerSimulator:
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

    # --- public state -------------------------------------------------------

    @property
    def t(self) -> float:
        """Current simulation time (s)."""
        return self._step_index * self._period

    @property
    def step_index(self) -> int:
        """Number of sensor periods simulated so far."""
        return self._step_index

    @property
    def done(self) -> bool:
        """True once the scenario's duration has been simulated."""
        return self._step_index >= self._n_samples

    @property
    def state(self) -> Array:
        """Copy of the 26 plant states (see module docstring)."""
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

    def stack(values: Sequence[Any]) -> Array:
        return np.array(values)

    truths = [sample.truth for sample in samples]
    truth = SkidSteerTruth(
        **{name: stack([getattr(tr, name) for tr in truths]) for name in SkidSteerTruth.__dataclass_fields__}
    )
    readings = [sample.gnss for sample in samples if sample.gnss is not None]
    gnss = GnssReadings(
        **{
            name: np.array([getattr(g, name) for g in readings], dtype=float)
            for name in GnssReading.__dataclass_fields__
        }
    )
    return SkidSteerSimulationResult(
        scenario=scenario,
        seed=seed,
        t=stack([s.t for s in samples]),
        linear_acceleration=stack([s.linear_acceleration for s in samples]),
        angular_velocity=stack([s.angular_velocity for s in samples]),
        motor_position=stack([s.motor_position for s in samples]),
        motor_velocity=stack([s.motor_velocity for s in samples]),
        motor_effort=stack([s.motor_effort for s in samples]),
        gnss=gnss,
        truth=truth,
    )
