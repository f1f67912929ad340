"""Estimator 3's perpendicular load-cell forces F̌_⊥ ([RB] eqs. 86–88) and their covariance.

Single-axis load cells (``load_cell_axes = 1``) measure only the force along
the sensing axis; the perpendicular components are synthesised from Estimator
1's bogie moment and forward force and the carrier angles. With two-axis cells
(Estimator 2) F_⊥ is measured and passed through.
"""

from __future__ import annotations

import numpy as np

from terrain_estimation.estimators.rover_config import RoverEstimatorConfig
from terrain_estimation.estimators.rover_noise import nearest_covariance, split_covariance
from terrain_estimation.estimators.rover_windows import WindowMeans
from terrain_estimation.filters.base import Array
from terrain_estimation.models.rover import carrier_angles
from terrain_estimation.models.rover_estimators import (
    GeneralIndex,
    configuration,
    propagate_covariance,
    synthesised_perpendicular_forces,
)

__all__ = ["perpendicular_measurement"]

_G = GeneralIndex


def perpendicular_measurement(
    cfg: RoverEstimatorConfig, m: WindowMeans, x1: Array, P1: Array, gamma: Array, gamma_cov: Array
) -> tuple[Array, Array | None, Array | None]:
    """(F̌_⊥, its covariance, the split error's variances) of a window; (measured F_⊥, None, None) for Estimator 2.

    The propagation takes Estimator 1's covariance of M_1fw, F_xfw, θ, q1
    (``x1``, ``P1``), the load-cell noise and (terrain-frame split,
    ``perpendicular_split = "terrain"``) the covariance of γ̌; the
    cross-covariance of γ̌ with θ, q1 is left out. The terrain-frame split adds
    its own error (:func:`~terrain_estimation.estimators.rover_noise.split_covariance`),
    whose variances are returned too (None with the other split).
    """
    if cfg.load_cell_axes == 2:
        return m.perpendicular_force, None, None
    p = cfg.rover
    terrain = cfg.perpendicular_split == "terrain"
    idx = [_G.BOGIE_MOMENT, _G.FORCE_X, _G.PITCH, _G.BOGIE]
    mean = np.concatenate([x1[idx], m.axial_force, gamma])
    cov = np.zeros((10, 10))
    cov[:4, :4] = nearest_covariance(P1[np.ix_(idx, idx)])
    cov[4:7, 4:7] = np.diag(cfg.sensor_noise.load_cell**2 / m.cell_n)
    if terrain:
        cov[7:, 7:] = gamma_cov

    def perp_of(v: Array) -> Array:
        e = carrier_angles(p, configuration(v[2], v[3]))
        return synthesised_perpendicular_forces(p, v[4:7], v[0], v[1], e, v[7:10] if terrain else None)

    perp_cov = propagate_covariance(perp_of, mean, cov)
    if terrain:
        split = split_covariance(m.axial_force, x1[_G.SLIP], np.diag(P1)[_G.SLIP], cfg.split_traction_slope)
        return perp_of(mean), perp_cov + split, np.diag(split).copy()
    return perp_of(mean), perp_cov, None
