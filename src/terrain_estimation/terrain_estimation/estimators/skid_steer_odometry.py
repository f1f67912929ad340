"""Dead-reckoned planar pose with a covariance that grows (issue 20 item 4).

The skid-steer estimator integrates its twist ``(vx, vy, r)`` into a pose
``(x, y, yaw)`` in the odom frame: the trapezoidal twist of the step, rotated
with the mid-step heading (exact for a constant twist to O(Δt³))::

    v̄ = (v_{k−1} + v_k)/2,   ψ_m = ψ + Δt r̄/2
    x' = x + Δt (cos ψ_m v̄x − sin ψ_m v̄y)
    y' = y + Δt (sin ψ_m v̄x + cos ψ_m v̄y)
    ψ' = ψ + Δt r̄

The pose covariance goes through the same map with its Jacobians,
``P' = F P Fᵀ + c G Σ̄ Gᵀ``:

    F = ∂(x', y', ψ')/∂(x, y, ψ) = [[1, 0, −Δt (sin ψ_m v̄x + cos ψ_m v̄y)],
                                     [0, 1,  Δt (cos ψ_m v̄x − sin ψ_m v̄y)],
                                     [0, 0, 1]]
    G = ∂(x', y', ψ')/∂(v̄x, v̄y, r̄) = [[Δt cos ψ_m, −Δt sin ψ_m, (Δt/2) F₀₂],
                                        [Δt sin ψ_m,  Δt cos ψ_m, (Δt/2) F₁₂],
                                        [0, 0, Δt]]

with ``Σ̄ = (Σ_{k−1} + Σ_k)/2`` the filter's twist covariance over the step.
The twist error is not white: the filter's error is a slowly varying bias
(tire model, slip), so treating each step's error as independent would make
the pose variance grow like ``Δt·t`` and claim centimetres after minutes.
It is modelled as a first-order Gauss–Markov process of correlation time τ,
whose integral grows the variance by ``2 τ σ²`` per second for ``t ≫ τ``;
the white-noise equivalent of that per step is the factor
``c = max(1, 2τ/Δt)`` (τ = 0: white). Between restarts of the filter the
pose and its covariance carry on (a restart does not move the vehicle).
"""

# ruff: noqa: N803, N806 - matrix symbols (P, F, G) of the propagation

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from terrain_estimation.filters.base import Array

__all__ = ["DeadReckoning"]


def _wrap(angle: float) -> float:
    """Angle in (−π, π]."""
    a = math.remainder(angle, 2.0 * math.pi)
    return math.pi if a == -math.pi else a


