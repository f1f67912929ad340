"""Estimators 1–3 of the rocker-bogie terrain-response paper: process and measurement models ([RB] IV-B–IV-D).

Setterfield & Ellery (MODELS.md C.5–C.6) run two unscented Kalman filters at
T_e = 0.2 s (5 Hz) on temporally averaged 50 Hz measurements:

* **Estimator 1** (:class:`GeneralEstimatorModel`, 22 states, eq. 43): wheel
  rates, resistive torques, body pitch and bogie angle with their rates and
  accelerations, body accelerations, the net effects of the wheel forces,
  forward speed and the three slips. Measurement y1 (eq. 62, 11 entries).
* **Estimators 2 and 3** (:class:`WheelForceModel`, 9 states, eq. 75): contact
  angles γ, normal loads W and drawbar pulls DP, all random walks. The
  measurement y2 = y3 (eqs. 78, 85) holds the contact angles derived from
  Estimator 1 (eq. 79) and the load-cell forces; Estimator 3 (single-axis
  cells) synthesises F_⊥ from Estimator 1's net forces (eqs. 86–88,
  :func:`synthesised_perpendicular_forces`).

The multibody kinematics come from :mod:`terrain_estimation.models.rover`
(7 planar coordinates ``g = [x0, z0, θ, q1, q2, q3, q4]`` = Φ entries 1, 3,
5, 7, 8, 9, 10). The paper's estimated configuration Φ̂ (eq. 44) is
``g = [0, 0, θ̂, q̂1, 0, 0, 0]`` and its generalised velocity (eqs. 45, 66)
``ġ = [ẋ^R cos θ, −ẋ^R sin θ, θ̇, q̇1, q̇2, q̇3, q̇4]`` (ż0^R = 0 assumed; −sin,
as eq. 66 prints and the pitch convention of eqs. 72–73 requires).

Wheel order of every per-wheel array: :data:`~terrain_estimation.models.rover.WHEELS`
= (rear, middle, front) = paper wheels 1, 2, 3.

**Accelerations (eqs. 55–58).** The paper solves each of the four rows of
eq. 32 (x0, z0, θ, q1) for its own acceleration with the other
accelerations taken at step k (a Jacobi sweep over H). Here the 4×4 block
``H_ff g̈_f = Q_f − H_fw q̈_w`` is solved at once: the fixed point of that
sweep, with no risk of the sweep diverging when the couplings H15, H17, H57
are strong. ``Q_f = [F_xfw, F_zfw, M_0fw, M_1fw] − J_ωᵀ τ_R − ∂V/∂g`` on the
free coordinates, the wheel accelerations q̈_w from eq. 49. Ḣ ġ and ∂T/∂g are
dropped, as in the paper. H, ∂V/∂g and J_ω are evaluated once per step at
the estimated configuration Φ̂ (the paper's choice, :class:`KinematicTerms`)
and held over the sigma points; :class:`GeneralInput` with ``terms=None``
evaluates them at every point instead (slower, for checks).

**Quasi-static net forces (deviation from eq. 59, ``quasi_static=True``).**
Eq. 59 makes M_0fw, M_1fw, F_xfw, F_zfw random walks. But a rover at
2 cm/s is in equilibrium to within ≈ 1e-3 of its weight: the net
generalised force Q_f = [F_xfw, F_zfw, M_0fw, M_1fw] − J_ωᵀ τ_R − ∂V/∂g
stays ≈ H g̈ ≈ 0 while its parts change. As the rover pitches by Δθ the
gravity moment changes by ∂²V/∂θ² Δθ (≈ 30 N·m/rad × 1e-3 rad per step on
rolling terrain), and a change of τ_R is met at once by the wheel forces.
A pure random walk must be loose enough to follow both (≈ 0.05 N·m per
step), which lets θ̈ jump by ≈ 0.04 rad/s² per step and makes θ̇ — the input
of every contact angle, eq. 79 — noisy by ≈ 1e-3 rad/s (0.02 rad of γ at
the front wheel's 0.35 m lever and 2 cm/s). With ``quasi_static`` the
process model moves the net forces with the gravity gradient,
M_f ← M_f + ∂(∂V/∂g_f)/∂(θ, q1) · Δ(θ, q1) (:attr:`KinematicTerms.gravity_stiffness`),
and couples the τ_R increments into them (:meth:`GeneralEstimatorModel.process_noise_factor`),
so the independent random walks of the net forces can be small
(:class:`GeneralProcessNoise`). ``quasi_static=False`` is eq. 59 as printed.

**ż0^R (addition).** Eq. 79 with ż0^R = 0 (eq. 45) is the paper's
contact angle; :func:`contact_angles_with_vertical_speed` estimates ż0^R
from the parabola through the three wheel centres (all on one path in the
plane) and removes most of the error δ of eqs. 90–91.

**Measurement noise (R) from Table IV (MODELS.md C.5).** Every entry is the
sensor σ of :class:`SensorNoise` propagated through the measurement's
construction, with the number of 50 Hz samples that were averaged, plus a
model-error floor (:class:`MeasurementErrorFloors`) added in quadrature:

* wheel rates (eq. 63): the difference of two single encoder readings over
  the step, ``σ = √2 σ_q / T_e`` (2.6e-6 rad/s);
* pitch (eq. 64): ``σ_a/(g √n)`` plus the floor for the body acceleration
  that eq. 64 ignores (default 1e-4 rad ≈ 1e-3 m/s² / g);
* bogie angle, accelerations, forward speed: ``σ/√n``;
* slips (eq. 68) and contact angles (eq. 79): first-order propagation of the
  velocimeter, pitch-rate, bogie-rate and encoder noises (or of Estimator 1's
  posterior covariance for γ) through the kinematics (:func:`propagate_covariance`);
* load cells: ``σ_F/√n``; the synthesised F_⊥ of Estimator 3: propagation of
  Estimator 1's covariance of M_1fw, F_xfw, θ, q1 and the load-cell noise
  through eqs. 86–88, plus a floor for the load-proportional split of eq. 88.

**Process noise (Q).** Random-walk standard deviations per step of
``step_s`` (0.2 s), sized to the change expected over one step of a rover
at 2 cm/s (4 mm of travel); :class:`GeneralProcessNoise` and
:class:`WheelForceProcessNoise` give each value and why. Q scales with
``dt / step_s`` for other step lengths (random walk).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike

from terrain_estimation.filters.base import Array
from terrain_estimation.models.rover import (
    N_COORDINATES,
    WHEELS,
    RoverParams,
    contact_angle_from_velocity,
    dynamics_terms,
    slip_from_motion,
    wheel_angular_velocity_jacobian,
    wheel_centre_jacobian,
    wheel_centres,
)

__all__ = [
    "GENERAL_MEASUREMENTS",
    "GENERAL_STATES",
    "WHEEL_FORCE_MEASUREMENTS",
    "WHEEL_FORCE_STATES",
    "GeneralIndex",
    "GeneralInput",
    "GeneralEstimatorModel",
    "GeneralProcessNoise",
    "KinematicTerms",
    "MeasurementErrorFloors",
    "SensorNoise",
    "WheelForceModel",
    "WheelForceProcessNoise",
    "configuration",
    "contact_angle_measurement",
    "general_measurement",
    "general_measurement_variances",
    "generalised_velocity",
    "initial_general_state",
    "initial_wheel_force_state",
    "kinematic_terms",
    "pitch_from_gravity",
    "propagate_covariance",
    "VerticalSpeedEstimate",
    "contact_angle_covariance",
    "contact_angles_with_vertical_speed",
    "path_tangent_angles",
    "slip_measurement",
    "slip_measurement_jacobian",
    "synthesised_perpendicular_forces",
    "wheel_force_measurement_variances",
]

_DEG: Final[float] = math.pi / 180.0

# Indices into g (models.rover.COORDINATES).
_X0, _Z0, _PITCH, _BOGIE = 0, 1, 2, 3
_FREE: Final[tuple[int, ...]] = (0, 1, 2, 3)
_WHEEL_COORDS: Final[tuple[int, ...]] = (4, 5, 6)


def _per_wheel(prefix: str) -> tuple[str, str, str]:
    return (f"{prefix}_{WHEELS[0]}", f"{prefix}_{WHEELS[1]}", f"{prefix}_{WHEELS[2]}")


#: Estimator 1 state x1 (eq. 43), in order.
GENERAL_STATES: Final[tuple[str, ...]] = (
    *_per_wheel("wheel_rate"),  # q̇2, q̇3, q̇4 (rad/s), joint rates relative to the carrier
    *_per_wheel("resistive_torque"),  # τ_R1..3 (N·m)
    "pitch",  # θ0y (rad), positive nose down
    "bogie_angle",  # q1 (rad)
    "pitch_rate",  # θ̇0y (rad/s)
    "bogie_rate",  # q̇1 (rad/s)
    "pitch_acceleration",  # θ̈0y (rad/s²)
    "bogie_acceleration",  # q̈1 (rad/s²)
    "x_acceleration",  # ẍ0, world (m/s²)
    "z_acceleration",  # z̈0, world (m/s²)
    "body_moment",  # M_0fw: moment of the wheel linear forces about O (N·m)
    "bogie_moment",  # M_1fw: their moment about the bogie joint (N·m)
    "wheel_force_x",  # F_xfw: their world-horizontal sum (N)
    "wheel_force_z",  # F_zfw: their world-vertical sum (N)
    "forward_speed",  # ẋ0^R, along the body x axis (m/s)
    *_per_wheel("slip"),  # i1..3 (–)
)

#: Estimator 1 measurement y1 (eq. 62), in order.
GENERAL_MEASUREMENTS: Final[tuple[str, ...]] = (
    *_per_wheel("wheel_rate"),  # eq. 63, finite difference of encoder angles
    "pitch",  # eq. 64, from the gravity direction
    "bogie_angle",
    "specific_force_x",  # ẍ0^R of eq. 72 (accelerometer, gravity included)
    "specific_force_z",  # z̈0^R of eq. 73
    "forward_speed",  # velocimeter
    *_per_wheel("slip"),  # eq. 68
)

#: Estimators 2/3 state x2 = x3 (eq. 75), in order.
WHEEL_FORCE_STATES: Final[tuple[str, ...]] = (
    *_per_wheel("contact_angle"),  # γ (rad) w.r.t. the world horizontal, positive descending forward
    *_per_wheel("normal_load"),  # W (N)
    *_per_wheel("drawbar_pull"),  # DP (N)
)

#: Estimators 2/3 measurement y2 = y3 (eqs. 78, 85), in order.
WHEEL_FORCE_MEASUREMENTS: Final[tuple[str, ...]] = (
    *_per_wheel("contact_angle"),  # eq. 79
    *_per_wheel("axial_force"),  # F_L, load-cell sensing axis
    *_per_wheel("perpendicular_force"),  # F_⊥, measured (E2) or synthesised (E3, eqs. 86–88)
)


class GeneralIndex:
    """Indices into the Estimator 1 state x1 (:data:`GENERAL_STATES`)."""

    WHEEL_RATE: Final = slice(0, 3)
    RESISTIVE_TORQUE: Final = slice(3, 6)
    PITCH: Final = 6
    BOGIE: Final = 7
    PITCH_RATE: Final = 8
    BOGIE_RATE: Final = 9
    PITCH_ACC: Final = 10
    BOGIE_ACC: Final = 11
    X_ACC: Final = 12
    Z_ACC: Final = 13
    BODY_MOMENT: Final = 14
    BOGIE_MOMENT: Final = 15
    FORCE_X: Final = 16
    FORCE_Z: Final = 17
    FORWARD_SPEED: Final = 18
    SLIP: Final = slice(19, 22)
    #: Accelerations of the free coordinates (x0, z0, θ, q1), in g order.
    FREE_ACC: Final[tuple[int, ...]] = (12, 13, 10, 11)
    #: Net wheel-force effects on the free coordinates (x0, z0, θ, q1), in g order.
    FREE_FORCE: Final[tuple[int, ...]] = (16, 17, 14, 15)


_G = GeneralIndex


# ---------------------------------------------------------------------------
# Noise parameters
# ---------------------------------------------------------------------------


def _check_fields(obj: Any, *, strictly_positive: bool) -> None:
    for f in fields(obj):
        value = getattr(obj, f.name)
        ok = (
            isinstance(value, int | float)
            and math.isfinite(value)
            and (value > 0.0 or (not strictly_positive and value == 0.0))
        )
        if not ok:
            bound = "> 0" if strictly_positive else "≥ 0"
            raise ValueError(f"{type(obj).__name__}.{f.name} must be finite and {bound}, got {value!r}")


@dataclass(frozen=True, kw_only=True)
class SensorNoise:
    """Standard deviations of one 50 Hz sample of each sensor, [RB] Table IV in SI units.

    Table IV's encoder and ADC values are one least-significant step / 6.

    Attributes:
        bogie_angle: q̌1, 16-bit absolute encoder: 9.155e-4° (rad).
        pitch_rate: IMU pitch rate: 0.56 °/s (rad/s).
        forward_speed: optic-flow velocimeter: 1 mm/s (m/s).
        acceleration: IMU accelerations ẍ0^R, z̈0^R: 1.245e-3 m/s² (printed "m²/s").
        wheel_angle: q̌2..q̌4, 500 count/turn quadrature, 1400:1: 2.143e-5° (rad).
        load_cell: F_L and F_⊥, 200 N full scale, 10-bit ADC: 3.255e-2 N.
    """

    bogie_angle: float = 9.155e-4 * _DEG
    pitch_rate: float = 0.56 * _DEG
    forward_speed: float = 1.0e-3
    acceleration: float = 1.245e-3
    wheel_angle: float = 2.143e-5 * _DEG
    load_cell: float = 3.255e-2

    def __post_init__(self) -> None:
        _check_fields(self, strictly_positive=True)


@dataclass(frozen=True, kw_only=True)
class MeasurementErrorFloors:
    """Model-error standard deviations added in quadrature to the propagated sensor noise.

    They stand for what the measurement models leave out, not for sensor
    noise; 0 trusts the model exactly.

    Attributes:
        wheel_rate: eq. 63 (rad/s). Default 0: the encoder difference is the
            exact mean rate over the step.
        pitch: eq. 64 ignores the body acceleration, which tilts the measured
            gravity direction by ≈ ẍ/g (rad). Default 1e-4 rad = 1e-3 m/s².
        bogie_angle: (rad), default 0.
        specific_force: eqs. 72–73 leave out the IMU's offset from O and the
            centripetal terms (m/s²); default 2e-4 m/s².
        forward_speed: (m/s), default 0.
        slip: eq. 68 assumes ż0^R = 0 (m/s of wheel-centre speed error is
            δv/(r ω) of slip); default 0.005.
        contact_angle: what eq. 79 leaves of the error δ ≈ −ż0^R/ẋ0^R
            (eqs. 90–91; rad): with ż0^R from the wheel-centre path
            (:func:`contact_angles_with_vertical_speed`) the path's terms
            beyond the quartic, ≈ 0.004–0.009 rad on gently rolling terrain;
            with ż0^R = 0 all of δ (0.007–0.035 rad on the simulated
            terrains 1–3). Default 0.005 rad.
        load_cell: (N), default 0.
        synthesised_force: eq. 88 splits F_⊥12 in proportion to the loads,
            which DP does not follow (N); default 0.3 N.
    """

    wheel_rate: float = 0.0
    pitch: float = 1.0e-4
    bogie_angle: float = 0.0
    specific_force: float = 2.0e-4
    forward_speed: float = 0.0
    slip: float = 0.005
    contact_angle: float = 0.005
    load_cell: float = 0.0
    synthesised_force: float = 0.3

    def __post_init__(self) -> None:
        _check_fields(self, strictly_positive=False)


@dataclass(frozen=True, kw_only=True)
class GeneralProcessNoise:
    """Estimator 1 process noise: random-walk σ per step of ``step_s`` (0.2 s), per state group.

    Sized to the change over one step of a rover at 2 cm/s (4 mm of travel,
    MODELS.md C.5):

    Attributes:
        wheel_rate: eq. 49 with the step's mean torque; covers the mismatch
            of the Euler step and the averaged input: 5e-3 N·m of torque over
            0.2 s on I_wg = 1.082 kg·m² is 1e-3 rad/s.
        resistive_torque: eq. 50, τ_R follows W and i: ∂τ_R/∂W ≈ 0.03 m times
            ≈ 0.3 N of load change per step, plus slip changes; 0.01 N·m.
        pitch, bogie_angle: eqs. 51–52 are exact to the third derivative;
            1e-5 rad.
        pitch_rate, bogie_rate: eqs. 53–54; 1e-4 rad/s.
        pitch_acceleration, bogie_acceleration: on top of eqs. 55–56 (Ḣ ġ and
            ∂T/∂g dropped); 1e-3 rad/s².
        x_acceleration, z_acceleration: on top of eqs. 57–58; 1e-3 m/s².
        body_moment: M_0fw random walk (eq. 59) beyond the quasi-static
            model (module docstring): the change of H g̈ and of the dropped
            Ḣ ġ over a step, ≪ 1e-3 N·m, and the error of the gravity moment
            at the estimated configuration; 0.005 N·m. With the paper's pure
            random walk (``quasi_static=False``) use ≈ 0.05 N·m: the wheel
            loads shift by ≈ 0.3 N per step at 0.35 m lever arms.
        bogie_moment: M_1fw likewise; 0.003 N·m (≈ 0.03 N·m without the
            quasi-static model).
        wheel_force_x, wheel_force_z: F_xfw, F_zfw random walks: the change
            of the total mass times the body acceleration; 0.02 N.
        forward_speed: on top of eq. 60; 1e-4 m/s.
        slip: eq. 61; 0.005 per step. The window-mean slip of the simulated
            rover changes by ≈ 1.1e-3 per step on terrain 1 (RMS), with slow
            swings of several hundredths that a smaller σ lags; 0.02 (the
            default until issue 21) made the published slip σ ≈ 0.035
            against an RMS error of 0.008. The slip channels' R is matched
            to the innovations (:mod:`terrain_estimation.estimators.rover_noise`).
    """

    wheel_rate: float = 1.0e-3
    resistive_torque: float = 0.01
    pitch: float = 1.0e-5
    bogie_angle: float = 1.0e-5
    pitch_rate: float = 1.0e-4
    bogie_rate: float = 1.0e-4
    pitch_acceleration: float = 1.0e-3
    bogie_acceleration: float = 1.0e-3
    x_acceleration: float = 1.0e-3
    z_acceleration: float = 1.0e-3
    body_moment: float = 0.005
    bogie_moment: float = 0.003
    wheel_force_x: float = 0.02
    wheel_force_z: float = 0.02
    forward_speed: float = 1.0e-4
    slip: float = 0.005

    def __post_init__(self) -> None:
        _check_fields(self, strictly_positive=False)

    def sigma(self) -> Array:
        """σ per state of x1 (:data:`GENERAL_STATES` order), shape (22,)."""
        return np.array(
            [self.wheel_rate] * 3
            + [self.resistive_torque] * 3
            + [
                self.pitch,
                self.bogie_angle,
                self.pitch_rate,
                self.bogie_rate,
                self.pitch_acceleration,
                self.bogie_acceleration,
                self.x_acceleration,
                self.z_acceleration,
                self.body_moment,
                self.bogie_moment,
                self.wheel_force_x,
                self.wheel_force_z,
                self.forward_speed,
            ]
            + [self.slip] * 3
        )


@dataclass(frozen=True, kw_only=True)
class WheelForceProcessNoise:
    """Estimators 2/3 process noise: random-walk σ per step of ``step_s`` (eqs. 77, 84).

    Attributes:
        contact_angle: terrain angle change over 4 mm of travel at curvature
            κ ≤ 1/l_w = 1.43 m⁻¹ is ≤ 5.7e-3 rad; default 8e-3 rad: γ̌ is
            already a filtered quantity (Estimator 1's posterior), and on the
            simulated terrain 1 (κ up to 0.9 m⁻¹) 2e-3 lagged the rear wheel's
            γ by 0.02 rad RMS (DP error 1.3 N), 4e-3 by 0.014, 8e-3 by 0.011.
        normal_load: the window-mean W moves by ≈ 0.04–0.05 N per step (RMS)
            on the simulated terrain 1, and the cells, which see W and DP
            rotated by γ − ε, see a further W Δγ ≈ 50 N × 1.6e-3 rad ≈ 0.08 N
            per step as the terrain angle changes: a W/DP random walk smaller
            than that forces the cells' changes onto γ (measured on terrain 1:
            0.07 N gave the rear wheel DP errors of 1.2 N against 0.67 N at
            0.15 N). Default 0.15 N; the 0.3 N of the defaults before issue 21
            made the load-cell innovations far smaller than predicted. At steps
            (terrains 4–6) the innovation matching of
            :mod:`terrain_estimation.estimators.rover_noise` opens it.
        drawbar_pull: likewise (≈ 0.04 N per step on terrain 1, and the same
            rotation); default 0.15 N.
    """

    contact_angle: float = 8.0e-3
    normal_load: float = 0.15
    drawbar_pull: float = 0.15

    def __post_init__(self) -> None:
        _check_fields(self, strictly_positive=False)

    def sigma(self) -> Array:
        """σ per state of x2 (:data:`WHEEL_FORCE_STATES` order), shape (9,)."""
        return np.repeat([self.contact_angle, self.normal_load, self.drawbar_pull], 3).astype(float)


# ---------------------------------------------------------------------------
# Kinematics of the estimated configuration (eqs. 44–45, 65–67, 79)
# ---------------------------------------------------------------------------


def configuration(pitch: float, bogie_angle: float) -> Array:
    """Estimated/measured configuration Φ̂ (eqs. 44, 65) as g = [0, 0, θ, q1, 0, 0, 0], shape (7,)."""
    g = np.zeros(N_COORDINATES)
    g[_PITCH] = pitch
    g[_BOGIE] = bogie_angle
    return g


def generalised_velocity(
    pitch: float,
    forward_speed: float,
    pitch_rate: float,
    bogie_rate: float,
    wheel_rates: ArrayLike = (0.0, 0.0, 0.0),
    vertical_speed: float = 0.0,
) -> Array:
    """Φ̂̇ (eqs. 45, 66) as ġ = [ẋ0, ż0, θ̇, q̇1, q̇2, q̇3, q̇4], shape (7,).

    ẋ0 = ẋ^R cos θ + ż^R sin θ, ż0 = −ẋ^R sin θ + ż^R cos θ; the paper assumes
    ż0^R = 0 (``vertical_speed``, its gently-rolling-terrain condition).
    """
    g_dot = np.zeros(N_COORDINATES)
    c, s = math.cos(pitch), math.sin(pitch)
    g_dot[_X0] = forward_speed * c + vertical_speed * s
    g_dot[_Z0] = -forward_speed * s + vertical_speed * c
    g_dot[_PITCH] = pitch_rate
    g_dot[_BOGIE] = bogie_rate
    g_dot[list(_WHEEL_COORDS)] = np.asarray(wheel_rates, dtype=float)
    return g_dot


def pitch_from_gravity(specific_force_x: float, specific_force_z: float) -> float:
    """θ̌0y = atan(−f_x / f_z), the pitch from the measured gravity direction (eq. 64) (rad)."""
    return math.atan2(-specific_force_x, specific_force_z)


def _rate_map(pitch: float) -> Array:
    """A with ġ = A [ẋ^R, θ̇, q̇1, q̇2, q̇3, q̇4] (eqs. 45, 66), shape (7, 6)."""
    A = np.zeros((N_COORDINATES, 6))
    A[_X0, 0] = math.cos(pitch)
    A[_Z0, 0] = -math.sin(pitch)
    A[_PITCH, 1] = 1.0
    A[_BOGIE, 2] = 1.0
    A[4:, 3:] = np.eye(3)
    return A


def slip_measurement(
    params: RoverParams,
    pitch: float,
    bogie_angle: float,
    forward_speed: float,
    pitch_rate: float,
    bogie_rate: float,
    wheel_rates: ArrayLike,
    *,
    absolute_spin: bool = True,
) -> Array:
    """Measured slips ǐ (eqs. 65–68), shape (3,).

    The wheel-centre velocities are J_a(Φ̌) Φ̌̇ (eq. 67); each wheel's speed is
    ``sgn(v_x) |v|`` (eq. 68) and the slip follows eqs. 1–2
    (:func:`~terrain_estimation.models.rover.slip_from_motion`).

    Args:
        absolute_spin: use the wheel's absolute spin θ̇ + q̇1 + q̇_j (θ̇ + q̇4 for
            the front wheel), the rate that rolls the wheel over the ground
            (the plant's definition of slip). False: the joint rate q̇_j alone,
            as eq. 68 prints; the two differ by θ̇ + q̇1, ≈ 2 % of q̇_j on
            rolling terrain at 2 cm/s (θ̇ ≈ 5e-3 rad/s against q̇ ≈ 0.3 rad/s).
    """
    rates = np.asarray(wheel_rates, dtype=float)
    inputs = np.array([forward_speed, pitch_rate, bogie_rate, *rates])
    return slip_measurement_jacobian(params, pitch, bogie_angle, inputs, absolute_spin=absolute_spin)[0]


def slip_measurement_jacobian(
    params: RoverParams, pitch: float, bogie_angle: float, inputs: ArrayLike, *, absolute_spin: bool = True
) -> tuple[Array, Array]:
    """Slips ǐ (eq. 68) and their Jacobian w.r.t. ``inputs`` = [ẋ^R, θ̇, q̇1, q̇2, q̇3, q̇4], shapes (3,), (3, 6).

    Given the configuration the wheel-centre velocities and spins are linear
    in the rates, so the Jacobian is exact (first order in eqs. 1–2); it is 0
    for a clipped slip (|i| = 1).
    """
    g = configuration(pitch, bogie_angle)
    A = _rate_map(pitch)
    u = np.asarray(inputs, dtype=float)
    jv = wheel_centre_jacobian(params, g) @ A  # (3, 2, 6): d v_j / d inputs
    v = jv @ u
    norm = np.hypot(v[:, 0], v[:, 1])
    sign = np.where(v[:, 0] < 0.0, -1.0, 1.0)
    speed = sign * norm
    safe = np.where(norm > 0.0, norm, 1.0)
    d_speed = sign[:, None] * np.einsum("ja,jak->jk", v / safe[:, None], jv)
    if absolute_spin:
        d_spin = wheel_angular_velocity_jacobian(params, g) @ A
    else:
        d_spin = np.zeros((3, 6))
        d_spin[:, 3:] = np.eye(3)
    spin = d_spin @ u
    r = params.wheel_radius
    slip = slip_from_motion(spin, speed, r)
    rim = r * spin
    slipping = np.abs(rim) >= np.abs(speed)
    rim_safe = np.where(rim != 0.0, rim, 1.0)
    speed_safe = np.where(speed != 0.0, speed, 1.0)
    # eq. 1: i = 1 − s/(r ω);  eq. 2: i = r ω/s − 1.
    di_ds = np.where(slipping, -1.0 / rim_safe, -rim / speed_safe**2)
    di_dw = np.where(slipping, r * speed / rim_safe**2, r / speed_safe)
    active = (np.abs(slip) < 1.0) & (norm > 0.0) & (rim != 0.0)
    jac = np.where(active[:, None], di_ds[:, None] * d_speed + di_dw[:, None] * d_spin, 0.0)
    return slip, jac


def contact_angle_measurement(
    params: RoverParams,
    pitch: float,
    bogie_angle: float,
    forward_speed: float,
    pitch_rate: float,
    bogie_rate: float,
    vertical_speed: float = 0.0,
    sinkage_rate: ArrayLike | None = None,
) -> Array:
    """Contact angles γ̌ = atan(−v_z/v_x) of the wheel-centre velocities J_a(Φ̂) Φ̂̇ (eq. 79) (rad), shape (3,).

    ``vertical_speed`` is ż0^R (0 in the paper; see :func:`contact_angles_with_vertical_speed`).
    ``sinkage_rate``: ṡ_j of each wheel sinking into the soil (m/s, world
    vertical, positive deeper); the path the soil forces act along is the
    centre's velocity with ṡ_j added back to its v_z (None: 0, no sinkage).
    """
    g = configuration(pitch, bogie_angle)
    g_dot = generalised_velocity(pitch, forward_speed, pitch_rate, bogie_rate, vertical_speed=vertical_speed)
    v = wheel_centre_jacobian(params, g) @ g_dot
    if sinkage_rate is not None:
        v = v.copy()
        v[:, 1] += np.asarray(sinkage_rate, dtype=float)
    return contact_angle_from_velocity(v)


def _contact_angle_jacobian(
    params: RoverParams, inputs: Array, angle_step: float, sinkage_rate: Array | None = None
) -> tuple[Array, Array]:
    """γ̌ (eq. 79) and dγ̌/d inputs for inputs = [θ, q1, ẋ^R, θ̇, q̇1(, ż^R)], shapes (3,), (3, n).

    ``sinkage_rate``: ṡ_j (m/s) added back to each centre's v_z (:func:`contact_angle_measurement`).
    """
    n = inputs.size
    sink_rate = np.zeros(3) if sinkage_rate is None else np.asarray(sinkage_rate, dtype=float)
    if n not in (5, 6):
        raise ValueError(f"inputs must be [θ, q1, ẋ^R, θ̇, q̇1] or with ż^R appended, got {n} values")
    pitch, bogie = float(inputs[0]), float(inputs[1])
    rates = np.concatenate([inputs[2:5], np.zeros(3), inputs[5:6]])  # [ẋ^R, θ̇, q̇1, q̇2..4 = 0, (ż^R)]

    def velocities(p_: float, b_: float) -> tuple[Array, Array]:
        A = _rate_map(p_)
        if n == 6:
            A = np.column_stack([A, np.zeros(N_COORDINATES)])
            A[_X0, 6], A[_Z0, 6] = math.sin(p_), math.cos(p_)
        jv = wheel_centre_jacobian(params, configuration(p_, b_)) @ A
        v_ = jv @ rates
        v_[:, 1] += sink_rate
        return v_, jv

    v, jv = velocities(pitch, bogie)
    gamma = contact_angle_from_velocity(v)
    norm2 = np.maximum(np.einsum("ja,ja->j", v, v), np.finfo(float).tiny)
    d_gamma_dv = np.column_stack([v[:, 1], -v[:, 0]]) / norm2[:, None]  # dγ = (v_z dv_x − v_x dv_z)/|v|²
    jac = np.zeros((3, n))
    jac[:, 2:5] = np.einsum("ja,jak->jk", d_gamma_dv, jv[:, :, :3])
    if n == 6:
        jac[:, 5] = np.einsum("ja,ja->j", d_gamma_dv, jv[:, :, 6])
    for col, (dp, db) in enumerate(((angle_step, 0.0), (0.0, angle_step))):
        moved = contact_angle_from_velocity(velocities(pitch + dp, bogie + db)[0])
        jac[:, col] = (moved - gamma) / angle_step
    return gamma, jac


def contact_angle_covariance(
    params: RoverParams, inputs: ArrayLike, cov: ArrayLike, *, angle_step: float = 1e-6
) -> tuple[Array, Array]:
    """γ̌ (eq. 79) and its first-order covariance for ``inputs`` = [θ, q1, ẋ^R, θ̇, q̇1(, ż^R)] ~ (inputs, cov).

    The rates enter linearly (exact derivative through J_a); θ and q1 by
    forward differences of ``angle_step`` (rad). A sixth input is ż0^R
    (absent: 0, the paper's assumption). Returns (γ̌ (3,), (3, 3)).
    """
    gamma, jac = _contact_angle_jacobian(params, np.asarray(inputs, dtype=float), angle_step)
    out = jac @ np.asarray(cov, dtype=float) @ jac.T
    return gamma, 0.5 * (out + out.T)


def path_tangent_angles(
    params: RoverParams, pitch: float, bogie_angle: float, sinkage: ArrayLike | None = None
) -> tuple[Array, Array]:
    """Tangent angles of the parabola through the three wheel centres, and its error-cancelling weights.

    In the plane the three wheel centres lie on one path z_wc(x) (eq. 26).
    A wheel sunk s_j into the soil rides s_j below that path: ``sinkage``
    (m, (3,), positive deeper; None: 0) lifts each centre back onto it
    before the parabola is fitted (:mod:`~terrain_estimation.models.rover_sinkage`).
    The parabola through them gives each wheel's path angle
    γ_geo,j = −atan(p'(x_j)) from the configuration alone; its error is the
    path's cubic and higher terms. Returns (γ_geo (3,), c (3,)) where c is
    orthogonal to the tangent errors of a cubic and a quartic term at the
    three nodes (≈ (1, 4, 1), Simpson's weights, for equal spacing), so
    Σ c_j (γ_j − γ_geo,j) is free of them (:func:`contact_angles_with_vertical_speed`).
    """
    centres = wheel_centres(params, configuration(pitch, bogie_angle))
    x = centres[:, 0] - float(centres[:, 0].mean())
    A = np.column_stack([np.ones(3), x, x * x])
    heights = centres[:, 1] if sinkage is None else centres[:, 1] + np.asarray(sinkage, dtype=float)
    coef = np.linalg.solve(A, heights)
    slope = coef[1] + 2.0 * coef[2] * x
    errors = []
    for m in (3, 4):
        fit = np.linalg.solve(A, x**m)
        errors.append(m * x ** (m - 1) - (fit[1] + 2.0 * fit[2] * x))
    weights = np.cross(errors[0], errors[1])
    weights = weights / (np.sum(np.abs(weights)) or 1.0)
    if weights.sum() < 0.0:
        weights = -weights
    return -np.arctan(slope), weights


@dataclass(frozen=True)
class VerticalSpeedEstimate:
    """Contact angles with ż0^R estimated from the path geometry (:func:`contact_angles_with_vertical_speed`).

    Attributes:
        contact_angle: γ̌ (3,) (rad), eq. 79 with the estimated ż0^R.
        contact_angle_cov: its first-order covariance (3, 3).
        vertical_speed: ż0^R (m/s).
        vertical_speed_variance: its variance from the inputs' covariance
            ((m/s)²); the geometric model error is not in it.
    """

    contact_angle: Array
    contact_angle_cov: Array
    vertical_speed: float
    vertical_speed_variance: float


def contact_angles_with_vertical_speed(
    params: RoverParams,
    inputs: ArrayLike,
    cov: ArrayLike,
    *,
    angle_step: float = 1e-6,
    sinkage: ArrayLike | None = None,
    sinkage_rate: ArrayLike | None = None,
) -> VerticalSpeedEstimate:
    """γ̌ of eq. 79 without the ż0^R = 0 assumption: ż0^R from the path through the three wheel centres.

    The paper sets ż0^R = 0 (eq. 45) and names the error, δ ≈ −ż0^R/ẋ0^R in
    every contact angle (eqs. 90–91): on the simulated terrains ż0^R/ẋ0^R
    reaches 0.04 RMS (terrain 1), 2 N of DP at W = 50 N. But the three
    wheel centres are three points of the one path z_wc(x), at positions the
    configuration gives to ≈ 1e-5 m; the parabola through them gives each
    wheel's path angle γ_geo,j (:func:`path_tangent_angles`). The kinematic
    angles of eq. 79 depend on ż0^R as γ_j(w) ≈ γ_j(0) + a_j w with
    a_j = ∂γ_j/∂ż0^R, so ż0^R is the w for which the weighted sum
    Σ c_j (γ_j(w) − γ_geo,j) vanishes, c being blind to the parabola's cubic
    and quartic errors: ŵ = −c·(γ(0) − γ_geo)/(c·a), refined by one Newton
    step on the exact γ(w). The contact angles are eq. 79 at ŵ, so each wheel keeps its
    own kinematics; only the common error δ is removed. Exact for paths that
    are quartic over the wheelbase; measured on the simulated terrains with
    exact inputs the γ error falls from 0.035 to 0.009 rad (terrain 1), from
    0.0074 to 0.0042 (terrain 2) and from 0.027 to 0.018 (terrain 5).

    Args:
        params: rover geometry.
        inputs: [θ, q1, ẋ^R, θ̇, q̇1] (Estimator 1's posterior).
        cov: their covariance (5, 5).
        angle_step: forward-difference step in θ, q1 (rad).
        sinkage: s_j (m, positive deeper) of each wheel below the path
            (:func:`path_tangent_angles`); None: 0.
        sinkage_rate: ṡ_j (m/s) of each wheel (:func:`contact_angle_measurement`); None: 0.

    With sinkage the three centres ride s_j below the one path and move at
    ṡ_j off it: the path is fitted through the centres lifted by s_j and each
    wheel's kinematic angle is that of its velocity with ṡ_j added back, so
    γ̌ is the angle of the undisturbed surface the soil forces act in.
    """
    x = np.asarray(inputs, dtype=float)
    if x.shape != (5,):
        raise ValueError(f"inputs must be [θ, q1, ẋ^R, θ̇, q̇1], got shape {x.shape}")
    c = np.asarray(cov, dtype=float)
    sink_rate = None if sinkage_rate is None else np.asarray(sinkage_rate, dtype=float)
    gamma0, jac0 = _contact_angle_jacobian(params, np.append(x, 0.0), angle_step, sink_rate)
    sensitivity = jac0[:, 5]  # a_j = ∂γ_j/∂ż0^R
    geo, weights = path_tangent_angles(params, float(x[0]), float(x[1]), sinkage)
    denominator = float(weights @ sensitivity)
    if not math.isfinite(denominator) or abs(denominator) < 1e-12:
        gamma, jac = _contact_angle_jacobian(params, x, angle_step, sink_rate)
        gamma_cov = jac @ c @ jac.T
        return VerticalSpeedEstimate(gamma, 0.5 * (gamma_cov + gamma_cov.T), 0.0, 0.0)
    w = -float(weights @ (gamma0 - geo)) / denominator
    jac_geo = np.zeros((3, 5))
    for col, (dp, db) in enumerate(((angle_step, 0.0), (0.0, angle_step))):
        jac_geo[:, col] = (path_tangent_angles(params, x[0] + dp, x[1] + db, sinkage)[0] - geo) / angle_step
    dw = -(weights @ (jac0[:, :5] - jac_geo)) / denominator
    jac = jac0[:, :5] + np.outer(sensitivity, dw)
    # γ is an arctangent of the velocities: one Newton step on Σ c_j (γ_j(w) − γ_geo,j) = 0.
    pitch, bogie, speed, pitch_rate, bogie_rate = (float(v) for v in x)
    gamma = contact_angle_measurement(params, pitch, bogie, speed, pitch_rate, bogie_rate, w, sink_rate)
    w -= float(weights @ (gamma - geo)) / denominator
    gamma = contact_angle_measurement(params, pitch, bogie, speed, pitch_rate, bogie_rate, w, sink_rate)
    gamma_cov = jac @ c @ jac.T
    return VerticalSpeedEstimate(gamma, 0.5 * (gamma_cov + gamma_cov.T), w, float(dw @ c @ dw))


def synthesised_perpendicular_forces(
    params: RoverParams,
    axial_force: ArrayLike,
    bogie_moment: float,
    wheel_force_x: float,
    carrier_angle: ArrayLike,
    contact_angle: ArrayLike | None = None,
) -> Array:
    """F̌_⊥ of Estimator 3 (single-axis load cells) from Estimator 1's net forces, eqs. 86–88 (N), shape (3,).

    ::

        F_⊥12 = (−M_1fw + (F_L1 − F_L2) b) / a                                          (86)
        F_⊥3  = (F_xfw − (F_L1 + F_L2) sin ε1 − F_⊥12 cos ε1 − F_L3 sin ε3) / cos ε3       (87)
        F_⊥1  = F_⊥12 F_L1 / (F_L1 + F_L2),   F_⊥2 = F_⊥12 F_L2 / (F_L1 + F_L2)           (88)

    with a, b = ``params.bogie_joint_height``, ``params.bogie_half_length``
    (the rear wheel 1 at −b, the middle wheel 2 at +b along the bogie, a
    below the joint).

    **Split of F_⊥12.** Eq. 88 gives both bogie wheels the same F_⊥/F_L, i.e.
    the same force direction in the carrier frame; that is DP ∝ W only when
    both wheels meet the terrain at the carrier angle (γ1 = γ2 = ε1). On
    rolling terrain the two wheels stand on different slopes and
    W sin(γ_j − ε) reaches several newtons with opposite signs, which eq. 88
    puts into DP. With ``contact_angle`` (γ, e.g. eq. 79's γ̌) the split is
    made in the terrain frames instead: both wheels get the same DP/W = tan φ,
    so F_⊥j = F_Lj tan(δ_j + φ), δ_j = γ_j − ε_j, with φ the root of
    Σ_j F_Lj tan(δ_j + φ) = F_⊥12 (monotonic; Newton). It equals eq. 88 when
    δ1 = δ2. Without ``contact_angle``, if a bogie wheel is unloaded
    (F_L ≤ 0) or the root is not found, eq. 88 is used; if F_L1 + F_L2 ≤ 0,
    F_⊥12 is split evenly.

    Raises:
        ValueError: ``bogie_joint_height`` is 0 (eq. 86 needs a > 0).
    """
    a, b = params.bogie_joint_height, params.bogie_half_length
    if a <= 0.0:
        raise ValueError("synthesised_perpendicular_forces needs params.bogie_joint_height > 0 (eq. 86)")
    f_l = np.asarray(axial_force, dtype=float)
    eps = np.asarray(carrier_angle, dtype=float)
    f_p12 = (-bogie_moment + (f_l[0] - f_l[1]) * b) / a
    f_p3 = wheel_force_x - (f_l[0] + f_l[1]) * math.sin(eps[0]) - f_p12 * math.cos(eps[0]) - f_l[2] * math.sin(eps[2])
    f_p3 /= math.cos(eps[2])
    if contact_angle is not None:
        split = _terrain_frame_split(f_l[:2], f_p12, np.asarray(contact_angle, dtype=float)[:2] - eps[:2])
        if split is not None:
            return np.array([split[0], split[1], f_p3])
    total = f_l[0] + f_l[1]
    share = (f_l[0] / total, f_l[1] / total) if total > 0.0 else (0.5, 0.5)
    return np.array([f_p12 * share[0], f_p12 * share[1], f_p3])


def _terrain_frame_split(axial: Array, total: float, delta: Array) -> Array | None:
    """F_⊥j = F_Lj tan(δ_j + φ) with Σ = ``total`` (see :func:`synthesised_perpendicular_forces`)."""
    f1, f2 = float(axial[0]), float(axial[1])
    d1, d2 = float(delta[0]), float(delta[1])
    if f1 <= 0.0 or f2 <= 0.0:
        return None
    limit = 0.5 * math.pi - 1e-3
    low, high = -limit - min(d1, d2), limit - max(d1, d2)
    if low >= high:
        return None
    weight = f1 + f2
    phi = min(max(math.atan(total / weight) - (f1 * d1 + f2 * d2) / weight, low), high)
    for _ in range(30):
        t1, t2 = math.tan(d1 + phi), math.tan(d2 + phi)
        step = (f1 * t1 + f2 * t2 - total) / (f1 * (1.0 + t1 * t1) + f2 * (1.0 + t2 * t2))
        phi = min(max(phi - step, low), high)
        if abs(step) < 1e-13:
            break
    p1, p2 = f1 * math.tan(d1 + phi), f2 * math.tan(d2 + phi)
    if abs(p1 + p2 - total) > 1e-6 * max(1.0, abs(total)):
        return None
    return np.array([p1, p2])


def propagate_covariance(fn: Callable[[Array], Array], mean: ArrayLike, cov: ArrayLike) -> Array:
    """First-order covariance of ``fn(x)`` for x ~ (mean, cov): J cov Jᵀ with a central-difference J.

    The step per input is 1e-3 of its σ (at least 1e-9 of its magnitude):
    small against the spread, so the result is the local linearisation.
    Inputs with zero variance are skipped. Returns (p, p) for
    ``fn: (n,) → (p,)``.
    """
    x = np.asarray(mean, dtype=float)
    c = np.asarray(cov, dtype=float)
    scale = np.sqrt(np.clip(np.diag(c), 0.0, None))
    steps = np.maximum(1e-3 * scale, 1e-9 * np.maximum(1.0, np.abs(x)))
    y0 = np.asarray(fn(x), dtype=float)
    jac = np.zeros((y0.size, x.size))
    for k in range(x.size):
        if scale[k] == 0.0:
            continue
        dx = np.zeros_like(x)
        dx[k] = steps[k]
        jac[:, k] = (np.asarray(fn(x + dx), dtype=float) - np.asarray(fn(x - dx), dtype=float)) / (2.0 * steps[k])
    out: Array = jac @ c @ jac.T
    return 0.5 * (out + out.T)


# ---------------------------------------------------------------------------
# Estimator 1 (eqs. 43–74)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class KinematicTerms:
    """H, ∂V/∂g and the resistive-torque map at one estimated configuration Φ̂ (eqs. 55–58).

    Attributes:
        mass_matrix: H (7, 7).
        gravity_gradient: ∂V/∂g (7,).
        resistive_torque_map: generalised force per unit τ_R of each wheel,
            −J_ωᵀ (7, 3) (eqs. 34–36: the soil's moment on the wheel is −τ_R
            about +y, acting on the wheel's absolute rotation).
        gravity_stiffness: ∂(∂V/∂g)/∂(θ, q1) (7, 2), by central differences
            (the quasi-static net-force model, :class:`GeneralEstimatorModel`).
    """

    mass_matrix: Array
    gravity_gradient: Array
    resistive_torque_map: Array
    gravity_stiffness: Array


#: Step of the central differences of ∂V/∂g in θ and q1 (rad).
_STIFFNESS_STEP: Final[float] = 1e-5


def kinematic_terms(params: RoverParams, pitch: float, bogie_angle: float) -> KinematicTerms:
    """:class:`KinematicTerms` at Φ̂ = [0, 0, θ, q1, 0, 0, 0] (eq. 44)."""
    g = configuration(pitch, bogie_angle)
    zero = np.zeros(N_COORDINATES)
    terms = dynamics_terms(params, g, zero)
    h = _STIFFNESS_STEP
    stiffness = np.empty((N_COORDINATES, 2))
    for col, (dp, dq) in enumerate(((h, 0.0), (0.0, h))):
        plus = dynamics_terms(params, configuration(pitch + dp, bogie_angle + dq), zero).gravity
        minus = dynamics_terms(params, configuration(pitch - dp, bogie_angle - dq), zero).gravity
        stiffness[:, col] = (plus - minus) / (2.0 * h)
    return KinematicTerms(
        mass_matrix=np.asarray(terms.mass_matrix, dtype=float),
        gravity_gradient=np.asarray(terms.gravity, dtype=float),
        resistive_torque_map=-wheel_angular_velocity_jacobian(params, g).T,
        gravity_stiffness=stiffness,
    )


@dataclass(frozen=True)
class GeneralInput:
    """Input of one Estimator 1 step (eq. 47).

    Attributes:
        wheel_torque: τ_W1..3, applied wheel torques averaged over the step (N·m), (3,).
        terms: kinematics at Φ̂ held over the step (the paper's choice); None
            evaluates them at every sigma point.
    """

    wheel_torque: Array
    terms: KinematicTerms | None = None

    def __post_init__(self) -> None:
        torque = np.asarray(self.wheel_torque, dtype=float)
        if torque.shape != (3,) or not np.isfinite(torque).all():
            raise ValueError(f"GeneralInput.wheel_torque must be 3 finite values, got {self.wheel_torque!r}")
        object.__setattr__(self, "wheel_torque", torque)


class GeneralEstimatorModel:
    """Estimator 1, the general estimator: 22 states (eq. 43), 11 measurements (eq. 62).

    Implements :class:`~terrain_estimation.filters.base.StateSpaceModel`;
    ``f`` and ``h`` are vectorised over sigma points.

    Args:
        params: rover parameters (H, ∂V/∂g, J_w; b_d, I_wg; g).
        process_noise: Q per ``step_s``.
        step_s: T_e (s) the process noise refers to.
        r_diag: default measurement variances (11,), e.g. from
            :func:`general_measurement_variances`; the estimator overrides R
            per step with the actual number of averaged samples.
        quasi_static: the net wheel-force effects follow the equilibrium
            (module docstring, "Quasi-static net forces"); False: pure random
            walks, eq. 59 as printed.
    """

    def __init__(
        self,
        params: RoverParams | None = None,
        *,
        process_noise: GeneralProcessNoise | None = None,
        step_s: float = 0.2,
        r_diag: ArrayLike | None = None,
        quasi_static: bool = True,
    ) -> None:
        self.params = params if params is not None else RoverParams()
        self.process_noise = process_noise if process_noise is not None else GeneralProcessNoise()
        if not (math.isfinite(step_s) and step_s > 0.0):
            raise ValueError(f"step_s must be finite and > 0, got {step_s}")
        self.step_s = float(step_s)
        if r_diag is None:
            r = general_measurement_variances(self.params, SensorNoise(), MeasurementErrorFloors(), step_s=step_s)
        else:
            r = np.asarray(r_diag, dtype=float)
        if r.shape != (11,) or not (np.isfinite(r).all() and (r > 0.0).all()):
            raise ValueError(f"r_diag must hold 11 finite variances > 0, got {r_diag!r}")
        self._r_sqrt = np.diag(np.sqrt(r))
        self._q_sigma = self.process_noise.sigma()
        self.quasi_static = bool(quasi_static)
        # −J_ωᵀ does not depend on the configuration (planar rotations add up).
        self._tau_map_free = -wheel_angular_velocity_jacobian(self.params, np.zeros(N_COORDINATES)).T[list(_FREE)]

    @property
    def state_dim(self) -> int:
        return 22

    @property
    def measurement_dim(self) -> int:
        return 11

    def f(self, x: Array, u: Any, dt: float) -> Array:
        """Process model f1 (eqs. 48–61) over ``dt``: ``(22,)``/``(m, 22)`` → same shape.

        ::

            q̈_j  = (τ_W,j − τ_R,j − b_d q̇_j) / I_wg               (49)
            q̇_j ← q̇_j + q̈_j dt                                   (48)
            θ ← θ + θ̇ dt + θ̈ dt²/2,  θ̇ ← θ̇ + θ̈ dt  (q1 alike)        (51–54)
            [ẍ0 z̈0 θ̈ q̈1] ← H_ff⁻¹ (Q_f − H_fw q̈_w)                 (55–58, module docstring)
            ẋ^R ← ẋ^R + (ẍ0 cos θ − z̈0 sin θ) dt                    (60)
            τ_R, M_0fw, M_1fw, F_xfw, F_zfw, i: random walks        (50, 59, 61)
        """
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be finite and > 0, got {dt}")
        if not isinstance(u, GeneralInput):
            raise ValueError(f"u must be a GeneralInput, got {type(u).__name__}")
        xs = np.array(x, dtype=float)
        single = xs.ndim == 1
        X = np.atleast_2d(xs)
        p = self.params
        out = X.copy()
        rates = X[:, _G.WHEEL_RATE]
        tau_r = X[:, _G.RESISTIVE_TORQUE]
        wheel_acc = (u.wheel_torque - tau_r - p.wheel_damping * rates) / p.wheel_gear_inertia  # (49)
        out[:, _G.WHEEL_RATE] = rates + wheel_acc * dt  # (48)
        for angle, rate, acc in ((_G.PITCH, _G.PITCH_RATE, _G.PITCH_ACC), (_G.BOGIE, _G.BOGIE_RATE, _G.BOGIE_ACC)):
            out[:, angle] = X[:, angle] + X[:, rate] * dt + 0.5 * X[:, acc] * dt * dt  # (51, 52)
            out[:, rate] = X[:, rate] + X[:, acc] * dt  # (53, 54)
        out[:, list(_G.FREE_ACC)] = self._free_accelerations(X, wheel_acc, u.terms)  # (55–58)
        if self.quasi_static:
            moved = out[:, [_G.PITCH, _G.BOGIE]] - X[:, [_G.PITCH, _G.BOGIE]]
            out[:, list(_G.FREE_FORCE)] += self._gravity_change(X, moved, u.terms)
        pitch = X[:, _G.PITCH]
        out[:, _G.FORWARD_SPEED] = X[:, _G.FORWARD_SPEED] + dt * (
            X[:, _G.X_ACC] * np.cos(pitch) - X[:, _G.Z_ACC] * np.sin(pitch)
        )  # (60)
        result: Array = out[0] if single else out
        return result

    def _free_accelerations(self, X: Array, wheel_acc: Array, terms: KinematicTerms | None) -> Array:
        """Solve rows x0, z0, θ, q1 of eq. 32 (without Ḣġ, ∂T/∂g) for their accelerations, (m, 4)."""
        free, wheels = list(_FREE), list(_WHEEL_COORDS)
        forces = X[:, list(_G.FREE_FORCE)]
        tau_r = X[:, _G.RESISTIVE_TORQUE]
        if terms is not None:
            H = terms.mass_matrix
            rhs = (
                forces
                + tau_r @ terms.resistive_torque_map[free].T
                - terms.gravity_gradient[free]
                - wheel_acc @ H[np.ix_(free, wheels)].T
            )
            solved = np.linalg.solve(H[np.ix_(free, free)], rhs.T).T
            return np.asarray(solved, dtype=float)
        out = np.empty((X.shape[0], 4))
        for k in range(X.shape[0]):
            t = kinematic_terms(self.params, float(X[k, _G.PITCH]), float(X[k, _G.BOGIE]))
            out[k] = self._free_accelerations(X[k : k + 1], wheel_acc[k : k + 1], t)[0]
        return out

    def _gravity_change(self, X: Array, moved: Array, terms: KinematicTerms | None) -> Array:
        """Change of ∂V/∂g on the free coordinates for the step's (Δθ, Δq1), (m, 4)."""
        free = list(_FREE)
        if terms is not None:
            change: Array = moved @ terms.gravity_stiffness[free].T
            return change
        out = np.empty((X.shape[0], 4))
        for k in range(X.shape[0]):
            t = kinematic_terms(self.params, float(X[k, _G.PITCH]), float(X[k, _G.BOGIE]))
            out[k] = t.gravity_stiffness[free] @ moved[k]
        return out

    def h(self, x: Array, u: Any = None) -> Array:
        """Measurement model h1 (eqs. 69–74): ``(22,)``/``(m, 22)`` → ``(11,)``/``(m, 11)``.

        ::

            q̇_j, θ, q1, ẋ^R, i_j: the states                      (70, 71, 74)
            ẍ0^R = ẍ0 cos θ − z̈0 sin θ − g sin θ                  (72)
            z̈0^R = ẍ0 sin θ + z̈0 cos θ + g cos θ                  (73)
        """
        xs = np.asarray(x, dtype=float)
        single = xs.ndim == 1
        X = np.atleast_2d(xs)
        pitch = X[:, _G.PITCH]
        c, s = np.cos(pitch), np.sin(pitch)
        up = X[:, _G.Z_ACC] + self.params.gravity
        out = np.column_stack(
            [
                X[:, _G.WHEEL_RATE],
                pitch,
                X[:, _G.BOGIE],
                X[:, _G.X_ACC] * c - up * s,
                X[:, _G.X_ACC] * s + up * c,
                X[:, _G.FORWARD_SPEED],
                X[:, _G.SLIP],
            ]
        )
        result: Array = out[0] if single else out
        return result

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        """Factor of Q for a step of ``dt`` (:meth:`process_noise_factor` of the configured σ)."""
        return self.process_noise_factor(self._q_sigma, dt)

    def process_noise_factor(self, sigma: ArrayLike, dt: float) -> Array:
        """L with Q = L Lᵀ: random walks of σ per ``step_s``, scaled by √(dt/step_s), (22, 22).

        With ``quasi_static`` the τ_R increments also move the net forces by
        −(−J_ωᵀ)_f Δτ_R: a resistive torque that changes is met by wheel
        forces that keep the body in balance (ΔM_0fw = Σ Δτ_R, ΔM_1fw =
        Δτ_R1 + Δτ_R2), so the net generalised force, not M_0fw itself, takes
        the independent increments.
        """
        sig = np.asarray(sigma, dtype=float) * math.sqrt(dt / self.step_s)
        L = np.diag(sig)
        if self.quasi_static:
            rows, cols = list(_G.FREE_FORCE), list(range(3, 6))
            L[np.ix_(rows, cols)] = -self._tau_map_free * sig[cols]
        return L

    def measurement_noise_sqrt(self) -> Array:
        """√R of the constructor's ``r_diag``."""
        return self._r_sqrt.copy()


def general_measurement(
    params: RoverParams,
    *,
    wheel_rates: ArrayLike,
    specific_force: ArrayLike,
    bogie_angle: float,
    forward_speed: float,
    slip_pitch_rate: float,
    slip_bogie_rate: float,
    absolute_spin: bool = True,
) -> Array:
    """Measurement vector y1 (eq. 62) from one step's averaged measurements, shape (11,).

    Args:
        params: rover parameters.
        wheel_rates: q̇̌_j of eq. 63 (rad/s), (3,).
        specific_force: averaged accelerometer (f_x, f_z) (m/s²).
        bogie_angle: averaged q̌1 (rad).
        forward_speed: averaged ẋ̌0^R (m/s).
        slip_pitch_rate, slip_bogie_rate: θ̇ and q̇1 entering Φ̌̇ of eq. 66
            (rad/s): the IMU's pitch rate in the paper.
        absolute_spin: see :func:`slip_measurement`.
    """
    f = np.asarray(specific_force, dtype=float)
    rates = np.asarray(wheel_rates, dtype=float)
    pitch = pitch_from_gravity(float(f[0]), float(f[1]))  # (64)
    slip = slip_measurement(
        params, pitch, bogie_angle, forward_speed, slip_pitch_rate, slip_bogie_rate, rates, absolute_spin=absolute_spin
    )
    return np.concatenate([rates, [pitch, bogie_angle, f[0], f[1], forward_speed], slip])


def general_measurement_variances(
    params: RoverParams,
    noise: SensorNoise,
    floors: MeasurementErrorFloors,
    *,
    step_s: float,
    samples: int | Sequence[int] = 10,
    pitch: float = 0.0,
    bogie_angle: float = 0.0,
    forward_speed: float = 0.02,
    slip_pitch_rate: float = 0.0,
    slip_bogie_rate: float = 0.0,
    wheel_rates: ArrayLike | None = None,
    slip_rate_variances: tuple[float, float] | None = None,
    absolute_spin: bool = True,
) -> Array:
    """Diagonal of R1 (eq. 62 order) from Table IV (module docstring), shape (11,).

    Args:
        params, noise, floors: rover, sensor σ, model-error floors.
        step_s: time between the two encoder readings of eq. 63 (s).
        samples: number of 50 Hz samples averaged: one count for all, or
            (imu, joints, velocimeter).
        pitch, bogie_angle, forward_speed, slip_pitch_rate, slip_bogie_rate,
        wheel_rates: the operating point of the slip's noise propagation
            (default: level, 2 cm/s, no slip).
        slip_rate_variances: variances of the θ̇, q̇1 that enter eq. 66
            (rad²/s²); default: the IMU's pitch rate averaged over the step
            and the bogie encoder differenced over the step.
        absolute_spin: see :func:`slip_measurement`.
    """
    counts = (samples,) * 3 if isinstance(samples, int) else tuple(samples)
    if len(counts) != 3 or min(counts) < 1:
        raise ValueError(f"samples must be a count ≥ 1 or three of them, got {samples!r}")
    n_imu, n_joint, n_vel = (float(c) for c in counts)
    rate_var = 2.0 * noise.wheel_angle**2 / step_s**2 + floors.wheel_rate**2
    pitch_var = (noise.acceleration / params.gravity) ** 2 / n_imu + floors.pitch**2
    bogie_var = noise.bogie_angle**2 / n_joint + floors.bogie_angle**2
    accel_var = noise.acceleration**2 / n_imu + floors.specific_force**2
    speed_var = noise.forward_speed**2 / n_vel + floors.forward_speed**2
    if slip_rate_variances is None:
        slip_rate_variances = (noise.pitch_rate**2 / n_imu, 2.0 * noise.bogie_angle**2 / step_s**2)
    rates = (
        np.full(3, forward_speed / params.wheel_radius) if wheel_rates is None else np.asarray(wheel_rates, dtype=float)
    )
    # ǐ as a function of (ẋ^R, θ̇, q̇1, q̇2, q̇3, q̇4); θ and q1 are known to ≤ 1e-4 rad, which moves
    # the wheel-centre speed by a relative 1e-4 and is left out.
    mean = np.array([forward_speed, slip_pitch_rate, slip_bogie_rate, *rates])
    cov = np.diag([speed_var, *slip_rate_variances, rate_var, rate_var, rate_var])
    _, jac = slip_measurement_jacobian(params, pitch, bogie_angle, mean, absolute_spin=absolute_spin)
    slip_var = np.einsum("jk,kl,jl->j", jac, cov, jac) + floors.slip**2
    return np.concatenate([[rate_var] * 3, [pitch_var, bogie_var, accel_var, accel_var, speed_var], slip_var])


def initial_general_state(
    params: RoverParams,
    *,
    wheel_rates: ArrayLike,
    wheel_torque: ArrayLike,
    pitch: float,
    bogie_angle: float,
    forward_speed: float,
    slip: ArrayLike,
) -> Array:
    """x1 at start from one step's measurements: steady state, the rover in equilibrium, shape (22,).

    τ_R = τ_W − b_d q̇ (eq. 49 with q̈ = 0), rates and accelerations 0, and the
    net wheel-force effects that hold the rover still at (θ, q1): Q_f = 0 in
    eqs. 55–58, i.e. [F_xfw, F_zfw, M_0fw, M_1fw] = ∂V/∂g − J_ωᵀ(−τ_R) on the free coordinates.
    """
    rates = np.asarray(wheel_rates, dtype=float)
    tau_r = np.asarray(wheel_torque, dtype=float) - params.wheel_damping * rates
    terms = kinematic_terms(params, pitch, bogie_angle)
    free = list(_FREE)
    forces = terms.gravity_gradient[free] - terms.resistive_torque_map[free] @ tau_r
    x = np.zeros(22)
    x[_G.WHEEL_RATE] = rates
    x[_G.RESISTIVE_TORQUE] = tau_r
    x[_G.PITCH] = pitch
    x[_G.BOGIE] = bogie_angle
    x[list(_G.FREE_FORCE)] = forces
    x[_G.FORWARD_SPEED] = forward_speed
    x[_G.SLIP] = np.asarray(slip, dtype=float)
    return x


# ---------------------------------------------------------------------------
# Estimators 2 and 3 (eqs. 75–89)
# ---------------------------------------------------------------------------


class WheelForceModel:
    """Estimators 2 and 3: 9 random-walk states (eq. 75), 9 measurements (eqs. 78, 85).

    ``u`` of ``h`` is the carrier angles ε (3,) of the step (eqs. 81–82: θ̂ + q̂1
    for the bogie wheels, θ̂ for the front wheel), from Estimator 1.

    Args:
        process_noise: Q per ``step_s``.
        step_s: T_e (s).
        r_diag: default measurement variances (9,); the estimator overrides R per step.
    """

    def __init__(
        self,
        *,
        process_noise: WheelForceProcessNoise | None = None,
        step_s: float = 0.2,
        r_diag: ArrayLike | None = None,
    ) -> None:
        self.process_noise = process_noise if process_noise is not None else WheelForceProcessNoise()
        if not (math.isfinite(step_s) and step_s > 0.0):
            raise ValueError(f"step_s must be finite and > 0, got {step_s}")
        self.step_s = float(step_s)
        r = (
            np.array([MeasurementErrorFloors().contact_angle ** 2] * 3 + [SensorNoise().load_cell ** 2 / 10.0] * 6)
            if r_diag is None
            else np.asarray(r_diag, dtype=float)
        )
        if r.shape != (9,) or not (np.isfinite(r).all() and (r > 0.0).all()):
            raise ValueError(f"r_diag must hold 9 finite variances > 0, got {r_diag!r}")
        self._r_sqrt = np.diag(np.sqrt(r))
        self._q_sigma = self.process_noise.sigma()

    @property
    def state_dim(self) -> int:
        return 9

    @property
    def measurement_dim(self) -> int:
        return 9

    def f(self, x: Array, u: Any, dt: float) -> Array:
        """Random walk (eqs. 77, 84): x_{k+1} = x_k."""
        out: Array = np.array(x, dtype=float)
        return out

    def h(self, x: Array, u: Any) -> Array:
        """h2 = h3 (eqs. 80–82, 89): ``(9,)``/``(m, 9)`` → same shape; ``u`` = carrier angles ε (3,).

        ::

            γ̂_j  = γ_j                                           (80)
            F̂_Lj = W_j cos(γ_j − ε_j) − DP_j sin(γ_j − ε_j)        (81)
            F̂_⊥j = W_j sin(γ_j − ε_j) + DP_j cos(γ_j − ε_j)        (82)
        """
        eps = np.asarray(u, dtype=float)
        if eps.shape != (3,) or not np.isfinite(eps).all():
            raise ValueError(f"u must be the 3 finite carrier angles ε, got {u!r}")
        xs = np.asarray(x, dtype=float)
        gamma, load, pull = xs[..., 0:3], xs[..., 3:6], xs[..., 6:9]
        delta = gamma - eps
        c, s = np.cos(delta), np.sin(delta)
        out: Array = np.concatenate([gamma, load * c - pull * s, load * s + pull * c], axis=-1)
        return out

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        """diag(σ √(dt/step_s)) (:class:`WheelForceProcessNoise`)."""
        return np.diag(self._q_sigma * math.sqrt(dt / self.step_s))

    def measurement_noise_sqrt(self) -> Array:
        """√R of the constructor's ``r_diag``."""
        return self._r_sqrt.copy()


def wheel_force_measurement_variances(
    *,
    contact_angle_cov: ArrayLike,
    noise: SensorNoise,
    floors: MeasurementErrorFloors,
    load_cell_samples: ArrayLike,
    synthesised_cov: ArrayLike | None = None,
) -> Array:
    """Diagonal of R2/R3 (eq. 78 order), shape (9,).

    Args:
        contact_angle_cov: covariance of γ̌ propagated from Estimator 1 (3, 3)
            (only its diagonal is used: R is diagonal).
        noise, floors: sensor σ and model-error floors.
        load_cell_samples: samples averaged per wheel (3,).
        synthesised_cov: covariance of Estimator 3's synthesised F̌_⊥ (3, 3);
            None: measured two-axis cells (Estimator 2).
    """
    n = np.asarray(load_cell_samples, dtype=float)
    gamma_var = np.diag(np.asarray(contact_angle_cov, dtype=float)) + floors.contact_angle**2
    cell_var = noise.load_cell**2 / n + floors.load_cell**2
    if synthesised_cov is None:
        perp_var = cell_var
    else:
        perp_var = np.diag(np.asarray(synthesised_cov, dtype=float)) + floors.synthesised_force**2
    return np.concatenate([gamma_var, cell_var, perp_var])


def initial_wheel_force_state(
    contact_angle: ArrayLike, axial_force: ArrayLike, perpendicular_force: ArrayLike, carrier_angle: ArrayLike
) -> Array:
    """x2 from one step's measurements: γ̌ and (W, DP) by the inverse rotation of eqs. 81–82, shape (9,)."""
    gamma = np.asarray(contact_angle, dtype=float)
    f_l = np.asarray(axial_force, dtype=float)
    f_p = np.asarray(perpendicular_force, dtype=float)
    delta = gamma - np.asarray(carrier_angle, dtype=float)
    c, s = np.cos(delta), np.sin(delta)
    return np.concatenate([gamma, f_l * c + f_p * s, -f_l * s + f_p * c])
