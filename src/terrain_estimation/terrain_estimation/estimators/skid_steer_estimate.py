"""What one skid-steer estimator step produces: :class:`SkidSteerEstimate`, the health counters, and the
derived output fields that are not the filter's state.

:class:`SkidSteerEstimate` holds every field of ``terrain_msgs/SkidSteerState`` plus the odometry pose and
diagnostics; :class:`SkidSteerCounters` the estimator's health counters. The helpers compute what the
estimator adds to the filter's state: the body sideslip variance (first-order through
``β = atan2(vy, vx)``) and the contract's six tire sideslip angles from the 2N per-wheel ones
(:func:`~terrain_estimation.models.skid_steer.contract_tire_sideslip`'s mapping, precomputed per vehicle).
Both types are re-exported by :mod:`terrain_estimation.estimators.skid_steer`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from terrain_estimation.filters.base import Array
from terrain_estimation.models.skid_steer import CONTRACT_AXLES, axle_count, axle_positions

if TYPE_CHECKING:
    from terrain_estimation.estimators.skid_steer_config import SkidSteerEstimatorConfig

__all__ = [
    "SkidSteerEstimate",
    "SkidSteerCounters",
    "ContractMapping",
    "contract_mapping",
    "map_contract",
    "body_sideslip_variance",
]

#: ``(N, k, k + 1, N − 1, w)``: how the contract's six tire sideslip values come from the 2N per-wheel ones.
ContractMapping = tuple[int, int, int, int, float]


@dataclass(frozen=True)
class SkidSteerEstimate:
    """One filter step's result: every ``SkidSteerState`` field, the odometry pose and diagnostics.

    Every float is finite.

    Attributes:
        t: time of the step (s), the IMU sample's stamp.
        vx, vy: body-frame velocity of the CM (m/s).
        yaw_rate: r (rad/s).
        vx_variance, vy_variance, yaw_rate_variance: filter variances.
        body_sideslip: β = atan2(vy, vx) (rad).
        body_sideslip_variance: first-order variance of β (rad², ≤ π²).
        slip_left, slip_right: per-side longitudinal slip κ (> 0 in traction).
        tire_sideslip: the contract's six α (rad): FL, ML, RL, FR, MR, RR for
            three axles; per side front, interpolated middle, rear otherwise.
        icr_x, icr_y: instantaneous centre of rotation in body axes (m); 0
            when not valid.
        icr_valid: ``|r| > min_yaw_rate``.
        fading_factor: strong-tracking λ (1 for the plain UKF or a consistent step).
        noise_scale: ``1 + K_q ᾱ`` (1 unless an_stukf).
        mean_abs_tire_sideslip: ᾱ that set the noise scale (rad; 0 unless an_stukf).
        x, y, yaw: dead-reckoned pose in the odom frame (m, m, rad in (−π, π]).
        twist_covariance: covariance of ``[vx, vy, r]``, 9 values row-major.
        nis: normalised innovation squared of the update (0 without update).
        accepted: a measurement update was applied at this step.
        initialised: this estimate comes from a (re)initialisation, not a filter step.
        wheel_speed_left, wheel_speed_right: wheel-side speeds used (rad/s).
        vx_encoder, yaw_rate_encoder: slip-free encoder-only estimates (m/s, rad/s).
        pose_covariance: covariance of the pose ``[x, y, yaw]``, 9 values
            row-major (m², m·rad, rad²).
        wheel_tire_sideslip: α of all 2N wheels in wheel order (rad).
        tire_scales: the estimated tire-parameter scales (``config.scale_states``
            order; empty without scale states).
        stationary: the stationary detector saw the vehicle at rest (a
            zero-velocity update was applied when enabled).
    """

    t: float
    vx: float
    vx_variance: float
    vy: float
    vy_variance: float
    yaw_rate: float
    yaw_rate_variance: float
    body_sideslip: float
    body_sideslip_variance: float
    slip_left: float
    slip_right: float
    tire_sideslip: tuple[float, ...]
    icr_x: float
    icr_y: float
    icr_valid: bool
    fading_factor: float
    noise_scale: float
    mean_abs_tire_sideslip: float
    x: float
    y: float
    yaw: float
    twist_covariance: tuple[float, ...]
    nis: float
    accepted: bool
    initialised: bool
    wheel_speed_left: float
    wheel_speed_right: float
    vx_encoder: float
    yaw_rate_encoder: float
    pose_covariance: tuple[float, ...] = (0.0,) * 9
    wheel_tire_sideslip: tuple[float, ...] = ()
    tire_scales: tuple[float, ...] = ()
    stationary: bool = False


@dataclass(frozen=True)
class SkidSteerCounters:
    """Health counters since construction or :meth:`SkidSteerEstimator.reset`."""

    imu_samples: int = 0
    joint_states: int = 0
    steps: int = 0
    updates_accepted: int = 0
    gated: int = 0
    strong_tracking_active: int = 0
    initialisations: int = 0
    restarts: int = 0
    recoveries: int = 0
    divergences: int = 0
    limit_resets: int = 0
    stale_wheel_speeds: int = 0
    no_wheel_speeds: int = 0
    imu_out_of_order: int = 0
    joint_out_of_order: int = 0
    wheel_speeds_interpolated: int = 0
    wheel_speeds_held: int = 0
    zero_velocity_updates: int = 0


def contract_mapping(cfg: SkidSteerEstimatorConfig) -> ContractMapping | None:
    """``(N, k, k + 1, N − 1, w)`` of :func:`~terrain_estimation.models.skid_steer.contract_tire_sideslip`
    for N ≠ 3 axles (None for three: the six wheels as they are)."""
    n = axle_count(cfg.vehicle)
    if n == CONTRACT_AXLES:
        return None
    xa = axle_positions(cfg.vehicle).tolist()
    x_mid = 0.5 * (xa[0] + xa[-1])
    k = max(i for i in range(n - 1) if xa[i] >= x_mid)
    return n, k, k + 1, n - 1, (xa[k] - x_mid) / (xa[k] - xa[k + 1])


def map_contract(alpha: tuple[float, ...], m: ContractMapping) -> tuple[float, ...]:
    """The contract's six tire sideslip values of the 2N per-wheel ones (front, middle, rear per side)."""
    n, k, k1, last, w = m
    out: list[float] = []
    for side in (0, n):
        out += [alpha[side], (1.0 - w) * alpha[side + k] + w * alpha[side + k1], alpha[side + last]]
    return tuple(out)


