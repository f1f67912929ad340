"""Estimators 2 and 3 of the rover: the wheel-force model ([RB] eqs. 75–89).

:class:`WheelForceModel` (9 random-walk states: contact angles, normal
loads, drawbar pulls; 9 measurements: γ̌ and the load cells), its
measurement variances and its start from one step's measurements;
re-exported by :mod:`terrain_estimation.models.rover_estimators`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from terrain_estimation.filters.base import Array
from terrain_estimation.models.rover_estimator_noise import (
    MeasurementErrorFloors,
    SensorNoise,
    StepNoiseModel,
    WheelForceProcessNoise,
)

__all__ = [
    "WheelForceModel",
    "initial_wheel_force_state",
    "wheel_force_measurement_variances",
]


class WheelForceModel(StepNoiseModel):
    """Estimators 2 and 3: 9 random-walk states (eq. 75), 9 measurements (eqs. 78, 85).

    ``u`` of ``h`` is the carrier angles ε (3,) of the step (eqs. 81–82: θ̂ + q̂1
    for the bogie wheels, θ̂ for the front wheel), from Estimator 1.

    Args:
        process_noise: Q per ``step_s``.
        step_s: T_e (s).
        r_diag: default measurement variances (9,); the estimator overrides R per step.
    """

    STATE_DIM = 9
    MEASUREMENT_DIM = 9

    def __init__(
        self,
        *,
        process_noise: WheelForceProcessNoise | None = None,
        step_s: float = 0.2,
        r_diag: ArrayLike | None = None,
    ) -> None:
        self.process_noise = process_noise if process_noise is not None else WheelForceProcessNoise()
        self._set_step(step_s)
        r = (
            np.array([MeasurementErrorFloors().contact_angle ** 2] * 3 + [SensorNoise().load_cell ** 2 / 10.0] * 6)
            if r_diag is None
            else np.asarray(r_diag, dtype=float)
        )
        self._set_measurement_noise(r, r_diag)
        self._q_sigma = self.process_noise.sigma()

    def f(self, x: Array, u: Any, dt: float) -> Array:
        """Random walk (eqs. 77, 84): x_{k+1} = x_k."""
        out: Array = np.array(x, dtype=float)
        return out

    def h(self, x: Array, u: Any) -> Array:
        """h2 = h3 (eqs. 80–82, 89): ``(9,)``/``(m, 9)`` → same shape; ``u`` = carrier angles ε (3,).

        ::

            γ̂_j  = γ_j                                           (80)
            F̂_Lj = W_j cos(γ_j − ε_j) − DP_j sin(γ_j − ε_j)        (81)
            F̂_⊥j = W_j sin(γ_j − ε_j) + DP_j cos(γ_j − ε_j)        (82)
        """
        eps = np.asarray(u, dtype=float)
        if eps.shape != (3,) or not np.isfinite(eps).all():
            raise ValueError(f"u must be the 3 finite carrier angles ε, got {u!r}")
        xs = np.asarray(x, dtype=float)
        gamma, load, pull = xs[..., 0:3], xs[..., 3:6], xs[..., 6:9]
        delta = gamma - eps
        c, s = np.cos(delta), np.sin(delta)
        out: Array = np.concatenate([gamma, load * c - pull * s, load * s + pull * c], axis=-1)
        return out

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        """diag(σ √(dt/step_s)) (:class:`WheelForceProcessNoise`)."""
        return self.random_walk_factor(self._q_sigma, dt)


def wheel_force_measurement_variances(
    *,
    contact_angle_cov: ArrayLike,
    noise: SensorNoise,
    floors: MeasurementErrorFloors,
    load_cell_samples: ArrayLike,
    synthesised_cov: ArrayLike | None = None,
) -> Array:
    """Diagonal of R2/R3 (eq. 78 order), shape (9,).

    Args:
        contact_angle_cov: covariance of γ̌ propagated from Estimator 1 (3, 3)
            (only its diagonal is used: R is diagonal).
        noise, floors: sensor σ and model-error floors.
        load_cell_samples: samples averaged per wheel (3,).
        synthesised_cov: covariance of Estimator 3's synthesised F̌_⊥ (3, 3);
            None: measured two-axis cells (Estimator 2).
    """
    n = np.asarray(load_cell_samples, dtype=float)
    gamma_var = np.diag(np.asarray(contact_angle_cov, dtype=float)) + floors.contact_angle**2
    cell_var = noise.load_cell**2 / n + floors.load_cell**2
    if synthesised_cov is None:
        perp_var = cell_var
    else:
        perp_var = np.diag(np.asarray(synthesised_cov, dtype=float)) + floors.synthesised_force**2
    return np.concatenate([gamma_var, cell_var, perp_var])


def initial_wheel_force_state(
    contact_angle: ArrayLike, axial_force: ArrayLike, perpendicular_force: ArrayLike, carrier_angle: ArrayLike
) -> Array:
    """x2 from one step's measurements: γ̌ and (W, DP) by the inverse rotation of eqs. 81–82, shape (9,)."""
    gamma = np.asarray(contact_angle, dtype=float)
    f_l = np.asarray(axial_force, dtype=float)
    f_p = np.asarray(perpendicular_force, dtype=float)
    delta = gamma - np.asarray(carrier_angle, dtype=float)
    c, s = np.cos(delta), np.sin(delta)
    return np.concatenate([gamma, f_l * c + f_p * s, -f_l * s + f_p * c])
