"""The rover's soil forces over one control step: terramechanics (Wong–Reece or its surrogate), sinkage, held model.

What is held over a 50 Hz step and why, and how the sinkage moves: the
plant docstring, that of :mod:`vehicle_sim.plants.rover`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vehicle_sim.plants.rover_scenario import N_WHEELS as _N_WHEELS
from vehicle_sim.plants.rover_scenario import RoverScenario
from vehicle_sim.terrain.terramechanics_surrogate import SURROGATE_LOAD_RANGE, terramechanics_surrogate
from vehicle_sim.terrain.wong_reece import RigidWheel, contact_angle, wheel_forces

Array = NDArray[np.float64]

# ---------------------------------------------------------------------------
# Terramechanics per step
# ---------------------------------------------------------------------------


class _Terramechanics:
    """(W, i, soil index) → (DP, τ_R, θ0) with the selected model, vectorised, overload saturated.

    The slip-sinkage and grouser effects act here (plant docstring).
    """

    def __init__(self, scenario: RoverScenario) -> None:
        params = scenario.params
        effects = scenario.effects
        self.slip_sinkage = effects.slip_sinkage_coefficient
        self.grouser_height = effects.grouser_height
        # Slip at the grouser tips: i_g = 1 − (1 − i) r_w/(r_w + h_g).
        self.grouser_speed_ratio = params.wheel_radius / (params.wheel_radius + effects.grouser_height)
        self.wheel = RigidWheel(radius=params.wheel_radius + effects.grouser_height, width=params.wheel_width)
        soils = [scenario.soil]
        if scenario.effects.soil_change_soil is not None:
            soils.append(scenario.effects.soil_change_soil)
        self.soils = tuple(soils)
        self.kind = scenario.terramechanics
        self.simpson_points = scenario.simpson_points
        self._surrogates = (
            tuple(terramechanics_surrogate(soil, self.wheel) for soil in self.soils) if self.kind == "surrogate" else ()
        )

    def __call__(self, load: Array, slip: Array, soil_index: NDArray[np.int_]) -> tuple[Array, Array, Array]:
        load = np.maximum(load, 0.0)
        slip = np.clip(slip, -1.0, 1.0)
        model_load, model_slip = load, slip
        sinkage_scale: Array | None = None
        if self.slip_sinkage > 0.0:
            # k_eff = k/(1 + c|i|): forces at W are (model forces at W (1 + c|i|))/(1 + c|i|).
            sinkage_scale = 1.0 + self.slip_sinkage * np.abs(slip)
            model_load = load * sinkage_scale
        if self.grouser_height > 0.0:
            model_slip = 1.0 - (1.0 - slip) * self.grouser_speed_ratio
        dp = np.zeros_like(load)
        tau = np.zeros_like(load)
        entry = np.full_like(load, math.nan)
        for index in np.unique(soil_index):
            rows = soil_index == index
            if self.kind == "surrogate":
                # Saturated at the fitting grid's upper edge rather than extrapolated.
                capped = np.minimum(model_load[rows], SURROGATE_LOAD_RANGE[1])
                dp[rows], tau[rows] = self._surrogates[index].wheel_forces(capped, model_slip[rows])
            else:
                dp[rows], tau[rows], entry[rows] = self._full_model(
                    wheel_forces, model_load[rows], model_slip[rows], index
                )
        if sinkage_scale is not None:
            dp /= sinkage_scale
            tau /= sinkage_scale
        lifted = load <= 0.0
        dp[lifted] = 0.0
        tau[lifted] = 0.0
        return dp, tau, entry

    def _full_model(self, function: Callable[..., Any], load: Array, slip: Array, index: int) -> Any:
        """``function`` of :mod:`vehicle_sim.terrain.wong_reece` on soil ``index``, this wheel, overload saturated."""
        return function(
            load, slip, self.soils[index], self.wheel, simpson_points=self.simpson_points, overload="saturate"
        )

    def sinkage(self, load: Array, slip: Array, soil_index: NDArray[np.int_]) -> tuple[Array, Array]:
        """Steady sinkage z* (m) of the wheel centre below the undisturbed surface and the contact length (m).

        z* = r_e (1 − cos θ0(W, |i|)) − h_g from the Wong–Reece entry angle θ0 that
        carries the load at the slip (eq. 7; skid at |i|, as the forces of eqs.
        10–11), with the same slip-sinkage scaling and grouser cylinder
        (r_e = r_w + h_g) as the forces: the rim sinks once the grouser tips
        are h_g deep. The contact length is r_e sin θ0. Both models (full and
        surrogate) use the full model's θ0 here: the surrogate gives forces
        only. A lifted wheel (W ≤ 0) has z* = 0.
        """
        load = np.maximum(load, 0.0)
        model_slip = np.abs(np.clip(slip, -1.0, 1.0))
        model_load = load * (1.0 + self.slip_sinkage * model_slip) if self.slip_sinkage > 0.0 else load
        if self.grouser_height > 0.0:
            model_slip = 1.0 - (1.0 - model_slip) * self.grouser_speed_ratio
        theta0 = np.zeros_like(load)
        for index in np.unique(soil_index):
            rows = soil_index == index
            theta0[rows] = self._full_model(contact_angle, model_load[rows], model_slip[rows], index)
        radius = self.wheel.radius
        depth: Array = np.maximum(radius * (1.0 - np.cos(theta0)) - self.grouser_height, 0.0)
        length: Array = radius * np.sin(theta0)
        return depth, length


@dataclass(frozen=True)
class _ForceModel:
    """What is held over one control step: wheel torques, loads and the slip quadratics of DP and τ_R.

    DP(i) = a0 + a1 (i − s) + a2 (i − s)², the same for τ_R, per wheel (evaluated in
    :meth:`_Equations._solve`).
    """

    wheel_torque: Array
    normal_load: Array
    centre: Array
    drawbar_pull: Array  # (3, 3): a0, a1, a2 per wheel
    resistive_torque: Array
    entry_angle: Array
    #: Sinkage over the step per wheel, (s0, ṡ0, z*, ω) of :func:`_sinkage_motion` (plant docstring "Sinkage").
    sinkage: tuple[tuple[float, float, float, float], ...] = ((0.0, 0.0, 0.0, 0.0),) * _N_WHEELS
    wheel_torque_list: list[float] = field(init=False, repr=False)
    centre_list: list[float] = field(init=False, repr=False)
    drawbar_pull_list: list[list[float]] = field(init=False, repr=False)
    resistive_torque_list: list[list[float]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # Plain-float copies for the inner loop of :meth:`_Equations._solve`.
        object.__setattr__(self, "wheel_torque_list", np.asarray(self.wheel_torque, dtype=float).tolist())
        object.__setattr__(self, "centre_list", self.centre.tolist())
        object.__setattr__(self, "drawbar_pull_list", self.drawbar_pull.tolist())
        object.__setattr__(self, "resistive_torque_list", self.resistive_torque.tolist())

    def with_torque(self, torque: Array) -> _ForceModel:
        return replace(self, wheel_torque=torque)

    def sinkage_at(self, elapsed: float) -> tuple[Array, Array]:
        """(s, ṡ) per wheel (m, m/s), ``elapsed`` (s) from the start of the step."""
        motion = [_sinkage_motion(*row, elapsed) for row in self.sinkage]
        return np.array([m[0] for m in motion]), np.array([m[1] for m in motion])

    @classmethod
    def constant(
        cls,
        torque: Array,
        load: Array,
        drawbar_pull: Array,
        resistive_torque: Array,
        sinkage: Array | None = None,
    ) -> _ForceModel:
        zeros = np.zeros(_N_WHEELS)
        depth = zeros if sinkage is None else sinkage
        return cls(
            torque,
            load,
            zeros,
            np.stack([drawbar_pull, zeros, zeros], axis=1),
            np.stack([resistive_torque, zeros, zeros], axis=1),
            np.full(_N_WHEELS, math.nan),
            _static_sinkage(depth),
        )


def _static_sinkage(depth: Array) -> tuple[tuple[float, float, float, float], ...]:
    """Sinkage held at ``depth`` (m) over a step: (s0, ṡ0, z*, ω) = (s, 0, s, 0) per wheel."""
    return tuple((float(d), 0.0, float(d), 0.0) for d in depth)


def _sinkage_motion(
    start: float, rate: float, target: float, omega: float, elapsed: float
) -> tuple[float, float, float]:
    """(s, ṡ, s̈) at ``elapsed`` (s) of s̈ = ω² (z* − s) − 2ω ṡ from (s0, ṡ0) (m, m/s, m/s²).

    Critically damped: e = s − z* = (A + B τ) e^(−ωτ), A = e0, B = ė0 + ω e0. s and ṡ
    stay continuous from step to step (only s̈ changes with the held target), so the
    path constraint never sees a jump of velocity. ω = 0: the sinkage moves at
    constant ṡ0 (0 for a held depth).
    """
    if omega <= 0.0:
        return start + rate * elapsed, rate, 0.0
    a = start - target
    b = rate + omega * a
    decay = math.exp(-omega * elapsed)
    position = a + b * elapsed
    return (
        target + position * decay,
        (b - omega * position) * decay,
        omega * (omega * position - 2.0 * b) * decay,
    )


def _fit_force_model(
    terramechanics: _Terramechanics,
    torque: Array,
    load: Array,
    slip: Array,
    soil_index: NDArray[np.int_],
    stencil: float,
    sinkage: tuple[tuple[float, float, float, float], ...] = ((0.0, 0.0, 0.0, 0.0),) * _N_WHEELS,
) -> _ForceModel:
    """One vectorised terramechanics call at (W, s − δ), (W, s), (W, s + δ) per wheel → quadratics in slip."""
    centre = np.clip(slip, -1.0 + stencil, 1.0 - stencil)
    slips = np.concatenate([centre - stencil, centre, centre + stencil])
    dp, tau, entry = terramechanics(np.tile(load, 3), slips, np.tile(soil_index, 3))

    def quadratic(values: Array) -> Array:
        low, mid, high = values[:_N_WHEELS], values[_N_WHEELS : 2 * _N_WHEELS], values[2 * _N_WHEELS :]
        return np.stack([mid, (high - low) / (2 * stencil), (high - 2 * mid + low) / (2 * stencil**2)], axis=1)

    return _ForceModel(
        torque,
        np.maximum(load, 0.0),
        centre,
        quadratic(dp),
        quadratic(tau),
        entry[_N_WHEELS : 2 * _N_WHEELS],
        sinkage,
    )
