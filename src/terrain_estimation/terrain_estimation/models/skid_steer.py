"""Skid-steered vehicle with N axles per side: parameters, kinematics, brush tire, quasi-static loads.

Shared physics of the skid-steer paper ([SS], MODELS.md B.2–B.5), used both by
the observer model (``terrain_estimation.models.skid_steer_observer``) and by
the truth plant (``vehicle_sim.plants.skid_steer``), which adds the physics the
observer lacks (roll/pitch load-transfer dynamics, tire relaxation, wheel-side
rotational dynamics). Plain numpy, vectorised over any leading dimensions.

Conventions
    Body frame REP 103 (x forward, y left, z up), origin at the centre of mass
    (= geometric centre, where the IMU sits). With N axles per side, wheel
    order everywhere is the left wheels front to rear, then the right wheels
    front to rear: index ``side * N + axle`` with side 0 = left
    (``y = +B/2``), 1 = right (``y = −B/2``) and axle 0 = front … N − 1 =
    rear. For the paper's three axles that is ``FL, ML, RL, FR, MR, RR``
    (CONTRACT.md ``tire_sideslip``); :func:`wheel_names` names them for any N.
    The wheels of a side turn at the same speed (one motor per side, B.1).

Geometry (MODELS.md B.2, chosen reading): axle 1 a ahead of axle 2, axle 3 b
behind it, CM x ahead of axle 2, so axle positions relative to the CM are
``a − x, −x, −(b + x)`` = +1.592, −0.244, −1.280 m; track = the "width" B.
Any other vehicle gives its axle positions directly (``SkidSteerParams.axle_x``,
front to rear, m from the CM; e.g. the 4-wheel Husky ``(0.256, −0.256)``);
every per-wheel function is vectorised over the 2N wheels.

Contract mapping (``SkidSteerState.tire_sideslip`` is ``float64[6]``): for
three axles the six wheels as they are; for N ≠ 3 per side the front axle,
a virtual middle wheel and the rear axle, where the middle value is the
side's tire sideslip linearly interpolated over the axle positions at the
midpoint between the front and the rear axle (for two axles the mean of
front and rear): :func:`contract_tire_sideslip`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.checks import check_fields, check_finite

Array = NDArray[np.float64]

__all__ = [
    "WHEEL_NAMES",
    "CONTRACT_AXLES",
    "SkidSteerParams",
    "axle_count",
    "axle_positions",
    "wheel_names",
    "wheel_positions",
    "contract_tire_sideslip",
    "contact_velocities",
    "tire_sideslip_angles",
    "theoretical_slips",
    "brush_tire_forces",
    "side_slip_ratios",
    "quasi_static_loads",
    "body_forces",
    "body_sideslip",
    "instantaneous_centre_of_rotation",
]

#: Wheel order of every per-wheel array of the paper's three-axle vehicle (CONTRACT.md ``tire_sideslip``).
WHEEL_NAMES: tuple[str, ...] = ("FL", "ML", "RL", "FR", "MR", "RR")
#: Number of axles per side of the contract's ``tire_sideslip`` (float64[6]).
CONTRACT_AXLES = 3


@dataclass(frozen=True, kw_only=True)
class SkidSteerParams:
    """Nominal vehicle of [SS] Table 1 (MODELS.md B.2) plus the values the paper omits.

    Args:
        mass: vehicle mass m (kg).
        yaw_inertia: I_z (kg·m²).
        axle_spacing_front: a, axle 1 to axle 2 (m).
        axle_spacing_rear: b, axle 2 to axle 3 (m).
        cm_ahead_of_middle_axle: x, CM ahead of axle 2 (m); negative puts it behind.
        track: lateral distance B between the left and right wheel contact
            lines (m); the paper's kinematics use the width 2.060 m.
        cg_height: height of the CM above the ground H (m).
        wheel_radius: rolling radius R (m).
        transmission_ratio: motor → wheel ratio i_g.
        longitudinal_stiffness: C_x, brush longitudinal slip stiffness per
            wheel (N per unit slip).
        cornering_stiffness: C_α per wheel (N/rad).
        friction: tire–ground friction coefficient μ (the paper plots μ = 0.8).
        gravity: g (m/s²).
        rolling_speed_floor: ε of the brush model's slip denominator (m/s).
        axle_x: axle positions relative to the CM, front to rear (m, strictly
            decreasing, at least two); None (default) takes the paper's three
            from ``axle_spacing_front``, ``axle_spacing_rear`` and
            ``cm_ahead_of_middle_axle`` (which are then unused). E.g. the
            4-wheel Husky: ``(0.256, −0.256)``.
    """

    mass: float = 3000.0
    yaw_inertia: float = 6390.0
    axle_spacing_front: float = 1.836
    axle_spacing_rear: float = 1.036
    cm_ahead_of_middle_axle: float = 0.244
    track: float = 2.060
    cg_height: float = 0.600
    wheel_radius: float = 0.375
    transmission_ratio: float = 27.13
    longitudinal_stiffness: float = 31300.0
    cornering_stiffness: float = 40200.0
    friction: float = 0.8
    gravity: float = 9.80665
    rolling_speed_floor: float = 0.05
    axle_x: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        positive = (
            "mass",
            "yaw_inertia",
            "axle_spacing_front",
            "axle_spacing_rear",
            "track",
            "cg_height",
            "wheel_radius",
            "transmission_ratio",
            "longitudinal_stiffness",
            "cornering_stiffness",
            "friction",
            "gravity",
            "rolling_speed_floor",
        )
        check_fields(self, positive)
        check_finite("SkidSteerParams", "cm_ahead_of_middle_axle", self.cm_ahead_of_middle_axle)
        if self.axle_x is not None:
            try:
                xs = tuple(float(v) for v in self.axle_x)
            except (TypeError, ValueError):
                raise ValueError(
                    f"SkidSteerParams.axle_x must be None or a sequence of numbers, got {self.axle_x!r}"
                ) from None
            if len(xs) < 2 or not all(math.isfinite(v) for v in xs):
                raise ValueError(f"SkidSteerParams.axle_x must hold at least 2 finite positions (m), got {xs}")
            if any(b >= a for a, b in zip(xs, xs[1:], strict=False)):
                raise ValueError(f"SkidSteerParams.axle_x must decrease strictly (front to rear), got {xs}")
            object.__setattr__(self, "axle_x", xs)


def axle_count(p: SkidSteerParams) -> int:
    """Number of axles per side N (3 for the paper's vehicle)."""
    return CONTRACT_AXLES if p.axle_x is None else len(p.axle_x)


def wheel_names(p: SkidSteerParams) -> tuple[str, ...]:
    """Names of the 2N wheels in wheel order.

    Three axles: :data:`WHEEL_NAMES`; two: ``FL, RL, FR, RR``; otherwise
    ``L1 … LN, R1 … RN`` (1 = front).
    """
    n = axle_count(p)
    if n == CONTRACT_AXLES:
        return WHEEL_NAMES
    if n == 2:
        return ("FL", "RL", "FR", "RR")
    return tuple(f"L{i + 1}" for i in range(n)) + tuple(f"R{i + 1}" for i in range(n))


def axle_positions(p: SkidSteerParams) -> Array:
    """Longitudinal axle positions x_i relative to the CM, front to rear (m), shape (N,)."""
    if p.axle_x is not None:
        return np.array(p.axle_x, dtype=float)
    x = p.cm_ahead_of_middle_axle
    return np.array([p.axle_spacing_front - x, -x, -(p.axle_spacing_rear + x)])


def wheel_positions(p: SkidSteerParams) -> tuple[Array, Array]:
    """Contact-point positions (x, y) of the 2N wheels in wheel order (m), each shape (2N,)."""
    xa = axle_positions(p)
    n = xa.size
    half = 0.5 * p.track
    return np.concatenate([xa, xa]), np.array([half] * n + [-half] * n)


def contract_tire_sideslip(alpha: Any, p: SkidSteerParams) -> Array:
    """Per-wheel tire sideslip ``(..., 2N)`` → the contract's six values ``(..., 6)`` (module docstring).

    Three axles: unchanged. N ≠ 3: per side (left, then right) the front
    axle's α, the α linearly interpolated over the axle positions at the
    midpoint between the front and the rear axle, and the rear axle's α.
    """
    a = np.asarray(alpha, dtype=float)
    n = axle_count(p)
    if a.shape[-1:] != (2 * n,):
        raise ValueError(f"alpha must end in a dimension of 2N = {2 * n} wheels, got shape {a.shape}")
    if n == CONTRACT_AXLES:
        return a.copy()
    xa = axle_positions(p)
    x_mid = 0.5 * (xa[0] + xa[-1])
    k = int(np.searchsorted(-xa, -x_mid, side="right")) - 1  # axle k ahead of (or at) x_mid, k + 1 behind
    k = min(max(k, 0), n - 2)
    w = (xa[k] - x_mid) / (xa[k] - xa[k + 1])
    sides = []
    for side in range(2):
        s = a[..., side * n : (side + 1) * n]
        mid = (1.0 - w) * s[..., k] + w * s[..., k + 1]
        sides += [s[..., 0], mid, s[..., n - 1]]
    return np.stack(sides, axis=-1)


def contact_velocities(vx: Any, vy: Any, yaw_rate: Any, p: SkidSteerParams) -> tuple[Array, Array]:
    """Velocities of the 2N contact points in the body frame (paper eqs. 3, 5; MODELS.md B.3).

    ``v_x,ij = vx − y_j r``, ``v_y,ij = vy + x_i r``. Inputs broadcast; outputs
    have shape ``(..., 2N)``.
    """
    xw, yw = wheel_positions(p)
    vx_ = np.asarray(vx, dtype=float)[..., None]
    vy_ = np.asarray(vy, dtype=float)[..., None]
    r_ = np.asarray(yaw_rate, dtype=float)[..., None]
    return vx_ - yw * r_, vy_ + xw * r_


def tire_sideslip_angles(v_x: Any, v_y: Any) -> Array:
    """Tire sideslip α = atan(v_y / v_x) per wheel (paper eq. 6), rad.

    Evaluated as ``atan2(v_y, |v_x|)`` so it is defined at ``v_x = 0`` (±π/2)
    and keeps the forward-driving sign when reversing.
    """
    return np.arctan2(np.asarray(v_y, dtype=float), np.abs(np.asarray(v_x, dtype=float)))


def _per_wheel_side(value: Any, axles: int = CONTRACT_AXLES) -> Array:
    """Expand a per-side quantity ``(..., 2)`` (left, right) to wheel order ``(..., 2N)``, N = ``axles``."""
    v = np.asarray(value, dtype=float)
    if v.shape[-1:] != (2,):
        raise ValueError(f"per-side array must end in a dimension of 2 (left, right), got shape {v.shape}")
    return np.repeat(v, axles, axis=-1)


def theoretical_slips(wheel_speed: Any, v_x: Any, v_y: Any, p: SkidSteerParams) -> tuple[Array, Array]:
    """Brush-model theoretical slips σ_x, σ_y per wheel (MODELS.md B.4).

    ``σ_x = (R ω − v_x)/V_r``, ``σ_y = −v_y/V_r`` with ``V_r = max(R|ω|, ε)``.

    Args:
        wheel_speed: wheel angular speeds per side ``(..., 2)`` (left, right),
            rad/s, or per wheel ``(..., 2N)``.
        v_x, v_y: contact-point velocities ``(..., 2N)`` from
            :func:`contact_velocities`.
    """
    w = np.asarray(wheel_speed, dtype=float)
    omega = _per_wheel_side(w, axle_count(p)) if w.shape[-1:] == (2,) else w
    rolling = p.wheel_radius * omega
    vr = np.maximum(np.abs(rolling), p.rolling_speed_floor)
    return (rolling - np.asarray(v_x, dtype=float)) / vr, -np.asarray(v_y, dtype=float) / vr


def brush_tire_forces(
    sigma_x: Any,
    sigma_y: Any,
    normal_load: Any,
    *,
    longitudinal_stiffness: Any,
    cornering_stiffness: Any,
    friction: Any,
) -> tuple[Array, Array]:
    """Combined-slip brush tire, parabolic pressure, one friction coefficient (MODELS.md B.4).

    ::

        γ = √((C_x σ_x)² + (C_α σ_y)²)
        F = γ − γ²/(3 μ F_z) + γ³/(27 μ² F_z²)   if γ < 3 μ F_z,   else μ F_z
        F_x = (C_x σ_x/γ) F,   F_y = (C_α σ_y/γ) F

    Pacejka, *Tire and vehicle dynamics*, ch. 3; Svendenius 2007. ``F_z ≤ 0``
    (a wheel off the ground) gives no force. All arguments broadcast.

    Returns:
        ``(F_x, F_y)`` in N, the shape of the broadcast inputs.
    """
    cx_sx = np.asarray(longitudinal_stiffness, dtype=float) * np.asarray(sigma_x, dtype=float)
    ca_sy = np.asarray(cornering_stiffness, dtype=float) * np.asarray(sigma_y, dtype=float)
    fz = np.maximum(np.asarray(normal_load, dtype=float), 0.0)
    mu_fz = np.asarray(friction, dtype=float) * fz
    gamma = np.hypot(cx_sx, ca_sy)
    limit = 3.0 * mu_fz
    # With t = min(γ, 3μF_z)/(3μF_z) ∈ [0, 1] (the sliding fraction of the
    # patch), γ − γ²/(3μF_z) + γ³/(27μ²F_z²) = μF_z t (3 − 3t + t²), and t = 1
    # gives exactly μF_z: one expression for both regions, without the
    # overflow (or 0/0 at denormal loads) of the powers of 1/(μF_z) and
    # without cancellation at small slip (3 − 3t + t² ≥ 1).
    t = np.minimum(gamma, limit) / np.where(limit > 0.0, limit, 1.0)
    force = mu_fz * t * (3.0 - 3.0 * t + t * t)
    scale = np.divide(force, gamma, out=np.zeros(np.broadcast(force, gamma).shape), where=gamma > 0.0)
    return cx_sx * scale, ca_sy * scale


def side_slip_ratios(wheel_speed: Any, v_x_side: Any, p: SkidSteerParams) -> Array:
    """Bounded longitudinal slip per side κ_j, positive in traction (MODELS.md B.3).

    ``κ = (Rω − v)/(Rω)`` when ``R|ω| ≥ |v|`` (driving), ``(Rω − v)/v``
    otherwise (braking); 0 when both speeds are below the rolling-speed floor.

    Args:
        wheel_speed: per-side wheel speeds ``(..., 2)`` (rad/s).
        v_x_side: per-side contact-line speeds ``vx ∓ r B/2`` ``(..., 2)`` (m/s).
    """
    rolling = p.wheel_radius * np.asarray(wheel_speed, dtype=float)
    v = np.asarray(v_x_side, dtype=float)
    driving = np.abs(rolling) >= np.abs(v)
    den = np.where(driving, rolling, v)
    small = np.abs(den) < p.rolling_speed_floor
    return np.where(small, 0.0, (rolling - v) / np.where(small, 1.0, den))


def quasi_static_loads(ax: Any, ay: Any, p: SkidSteerParams) -> Array:
    """Vertical wheel loads with longitudinal and lateral load transfer (MODELS.md B.5).

    Rigid body on equal virtual springs: axle loads ``F_i = p + q x_i`` satisfy
    vertical and pitch equilibrium with the inertial force ``−m a_x`` at height
    H (``N p + q Σx_i = m g``, ``p Σx_i + q Σx_i² = −m a_x H``; for two axles
    the statically determinate split); the lateral transfer ``m a_y H / B`` is
    split equally between the N axles (``a_y > 0``, a left turn, loads the
    right side). Floored at 0.

    Args:
        ax, ay: body accelerations (m/s², gravity removed), broadcast.

    Returns:
        ``F_z`` per wheel ``(..., 2N)`` (N).
    """
    xa = axle_positions(p)
    n = float(xa.size)
    s1, s2 = float(np.sum(xa)), float(np.sum(xa**2))
    d = n * s2 - s1**2
    m, g, h = p.mass, p.gravity, p.cg_height
    ax_ = np.asarray(ax, dtype=float)[..., None]
    ay_ = np.asarray(ay, dtype=float)[..., None]
    p0 = m * (g * s2 + ax_ * h * s1) / d
    q = -m * (n * ax_ * h + g * s1) / d
    axle = p0 + q * xa
    lateral = m * ay_ * h / (n * p.track)
    return np.maximum(np.concatenate([0.5 * axle - lateral, 0.5 * axle + lateral], axis=-1), 0.0)


def body_forces(fx: Any, fy: Any, p: SkidSteerParams) -> tuple[Array, Array, Array]:
    """Sum of the tire forces and their yaw moment about the CM (MODELS.md B.6).

    ``M_z = Σ (x_i F_y,ij − y_j F_x,ij)``. Inputs ``(..., 2N)``; outputs ``(...)``.
    """
    xw, yw = wheel_positions(p)
    fx_ = np.asarray(fx, dtype=float)
    fy_ = np.asarray(fy, dtype=float)
    return fx_.sum(axis=-1), fy_.sum(axis=-1), (xw * fy_ - yw * fx_).sum(axis=-1)


def body_sideslip(vx: Any, vy: Any) -> Array:
    """Body sideslip β = atan2(vy, vx) (paper eq. 40), rad."""
    return np.arctan2(np.asarray(vy, dtype=float), np.asarray(vx, dtype=float))


def instantaneous_centre_of_rotation(
    vx: Any, vy: Any, yaw_rate: Any, min_yaw_rate: float = 0.02
) -> tuple[Array, Array, Array]:
    """ICR in body axes ``x = −vy/r``, ``y = vx/r`` (paper eq. 41; MODELS.md B.3).

    Meaningless as ``r → 0``: where ``|r| ≤ min_yaw_rate`` the coordinates are
    returned as 0 and the validity flag is False (never NaN or Inf).

    Returns:
        ``(x_icr, y_icr, valid)``.
    """
    r = np.asarray(yaw_rate, dtype=float)
    valid = np.abs(r) > min_yaw_rate
    safe = np.where(valid, r, 1.0)
    x_icr = np.where(valid, -np.asarray(vy, dtype=float) / safe, 0.0)
    y_icr = np.where(valid, np.asarray(vx, dtype=float) / safe, 0.0)
    return x_icr, y_icr, valid