def body_sideslip_variance(vx: float, vy: float, P: Array, speed_floor_sq: float) -> tuple[float, float]:
    """``(v², var β)``: the squared speed, floored at ``speed_floor_sq``, and the first-order variance
    of ``β = atan2(vy, vx)``, capped at π².

    ``∂β/∂(vx, vy) = (−vy, vx)/(vx² + vy²)``; the floor (the rolling-speed floor squared) keeps the
    variance finite at rest, the cap is β's whole range (2π). In scalars on the state's floats (the
    array form ``jac @ P[:2, :2] @ jac`` cost more than the arithmetic once per IMU sample; BLAS may
    fuse its multiply-adds, so the two agree to rounding, a test compares). Python's ``float ** 2``
    and numpy's float64 ``** 2`` are the same libm ``pow``; overflow gives inf as numpy's does.
    """
    try:
        v2 = max(vx**2 + vy**2, speed_floor_sq)
    except OverflowError:  # Python's float ** raises where numpy's gives inf (and warns): numpy's then
        v2 = max(float(np.float64(vx) ** 2 + np.float64(vy) ** 2), speed_floor_sq)
    j0, j1 = -vy / v2, vx / v2
    p00, p01, p10, p11 = float(P[0, 0]), float(P[0, 1]), float(P[1, 0]), float(P[1, 1])
    return v2, min((j0 * p00 + j1 * p10) * j0 + (j0 * p01 + j1 * p11) * j1, math.pi**2)
