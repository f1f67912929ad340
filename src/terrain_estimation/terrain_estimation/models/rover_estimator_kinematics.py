"""Kinematics of the rover's estimated configuration: slips, contact angles, F_⊥ ([RB] eqs. 44–45, 65–68, 79, 86–88).

The measurement constructions Estimators 1–3 share, on the multibody
kinematics of :mod:`terrain_estimation.models.rover`: the estimated
configuration Φ̂ and its velocity, the measured slips and their Jacobian,
the contact angles of eq. 79 (with ż0^R estimated from the wheel-centre
path), Estimator 3's synthesised F_⊥ and first-order covariance
propagation; re-exported by :mod:`terrain_estimation.models.rover_estimators`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from terrain_estimation.filters.base import Array
from terrain_estimation.filters.sigma_points import solve
from terrain_estimation.models.rover import (
    N_COORDINATES,
    RoverParams,
    contact_angle_from_velocity,
    slip_from_motion,
    wheel_angular_velocity_jacobian,
    wheel_centre_jacobian,
    wheel_centres,
)
from terrain_estimation.models.rover_estimator_states import WHEEL_COORDINATES

__all__ = [
    "VerticalSpeedEstimate",
    "configuration",
    "contact_angle_covariance",
    "contact_angle_measurement",
    "contact_angles_with_vertical_speed",
    "generalised_velocity",
    "path_tangent_angles",
    "pitch_from_gravity",
    "propagate_covariance",
    "slip_measurement",
    "slip_measurement_jacobian",
    "synthesised_perpendicular_forces",
]

# Indices into g (models.rover.COORDINATES).
_X0, _Z0, _PITCH, _BOGIE = 0, 1, 2, 3


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
    g_dot[list(WHEEL_COORDINATES)] = np.asarray(wheel_rates, dtype=float)
    return g_dot


def pitch_from_gravity(specific_force_x: float, specific_force_z: float) -> float:
    """θ̌0y = atan(−f_x / f_z), the pitch from the measured gravity direction (eq. 64) (rad)."""
    return math.atan2(-specific_force_x, specific_force_z)


def _rate_map_template(columns: int) -> Array:
    """The constant entries of :func:`_rate_map` (read-only): 1 for θ̇, q̇1 and each wheel rate."""
    A = np.zeros((N_COORDINATES, columns))
    A[_PITCH, 1] = 1.0
    A[_BOGIE, 2] = 1.0
    A[4:, 3:6] = np.eye(3)
    A.setflags(write=False)
    return A


_RATE_MAP = _rate_map_template(6)
_RATE_MAP_VERTICAL = _rate_map_template(7)


def _rate_map(pitch: float, *, vertical: bool = False) -> Array:
    """A with ġ = A [ẋ^R, θ̇, q̇1, q̇2, q̇3, q̇4] (eqs. 45, 66), shape (7, 6).

    ``vertical``: a seventh column for ż^R (ẋ0 += ż^R sin θ, ż0 += ż^R cos θ), shape (7, 7).
    """
    A = (_RATE_MAP_VERTICAL if vertical else _RATE_MAP).copy()
    A[_X0, 0] = math.cos(pitch)
    A[_Z0, 0] = -math.sin(pitch)
    if vertical:
        A[_X0, 6], A[_Z0, 6] = math.sin(pitch), math.cos(pitch)
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

    The last call's result is kept: an estimator step asks for the same slips twice (the measurement, eq. 62,
    and its variance); a repeated call returns copies of it.
    """
    u = np.asarray(inputs, dtype=float)
    key = (id(params), absolute_spin, np.array([pitch, bogie_angle], dtype=float).tobytes(), u.tobytes())
    last = _LAST_SLIP_JACOBIAN[0]  # one read: another thread may replace the entry, never half of it
    if last is not None and last[0] == key and last[1] is params:
        return last[2].copy(), last[3].copy()
    slip, jac = _slip_measurement_jacobian(params, pitch, bogie_angle, u, absolute_spin)
    _LAST_SLIP_JACOBIAN[0] = (key, params, slip.copy(), jac.copy())
    return slip, jac


#: (key, params, slips, Jacobian) of the last :func:`slip_measurement_jacobian` call.
_LAST_SLIP_JACOBIAN: list[tuple[Any, RoverParams, Array, Array] | None] = [None]


def _slip_measurement_jacobian(
    params: RoverParams, pitch: float, bogie_angle: float, u: Array, absolute_spin: bool
) -> tuple[Array, Array]:
    """:func:`slip_measurement_jacobian` without its one-call memory."""
    g = configuration(pitch, bogie_angle)
    A = _rate_map(pitch)
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
        A = _rate_map(p_, vertical=n == 6)
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
    angles, x, A = _path_angles(params, pitch, bogie_angle, sinkage)
    errors = []
    for m in (3, 4):
        fit = solve(A, x**m)
        errors.append(m * x ** (m - 1) - (fit[1] + 2.0 * fit[2] * x))
    (a0, a1, a2), (b0, b1, b2) = errors[0].tolist(), errors[1].tolist()
    weights = np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])  # np.cross's products and differences
    weights = weights / (np.sum(np.abs(weights)) or 1.0)
    if weights.sum() < 0.0:
        weights = -weights
    return angles, weights


def _path_angles(
    params: RoverParams, pitch: float, bogie_angle: float, sinkage: ArrayLike | None
) -> tuple[Array, Array, Array]:
    """The tangent angles of :func:`path_tangent_angles` alone, with the centred x_j and the design matrix."""
    centres = wheel_centres(params, configuration(pitch, bogie_angle))
    x = centres[:, 0] - float(centres[:, 0].mean())
    A = np.column_stack([np.ones(3), x, x * x])
    heights = centres[:, 1] if sinkage is None else centres[:, 1] + np.asarray(sinkage, dtype=float)
    coef = solve(A, heights)
    slope = coef[1] + 2.0 * coef[2] * x
    return -np.arctan(slope), x, A


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
        jac_geo[:, col] = (_path_angles(params, x[0] + dp, x[1] + db, sinkage)[0] - geo) / angle_step
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
