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

from terrain_estimation.models.rover_estimator_kinematics import (
    VerticalSpeedEstimate,
    configuration,
    contact_angle_covariance,
    contact_angle_measurement,
    contact_angles_with_vertical_speed,
    generalised_velocity,
    path_tangent_angles,
    pitch_from_gravity,
    propagate_covariance,
    slip_measurement,
    slip_measurement_jacobian,
    synthesised_perpendicular_forces,
)
from terrain_estimation.models.rover_estimator_noise import (
    GeneralProcessNoise,
    MeasurementErrorFloors,
    SensorNoise,
    WheelForceProcessNoise,
)
from terrain_estimation.models.rover_estimator_states import (
    GENERAL_MEASUREMENTS,
    GENERAL_STATES,
    WHEEL_FORCE_MEASUREMENTS,
    WHEEL_FORCE_STATES,
    GeneralIndex,
)
from terrain_estimation.models.rover_general_model import (
    GeneralEstimatorModel,
    GeneralInput,
    KinematicTerms,
    general_measurement,
    general_measurement_variances,
    initial_general_state,
    kinematic_terms,
)
from terrain_estimation.models.rover_wheel_force_model import (
    WheelForceModel,
    initial_wheel_force_state,
    wheel_force_measurement_variances,
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
