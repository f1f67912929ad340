"""Global polynomial surrogate of the Wong–Reece wheel, as the rocker-bogie simulator uses it.

Setterfield & Ellery ([RB] section II-E, MODELS.md C.2, D.3): DP(i, W) and
τ_R(i, W) of the full model (:mod:`vehicle_sim.terrain.wong_reece`) are
computed on a 100×100 grid over 0 ≤ i ≤ 1, 0.1 ≤ W ≤ 200 N and fitted with
4th-order 2-D polynomials (equal weights), which the simulation evaluates
instead of solving eq. 7 at every step. The paper reports RMS errors of
0.1080 N (DP) and 0.008033 N·m (τ_R) over that grid; :attr:`TerramechanicsSurrogate.drawbar_pull_rms`
and :attr:`~TerramechanicsSurrogate.resistive_torque_rms` are this code's own.

The fit is computed at first use (≈ 0.2 s on one free core, ≈ 0.5 s on a
busy 2-core machine: one vectorised solve of the grid and two least-squares
fits) and cached in memory per (soil, wheel, settings); nothing is read from
or written to disk.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from terrain_estimation.models.terrain_response import PolynomialModel2D, fit_polynomial_2d
from vehicle_sim.terrain.wong_reece import (
    DEFAULT_SIMPSON_POINTS,
    KAPVIK_WHEEL,
    TABLE_II_SOIL,
    RigidWheel,
    WongReeceSoil,
    wheel_forces,
)

Array = NDArray[np.float64]

__all__ = [
    "SURROGATE_GRID_POINTS",
    "SURROGATE_LOAD_RANGE",
    "SURROGATE_ORDER",
    "SURROGATE_SLIP_RANGE",
    "TerramechanicsSurrogate",
    "fit_terramechanics_surrogate",
    "surrogate_grid",
    "terramechanics_surrogate",
]

SURROGATE_ORDER = 4
"""Polynomial order of the global surrogate ([RB] II-E)."""

SURROGATE_SLIP_RANGE = (0.0, 1.0)
"""Slip range of the fitting grid (–)."""

SURROGATE_LOAD_RANGE = (0.1, 200.0)
"""Load range of the fitting grid (N)."""

SURROGATE_GRID_POINTS = 100
"""Grid points per axis (100×100 = 10 000 samples)."""


@dataclass(frozen=True, kw_only=True)
class TerramechanicsSurrogate:
    """Polynomial DP(i, W), τ_R(i, W) fitted to the Wong–Reece wheel, with its own accuracy.

    Attributes:
        drawbar_pull: DP model (N), valid over the fitting grid.
        resistive_torque: τ_R model (N·m).
        drawbar_pull_rms: RMS of surrogate − full model over the grid (N).
        resistive_torque_rms: the same for τ_R (N·m).
        drawbar_pull_range: (min, max) of the full model's DP on the grid (N).
        resistive_torque_range: (min, max) of the full model's τ_R (N·m).
        soil, wheel: the full model's parameters.
    """

    drawbar_pull: PolynomialModel2D
    resistive_torque: PolynomialModel2D
    drawbar_pull_rms: float
    resistive_torque_rms: float
    drawbar_pull_range: tuple[float, float]
    resistive_torque_range: tuple[float, float]
    soil: WongReeceSoil
    wheel: RigidWheel

    def wheel_forces(self, load: ArrayLike, slip: ArrayLike) -> tuple[Array, Array]:
        """(DP (N), τ_R (N·m)) at the broadcast (W, i).

        Skid (i < 0) by the anti-symmetry of [RB] eqs. 10–11 applied to the
        polynomials, as for the full model. A wheel without load (W ≤ 0, lifted
        off) gets no force [recon]; loads in (0, 0.1) N and above 200 N or
        |i| > 1 extrapolate the polynomial.
        """
        load_, slip_ = np.broadcast_arrays(np.asarray(load, dtype=float), np.asarray(slip, dtype=float))
        magnitude = np.abs(slip_)
        dp = self.drawbar_pull.evaluate(magnitude, load_)
        tau = self.resistive_torque.evaluate(magnitude, load_)
        skid = slip_ < 0.0
        if np.any(skid):
            dp = np.where(skid, -dp + 2.0 * self.drawbar_pull.evaluate(0.0, load_), dp)  # eq. 10
            tau = np.where(skid, -tau + 2.0 * self.resistive_torque.evaluate(0.0, load_), tau)  # eq. 11
        in_contact = load_ > 0.0
        return np.where(in_contact, dp, 0.0), np.where(in_contact, tau, 0.0)


def surrogate_grid(grid_points: int = SURROGATE_GRID_POINTS) -> tuple[Array, Array]:
    """(slip, load) meshes of the fitting grid over [RB]'s 0 ≤ i ≤ 1, 0.1 ≤ W ≤ 200 N, shape (n, n)."""
    slip = np.linspace(*SURROGATE_SLIP_RANGE, grid_points)
    load = np.linspace(*SURROGATE_LOAD_RANGE, grid_points)
    load_mesh, slip_mesh = np.meshgrid(load, slip, indexing="ij")
    return slip_mesh, load_mesh


def fit_terramechanics_surrogate(
    soil: WongReeceSoil = TABLE_II_SOIL,
    wheel: RigidWheel = KAPVIK_WHEEL,
    *,
    order: int = SURROGATE_ORDER,
    grid_points: int = SURROGATE_GRID_POINTS,
    simpson_points: int = DEFAULT_SIMPSON_POINTS,
) -> TerramechanicsSurrogate:
    """Fit the surrogate to the full model on the grid.

    Uncached; :func:`terramechanics_surrogate` is this function cached in
    memory, the surrogate for (soil, wheel) fitted at first use.

    Raises:
        vehicle_sim.terrain.wong_reece.WheelOverloadError: the wheel cannot
            carry 200 N with θ0 ≤ π/2 in this soil.
    """
    slip, load = surrogate_grid(grid_points)
    truth = wheel_forces(load, slip, soil, wheel, simpson_points=simpson_points)
    dp_model = fit_polynomial_2d(slip, load, truth.drawbar_pull, order).model
    tau_model = fit_polynomial_2d(slip, load, truth.resistive_torque, order).model
    return TerramechanicsSurrogate(
        drawbar_pull=dp_model,
        resistive_torque=tau_model,
        # The fit's residual over its own grid is the paper's "RMS error over the 10 000 points".
        drawbar_pull_rms=dp_model.residual_rms(slip, load, truth.drawbar_pull),
        resistive_torque_rms=tau_model.residual_rms(slip, load, truth.resistive_torque),
        drawbar_pull_range=(float(truth.drawbar_pull.min()), float(truth.drawbar_pull.max())),
        resistive_torque_range=(float(truth.resistive_torque.min()), float(truth.resistive_torque.max())),
        soil=soil,
        wheel=wheel,
    )


terramechanics_surrogate = functools.lru_cache(maxsize=8)(fit_terramechanics_surrogate)
"""The surrogate for (soil, wheel), fitted at first use and cached in memory.

:func:`fit_terramechanics_surrogate` behind an LRU cache of 8 entries: same
arguments, and a repeated call returns the same object.
"""
