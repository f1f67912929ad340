"""Estimator 1 of the rover, the general estimator: process and measurement model ([RB] eqs. 43–74).

:class:`GeneralEstimatorModel` (22 states, 11 measurements), its input
(:class:`GeneralInput`, :class:`KinematicTerms`), the measurement vector y1
and its variances from Table IV, and the equilibrium start; the module
docstring of :mod:`terrain_estimation.models.rover_estimators` (which
re-exports all of it) describes the accelerations and the quasi-static
net forces.

**Wheel damping** (issue 21). Eq. 48 steps the wheel rate with eq. 49's
acceleration at the step's start, so the damping b_d q̇ is taken at the
previous rate. The encoders give the window's *mean* rate, and the wheel's
torque balance over a window is ``I_wg Δq̇ / T = τ̄_W − τ̄_R − b_d q̄̇`` with
the damping at the mean rate of the window just closed, i.e. the new state.
With b_d T / I_wg = 0.42 (Table III, T_e = 0.2 s) the explicit step put
b_d (q̇_k − q̇_k−1) ≈ 0.46 q̈ N·m into τ_R: on the simulated terrain 1 τ_R's
error against the window-mean truth was 0.51 q̈ (correlation 0.98 with the
wheel's acceleration), 4.2e-4 N·m RMS on the rear wheel. ``f`` takes the
damping at the new rate (implicit Euler, exact for this linear balance):
``q̇_k = (q̇_k−1 + T (τ_W − τ_R) / I_wg) / (1 + T b_d / I_wg)``; the error
fell to 1.7e-4 (rear) and 1.4e-4 N·m (middle, front).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike

from terrain_estimation.filters.base import Array
from terrain_estimation.filters.sigma_points import solve
from terrain_estimation.models.rover import (
    N_COORDINATES,
    RoverParams,
    dynamics_gravity,
    dynamics_terms,
    wheel_angular_velocity_jacobian,
)
from terrain_estimation.models.rover_estimator_kinematics import (
    configuration,
    pitch_from_gravity,
    slip_measurement,
    slip_measurement_jacobian,
)
from terrain_estimation.models.rover_estimator_noise import (
    GeneralProcessNoise,
    MeasurementErrorFloors,
    SensorNoise,
    StepNoiseModel,
)
from terrain_estimation.models.rover_estimator_states import FREE_COORDINATES, WHEEL_COORDINATES, GeneralIndex

__all__ = [
    "GeneralEstimatorModel",
    "GeneralInput",
    "KinematicTerms",
    "general_measurement",
    "general_measurement_variances",
    "initial_general_state",
    "kinematic_terms",
]

_G = GeneralIndex


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
        plus = dynamics_gravity(params, configuration(pitch + dp, bogie_angle + dq))
        minus = dynamics_gravity(params, configuration(pitch - dp, bogie_angle - dq))
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


class GeneralEstimatorModel(StepNoiseModel):
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

    STATE_DIM = 22
    MEASUREMENT_DIM = 11

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
        self._set_step(step_s)
        if r_diag is None:
            r = general_measurement_variances(self.params, SensorNoise(), MeasurementErrorFloors(), step_s=step_s)
        else:
            r = np.asarray(r_diag, dtype=float)
        self._set_measurement_noise(r, r_diag)
        self._q_sigma = self.process_noise.sigma()
        self.quasi_static = bool(quasi_static)
        # −J_ωᵀ does not depend on the configuration (planar rotations add up).
        tau_map = -wheel_angular_velocity_jacobian(self.params, np.zeros(N_COORDINATES)).T
        self._tau_map_free = tau_map[list(FREE_COORDINATES)]

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
        # (48–49) with the damping at the step's new rate (implicit Euler, module docstring "Wheel damping").
        new_rates = (rates + dt * (u.wheel_torque - tau_r) / p.wheel_gear_inertia) / (
            1.0 + dt * p.wheel_damping / p.wheel_gear_inertia
        )
        wheel_acc = (new_rates - rates) / dt  # = (τ_W − τ_R − b_d q̇_new) / I_wg
        out[:, _G.WHEEL_RATE] = new_rates
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
        free, wheels = list(FREE_COORDINATES), list(WHEEL_COORDINATES)
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
            solved = solve(H[np.ix_(free, free)], rhs.T).T
            return np.asarray(solved, dtype=float)
        out = np.empty((X.shape[0], 4))
        for k in range(X.shape[0]):
            t = kinematic_terms(self.params, float(X[k, _G.PITCH]), float(X[k, _G.BOGIE]))
            out[k] = self._free_accelerations(X[k : k + 1], wheel_acc[k : k + 1], t)[0]
        return out

    def _gravity_change(self, X: Array, moved: Array, terms: KinematicTerms | None) -> Array:
        """Change of ∂V/∂g on the free coordinates for the step's (Δθ, Δq1), (m, 4)."""
        free = list(FREE_COORDINATES)
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
        L = self.random_walk_factor(sigma, dt)
        if self.quasi_static:
            rows, cols = list(_G.FREE_FORCE), list(range(3, 6))
            L[np.ix_(rows, cols)] = -self._tau_map_free * np.diag(L)[cols]
        return L


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
    free = list(FREE_COORDINATES)
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