class DeadReckoning:
    """Pose ``(x, y, yaw)`` and its 3×3 covariance from the estimated twist (module docstring).

    Args:
        correlation_time_s: τ of the twist error (s, ≥ 0).

    Raises:
        ValueError: ``correlation_time_s`` not finite and ≥ 0.
    """

    def __init__(self, correlation_time_s: float = 1.0) -> None:
        if not (math.isfinite(correlation_time_s) and correlation_time_s >= 0.0):
            raise ValueError(f"correlation_time_s must be finite and >= 0, got {correlation_time_s}")
        self.correlation_time_s = float(correlation_time_s)
        self.reset()

    def reset(self) -> None:
        """Pose at the origin with zero covariance (the odom frame starts where the vehicle is)."""
        self.pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.covariance_values: tuple[float, ...] = (0.0,) * 9

    @property
    def covariance(self) -> Array:
        """The pose covariance ``(3, 3)`` (m², m·rad, rad²)."""
        return np.array(self.covariance_values).reshape(3, 3)

    @covariance.setter
    def covariance(self, value: Array) -> None:
        m = np.asarray(value, dtype=float)
        if m.shape != (3, 3):
            raise ValueError(f"covariance must have shape (3, 3), got {m.shape}")
        self.covariance_values = tuple(m.ravel().tolist())

    def advance(
        self,
        dt: float,
        previous: tuple[float, float, float],
        current: tuple[float, float, float],
        previous_cov: Sequence[float] | Array,
        current_cov: Sequence[float] | Array,
    ) -> None:
        """Integrate one step.

        Args:
            dt: step length (s); ≤ 0 leaves the pose as it is.
            previous, current: twist ``(vx, vy, r)`` at the step's start and end (m/s, m/s, rad/s).
            previous_cov, current_cov: their 3×3 covariances (arrays, or 9 values row-major).
        """
        if dt <= 0.0:
            return
        px, py, yaw = self.pose
        vx = 0.5 * (previous[0] + current[0])
        vy = 0.5 * (previous[1] + current[1])
        r = 0.5 * (previous[2] + current[2])
        mid = yaw + 0.5 * dt * r
        c, s = math.cos(mid), math.sin(mid)
        dx = dt * (c * vx - s * vy)
        dy = dt * (s * vx + c * vy)
        self.pose = (px + dx, py + dy, _wrap(yaw + dt * r))
        # F P Fᵀ with F = I + (−dy, dx, 0) e₃ᵀ (the pose moves with the heading), in scalars: 3×3 numpy
        # products cost more than the arithmetic once per IMU sample.
        p00, p01, p02, _, p11, p12, _, _, p22 = self.covariance_values
        a, b = -dy, dx
        f02, f12 = p02 + a * p22, p12 + b * p22
        q00 = p00 + a * p02 + a * f02
        q01 = p01 + b * p02 + a * f12
        q11 = p11 + b * p12 + b * f12
        # c G Σ̄ Gᵀ, G rows g0 = (Δt cos, −Δt sin, −Δt dy/2), g1 = (Δt sin, Δt cos, Δt dx/2), g2 = (0, 0, Δt).
        w = 0.5 * max(1.0, 2.0 * self.correlation_time_s / dt)  # the factor c and the 1/2 of the mean Σ̄
        a0, a1, a2, a3, a4, a5, a6, a7, a8 = _values(previous_cov)
        b0, b1, b2, b3, b4, b5, b6, b7, b8 = _values(current_cov)
        # Σ = previous + current, then G Σ Gᵀ, element by element (the same operations as a loop over k;
        # written out: this runs once per IMU sample).
        q0, q1, q2 = a0 + b0, a1 + b1, a2 + b2
        q3, q4, q5 = a3 + b3, a4 + b4, a5 + b5
        q6, q7, q8 = a6 + b6, a7 + b7, a8 + b8
        g00, g01, g02 = dt * c, -dt * s, -0.5 * dt * dy
        g10, g11, g12 = dt * s, dt * c, 0.5 * dt * dx
        s00 = q0 * g00 + q3 * g01 + q6 * g02  # (G Σ)_0
        s01 = q1 * g00 + q4 * g01 + q7 * g02
        s02 = q2 * g00 + q5 * g01 + q8 * g02
        s10 = q0 * g10 + q3 * g11 + q6 * g12  # (G Σ)_1
        s11 = q1 * g10 + q4 * g11 + q7 * g12
        s12 = q2 * g10 + q5 * g11 + q8 * g12
        s20, s21, s22 = dt * q6, dt * q7, dt * q8  # (G Σ)_2
        n00 = w * (s00 * g00 + s01 * g01 + s02 * g02)
        n01 = w * 0.5 * (s00 * g10 + s01 * g11 + s02 * g12 + s10 * g00 + s11 * g01 + s12 * g02)
        n02 = w * 0.5 * (s02 * dt + s20 * g00 + s21 * g01 + s22 * g02)
        n11 = w * (s10 * g10 + s11 * g11 + s12 * g12)
        n12 = w * 0.5 * (s12 * dt + s20 * g10 + s21 * g11 + s22 * g12)
        n22 = w * s22 * dt
        r00, r01, r02 = q00 + n00, q01 + n01, f02 + n02
        r11, r12, r22 = q11 + n11, f12 + n12, p22 + n22
        self.covariance_values = (r00, r01, r02, r01, r11, r12, r02, r12, r22)


def _values(cov: Sequence[float] | Array) -> Sequence[float]:
    """A 3×3 covariance as 9 floats, row-major (a tuple or list of floats as it is)."""
    if isinstance(cov, np.ndarray):
        return cov.ravel().tolist()
    if len(cov) != 9:
        raise ValueError(f"a 3x3 covariance needs 9 values (row-major), got {len(cov)}")
    return cov
