"""Wheel–terrain quantities of the rocker-bogie rover: the soil force's frames and the slip ([RB], MODELS.md C.3).

The soil's force on a wheel as (W, DP) in the terrain frame at the contact angle γ, in the world frame
(:func:`terrain_contact_force_world`) and on a load cell's carrier axes (eqs. 81–82, :func:`load_cell_forces`
and its inverse :func:`wheel_forces_from_load_cell`); the contact angle of a wheel centre's velocity (eq. 79,
:func:`contact_angle_from_velocity`); the slip of eqs. 1–2 (:func:`slip_from_motion`,
:func:`slip_from_motion_scalar`). Functions of forces, angles and velocities alone: no geometry, so they
live apart from the chain kinematics and dynamics of :mod:`terrain_estimation.models.rover`, which
re-exports them.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = [
    "contact_angle_from_velocity",
    "load_cell_forces",
    "slip_from_motion",
    "slip_from_motion_scalar",
    "terrain_contact_force_world",
    "wheel_forces_from_load_cell",
]


def terrain_contact_force_world(normal_load: ArrayLike, drawbar_pull: ArrayLike, gamma: ArrayLike) -> Array:
    """World (F_x, F_z) of the soil's force on a wheel (N), shape (..., 2).

    W acts along the terrain normal n = (sin γ, cos γ) and DP along the
    tangent t = (cos γ, −sin γ) of eq. 39. γ is the contact angle w.r.t. the
    world horizontal in the same sense as the pitch: positive when the
    terrain descends forward, so a wheel centre moving along the terrain has
    γ = atan(−v_z/v_x) (eq. 79) and a path z_wc(x) gives γ = −atan(dz_wc/dx).
    """
    W = np.asarray(normal_load, dtype=float)
    dp = np.asarray(drawbar_pull, dtype=float)
    gam = np.asarray(gamma, dtype=float)
    s, c = np.sin(gam), np.cos(gam)
    return np.stack(np.broadcast_arrays(W * s + dp * c, W * c - dp * s), axis=-1)


def load_cell_forces(
    normal_load: ArrayLike, drawbar_pull: ArrayLike, contact_angle_gamma: ArrayLike, carrier_angle: ArrayLike
) -> tuple[Array, Array]:
    """Load-cell components (F_L, F_⊥) of the soil force on a wheel (N), eqs. 81–82 (vectorised).

    F_L = W cos(γ − ε) − DP sin(γ − ε)   along the carrier z axis (the single-axis cell)
    F_⊥ = W sin(γ − ε) + DP cos(γ − ε)   along the carrier x axis

    i.e. the world force of :func:`terrain_contact_force_world` projected on
    the carrier axes (sin ε, cos ε) and (cos ε, −sin ε). At γ = ε: F_L = W,
    F_⊥ = DP.
    """
    W = np.asarray(normal_load, dtype=float)
    dp = np.asarray(drawbar_pull, dtype=float)
    delta = np.asarray(contact_angle_gamma, dtype=float) - np.asarray(carrier_angle, dtype=float)
    s, c = np.sin(delta), np.cos(delta)
    return W * c - dp * s, W * s + dp * c


def wheel_forces_from_load_cell(
    axial_force: ArrayLike, perpendicular_force: ArrayLike, contact_angle_gamma: ArrayLike, carrier_angle: ArrayLike
) -> tuple[Array, Array]:
    """(W, DP) from (F_L, F_⊥): the inverse rotation of eqs. 81–82 (N)."""
    f_l = np.asarray(axial_force, dtype=float)
    f_p = np.asarray(perpendicular_force, dtype=float)
    delta = np.asarray(contact_angle_gamma, dtype=float) - np.asarray(carrier_angle, dtype=float)
    s, c = np.sin(delta), np.cos(delta)
    return f_l * c + f_p * s, -f_l * s + f_p * c


def contact_angle_from_velocity(centre_velocity: ArrayLike) -> Array:
    """γ = atan(−v_z / v_x) of a wheel centre's world velocity (..., 2) (rad), eq. 79.

    ``arctan2(−v_z, v_x)`` would flip by π when reversing; eq. 79 is an
    arctangent of the ratio, so a reversing wheel gets the same γ as a forward
    one. A wheel at rest (v_x = v_z = 0) gets γ = 0.
    """
    v = np.asarray(centre_velocity, dtype=float)
    vx, vz = v[..., 0], v[..., 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        gamma = np.arctan(np.where(vx != 0.0, -vz / np.where(vx != 0.0, vx, 1.0), 0.0))
    vertical = (vx == 0.0) & (vz != 0.0)
    return np.where(vertical, -np.sign(vz) * 0.5 * math.pi, gamma)


def slip_from_motion(wheel_rate: ArrayLike, centre_speed: ArrayLike, radius: float) -> Array:
    """Slip (> 0) or skid (< 0) of a wheel, [RB] eqs. 1–2, clipped to [−1, 1].

    i = 1 − v/(r ω) when |r ω| ≥ |v| (eq. 1), i = r ω / v − 1 otherwise (eq. 2).

    Args:
        wheel_rate: absolute wheel spin rate ω about +y (rad/s), positive rolling forward.
        centre_speed: signed speed v of the wheel centre along the terrain
            tangent (m/s), positive forward.
        radius: r_w (m).

    Guards: a wheel at rest (ω = v = 0) has i = 0. When r ω and v do not have
    the same sign (one of them zero or reversed, e.g. a stalled rover sliding
    back while its wheels still turn forward) eqs. 1–2 leave [−1, 1]; the
    wheel is then at full slip, i = +1 if the rim moves forward relative to
    the centre (r ω > v) and i = −1 (locked, skidding) otherwise, so that the
    soil force opposes the sliding as the forward-driving model's DP(±1)
    does. A wheel spinning on a stationary centre thus has i = 1 and a locked
    wheel moving forward i = −1, the formulas' own limits. Driving backwards
    (both negative) is outside the paper's model; eqs. 1–2 are applied to it
    as printed.
    """
    rim = radius * np.asarray(wheel_rate, dtype=float)
    v = np.asarray(centre_speed, dtype=float)
    if rim.shape != v.shape:
        rim, v = np.broadcast_arrays(rim, v)
    slipping = np.abs(rim) >= np.abs(v)
    numerator = np.where(slipping, v, rim)
    denominator = np.where(slipping, rim, v)
    # The denominator is 0 only at rest (|v| ≤ |r ω| = 0), where i = 0.
    at_rest = denominator == 0.0
    ratio = np.divide(numerator, np.where(at_rest, 1.0, denominator))
    slip = np.where(slipping, 1.0 - ratio, ratio - 1.0)
    opposed = rim * v <= 0.0
    slip = np.where(opposed, np.sign(rim - v), slip)
    result: Array = np.clip(np.where(at_rest, 0.0, slip), -1.0, 1.0)
    return result


def slip_from_motion_scalar(wheel_rate: float, centre_speed: float, radius: float) -> float:
    """:func:`slip_from_motion` for one wheel in plain floats (the plant's inner loop)."""
    rim = radius * wheel_rate
    v = centre_speed
    if rim == 0.0 and v == 0.0:
        return 0.0
    if rim * v <= 0.0:
        return 1.0 if rim > v else -1.0
    slip = 1.0 - v / rim if abs(rim) >= abs(v) else rim / v - 1.0
    return min(max(slip, -1.0), 1.0)
