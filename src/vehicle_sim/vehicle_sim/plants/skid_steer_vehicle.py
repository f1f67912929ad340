"""The skid-steered vehicle of the truth plant: its physical parameters, unmodelled effects and sensor models.

Configuration only (frozen dataclasses); the plant that runs them is
:mod:`vehicle_sim.plants.skid_steer` (module docstring: what the truth has
beyond the observer's model), its equations of motion
:mod:`vehicle_sim.plants.skid_steer_dynamics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any

from terrain_estimation.checks import (
    check_fields,
    check_finite,
    check_int_at_least,
    check_non_negative,
    check_positive,
    finite_tuple,
)
from terrain_estimation.models.skid_steer import SkidSteerParams
from vehicle_sim.plants.checks import changed_fields, without_noise
from vehicle_sim.plants.tire_laws import TIRE_LAWS, MagicFormulaTire

__all__ = ["TURNING_RESISTANCE_SPEED", "SkidSteerEffects", "SkidSteerSensors", "SkidSteerVehicle"]


TURNING_RESISTANCE_SPEED = 0.05
"""Lateral contact speed v_b (m/s) over which the soil's lateral resistance of the effect
``turning_resistance`` builds up (``tanh(v_y / v_b)``): a few centimetres per second, the lateral
slip speed at which a rut's shear resistance is mobilised (Janosi–Hanamoto shear deformation
K ≈ 1–5 cm over a contact passage of ≈ 0.5 s)."""


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
            check_positive(owner, name, getattr(self, name))
        for name in (
            "motor_inertia",
            "rolling_resistance",
            "unsprung_mass_per_wheel",
            "roll_damping",
            "pitch_damping",
            "roll_centre_height",
            "pitch_centre_height",
        ):
            check_non_negative(owner, name, getattr(self, name))
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
            object.__setattr__(self, name, finite_tuple(owner, name, getattr(self, name), size))
        if not all(-1.0 < v < 1.0 for v in self.accel_scale):
            raise ValueError(f"{owner}.accel_scale must lie in (−1, 1) per axis, got {self.accel_scale}")
        if not (math.isfinite(self.gyro_scale) and -1.0 < self.gyro_scale < 1.0):
            raise ValueError(f"{owner}.gyro_scale must be in (−1, 1), got {self.gyro_scale}")
        check_non_negative(owner, "wheel_speed_delay", self.wheel_speed_delay)
        check_non_negative(owner, "turning_resistance", self.turning_resistance)
        if not all(abs(v) < math.pi / 4.0 for v in self.terrain_slope):
            raise ValueError(f"{owner}.terrain_slope must be in (−π/4, π/4) rad per axis, got {self.terrain_slope}")
        object.__setattr__(self, "accel_bias", finite_tuple(owner, "accel_bias", self.accel_bias, 3))
        check_finite(owner, "gyro_bias", self.gyro_bias)
        check_non_negative(owner, "sensor_delay", self.sensor_delay)
        e = self.wheel_radius_error
        if not (math.isfinite(e) and -0.5 < e < 0.5):
            raise ValueError(f"{owner}.wheel_radius_error must be in (−0.5, 0.5), got {e}")
        check_positive(owner, "friction_change", self.friction_change)
        check_positive(owner, "cornering_stiffness_change", self.cornering_stiffness_change)
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
        return changed_fields(self, SkidSteerEffects())

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
        counts = "encoder_counts_per_revolution"
        check_fields(self, (f.name for f in fields(self) if f.name != counts), rule="non_negative")
        check_int_at_least("SkidSteerSensors", counts, self.encoder_counts_per_revolution, 1)

    @classmethod
    def noiseless(cls) -> SkidSteerSensors:
        """No noise anywhere (encoders still quantised)."""
        return without_noise(cls)
