"""Cubature Kalman filter with full covariance (Arasaratnam–Haykin 2009).

The third-degree spherical-radial cubature rule (``2n`` points
``ξ = √n [I, −I]``, weights ``1/(2n)``, MODELS.md A.5 eq. 14) inside the
additive-noise sigma-point recursion of
:class:`~terrain_estimation.filters.ukf.SigmaPointKalmanFilter`. It is the
full-covariance twin of :class:`~terrain_estimation.filters.sckf.SquareRootCubatureKalmanFilter`
(equal in exact arithmetic) and equals the unscented filter with
``α = 1, β = 0, κ = 0`` (whose centre point then has zero weight).
"""

from __future__ import annotations

from dataclasses import dataclass

from .sigma_points import SigmaPointSet, cubature_points
from .ukf import SigmaPointKalmanFilter

__all__ = ["CubatureKalmanFilter"]


@dataclass(frozen=True, kw_only=True)
class CubatureKalmanFilter(SigmaPointKalmanFilter):
    """Full-covariance cubature Kalman filter.

    Args:
        gate_threshold: Mahalanobis gate on the NIS (e.g. a χ²_p quantile);
            ``None`` disables gating.
    """

    def point_set(self, n: int) -> SigmaPointSet:
        """Cubature points for dimension ``n`` (cached)."""
        return cubature_points(n)
