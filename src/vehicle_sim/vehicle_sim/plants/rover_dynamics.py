"""The rover's constrained dynamics (eq. 32), their RK4 integration and the start configuration.

Equations, constraint, contact angle and step sizes: the plant docstring,
that of :mod:`vehicle_sim.plants.rover`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.lapack import dgesv

from terrain_estimation.models.rover import RoverParams, dynamics_terms, slip_from_motion_scalar
from vehicle_sim.plants.rover_paths import WheelPath
from vehicle_sim.plants.rover_scenario import N_WHEELS as _N_WHEELS
from vehicle_sim.plants.rover_scenario import RoverScenario
from vehicle_sim.plants.rover_terramechanics import _ForceModel, _sinkage_motion

__all__ = ["solve_configuration"]

Array = NDArray[np.float64]

_STATE_SIZE = 14  # [g (7), ġ (7)]
#: Largest λ Δt of the slip modes per RK4 step (RK4 is stable to 2.78 on the negative real axis).
_SLIP_MODE_STEP_LIMIT = 1.5


# ---------------------------------------------------------------------------
# Equations of motion (eq. 32)
# ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Evaluation:
    g_ddot: Array
    vertical_reaction: Array
    slip: Array
    drawbar_pull: Array
    resistive_torque: Array
    slope: Array
    residual: Array
    centres: Array
    centre_velocity: Array
    tangent_speed: Array
    wheel_rate: Array


class _Equations:
    """Right-hand side of the constrained dynamics for a held :class:`_ForceModel`."""

    def __init__(self, scenario: RoverScenario, path: WheelPath) -> None:
        self.params = scenario.params
        self.path = path
        self.alpha = scenario.baumgarte_alpha
        self.beta = scenario.baumgarte_beta
        self._system = np.zeros((10, 10))

    def evaluate(self, state: Array, model: _ForceModel, elapsed: float = 0.0) -> _Evaluation:
        """Solve eq. 32 at ``state`` (14,) with the held ``model``, ``elapsed`` (s) into the step; sample quantities."""
        solution, wheels = self._solve(state, model, elapsed)
        return _Evaluation(
            g_ddot=solution[:7],
            vertical_reaction=-solution[7:],
            slip=np.array(wheels["slip"]),
            drawbar_pull=np.array(wheels["dp"]),
            resistive_torque=np.array(wheels["tau"]),
            slope=np.array(wheels["slope"]),
            residual=np.array(wheels["residual"]),
            centres=wheels["centres"],
            centre_velocity=wheels["velocity"],
            tangent_speed=np.array(wheels["tangent_speed"]),
            wheel_rate=np.array(wheels["wheel_rate"]),
        )

    def derivative(self, state: Array, model: _ForceModel, elapsed: float = 0.0) -> Array:
        """d[g, ġ]/dt ``elapsed`` (s) into the step (the sinkage moves with time)."""
        derivative = np.empty(_STATE_SIZE)
        derivative[:7] = state[7:]
        derivative[7:] = self._solve(state, model, elapsed)[0][:7]
        return derivative

    def _solve(self, state: Array, model: _ForceModel, elapsed: float = 0.0) -> tuple[Array, dict[str, Any]]:
        """The bordered system of eq. 32 → ([g̈, −λ], per-wheel quantities).

        Per-wheel work is done in Python floats: with three wheels that is
        several times faster than numpy on (3,) arrays, and this runs four
        times per integration step.
        """
        p = self.params
        g, g_dot = state[:7], state[7:]
        terms = dynamics_terms(p, g, g_dot)
        jac = terms.wheel_jacobian
        centres = terms.wheel_centres
        point = self.path.point
        path_z, slope, second = zip(*(point(x) for x in centres[:, 0].tolist()), strict=True)
        velocity = jac @ g_dot
        vx, vz = velocity[:, 0].tolist(), velocity[:, 1].tolist()
        z = centres[:, 1].tolist()
        bias = terms.wheel_bias.tolist()
        rates = g_dot.tolist()
        carrier_rate = rates[2] + rates[3]
        wheel_rate = (carrier_rate + rates[4], carrier_rate + rates[5], rates[2] + rates[6])
        radius = p.wheel_radius
        two_alpha, beta_squared = 2.0 * self.alpha, self.beta**2
        dp_coefficients = model.drawbar_pull_list
        tau_coefficients = model.resistive_torque_list
        centre = model.centre_list

        residual = [0.0] * 3
        zeta = [0.0] * 3
        slip = [0.0] * 3
        dp = [0.0] * 3
        tau = [0.0] * 3
        tangent_speed = [0.0] * 3
        along = [0.0] * 3
        across = [0.0] * 3
        for j in range(3):
            dz = slope[j]
            # Sinkage s_j(τ) (plant docstring): Ψ_j = z_j − z_wc(x_j) + s_j(τ), whose explicit time
            # dependence adds ṡ to Ψ̇ and s̈ to the constraint acceleration.
            sink, sink_rate, sink_acceleration = _sinkage_motion(*model.sinkage[j], elapsed)
            residual[j] = z[j] - path_z[j] + sink
            residual_rate = vz[j] - dz * vx[j] + sink_rate
            zeta[j] = (
                -(bias[j][1] - dz * bias[j][0] - second[j] * vx[j] ** 2 + sink_acceleration)
                - two_alpha * residual_rate
                - beta_squared * residual[j]
            )
            norm = math.sqrt(1.0 + dz * dz)
            tangent_speed[j] = (vx[j] + dz * vz[j]) / norm
            slip[j] = slip_from_motion_scalar(wheel_rate[j], tangent_speed[j], radius)
            d = slip[j] - centre[j]
            a, b = dp_coefficients[j], tau_coefficients[j]
            dp[j] = a[0] + d * (a[1] + d * a[2])
            tau[j] = b[0] + d * (b[1] + d * b[2])
            # DP along the tangent (cos γ, −sin γ) = (1, z')/√(1 + z'²), eq. 39.
            along[j] = dp[j] / norm
            across[j] = along[j] * dz

        jx, jz = jac[:, 0, :], jac[:, 1, :]
        rhs = (np.dot(along, jx) + np.dot(across, jz) - terms.coriolis - terms.gravity).tolist()
        # −τ_R on the wheels (eq. 36) through their absolute spin; internal drive torque minus damping (eq. 40).
        torque, damping = model.wheel_torque_list, p.wheel_damping
        rhs[2] -= tau[0] + tau[1] + tau[2]
        rhs[3] -= tau[0] + tau[1]
        for j in range(3):
            rhs[4 + j] += torque[j] - damping * rates[4 + j] - tau[j]
        rhs.extend(zeta)

        constraint_jacobian = jz - np.array(slope)[:, None] * jx
        system = self._system
        system[:7, :7] = terms.mass_matrix
        system[:7, 7:] = constraint_jacobian.T
        system[7:, :7] = constraint_jacobian
        # LAPACK dgesv directly: np.linalg.solve's wrapper costs more than the 10×10 solve itself.
        _, _, solution, info = dgesv(system, np.array(rhs))
        if info != 0:
            raise np.linalg.LinAlgError(f"eq. 32 is singular (dgesv info {info}): the constraints are dependent")
        wheels = {
            "slip": slip,
            "dp": dp,
            "tau": tau,
            "slope": slope,
            "residual": residual,
            "centres": centres,
            "velocity": velocity,
            "tangent_speed": tangent_speed,
            "wheel_rate": wheel_rate,
        }
        return solution, wheels

    def stable_step(self, evaluation: _Evaluation, model: _ForceModel) -> float:
        """Largest RK4 step for the slip modes: 1.5/λ, λ ≈ Σ|dDP/di||∂i/∂v|/m + max|dτ_R/di||∂i/∂ω|/I_wg."""
        p = self.params
        rim = p.wheel_radius * np.abs(evaluation.wheel_rate)
        sensitivity = 1.0 / np.maximum(np.maximum(rim, np.abs(evaluation.tangent_speed)), 1e-4)  # |∂i/∂v| (s/m)
        translation = float(np.sum(np.abs(model.drawbar_pull[:, 1]) * sensitivity)) / p.total_mass
        spin = float(np.max(np.abs(model.resistive_torque[:, 1]) * p.wheel_radius * sensitivity)) / (
            p.wheel_gear_inertia
        )
        rate = translation + spin
        return math.inf if rate <= 0.0 else _SLIP_MODE_STEP_LIMIT / rate


def _rk4(equations: _Equations, state: Array, model: _ForceModel, dt: float, steps: int) -> Array:
    half, sixth = 0.5 * dt, dt / 6.0
    for m in range(steps):
        tau = m * dt
        k1 = equations.derivative(state, model, tau)
        k2 = equations.derivative(state + half * k1, model, tau + half)
        k3 = equations.derivative(state + half * k2, model, tau + half)
        k4 = equations.derivative(state + dt * k3, model, tau + dt)
        state = state + sixth * (k1 + 2.0 * (k2 + k3) + k4)
    return state


# ---------------------------------------------------------------------------
# Initial condition
# ---------------------------------------------------------------------------


def solve_configuration(
    params: RoverParams,
    path: WheelPath,
    x0: float,
    *,
    sinkage: ArrayLike | None = None,
    tolerance: float = 1e-13,
    max_iterations: int = 50,
) -> Array:
    """Configuration g with O at x0 and all three wheel centres on the path (Ψ = 0), by Newton on (z0, θ, q1).

    ``sinkage`` (3,) (m, default 0) lowers each wheel centre below the path:
    Ψ_j = z_j − z_wc(x_j) + s_j = 0. Wheel angles are 0. Raises RuntimeError
    if Newton does not converge.
    """
    depth = np.zeros(_N_WHEELS) if sinkage is None else np.asarray(sinkage, dtype=float).reshape(_N_WHEELS)
    g = np.zeros(7)
    g[0] = x0
    level = params.level_wheel_offsets
    g[1] = float(np.mean(path.height(x0 + level[:, 0]) - depth)) - float(np.mean(level[:, 1]))
    for _ in range(max_iterations):
        terms = dynamics_terms(params, g, np.zeros(7))
        x, z = terms.wheel_centres[:, 0], terms.wheel_centres[:, 1]
        path_z, dz, _ = path.evaluate(x)
        residual = z - path_z + depth
        if np.max(np.abs(residual)) < tolerance:
            return g
        jac = terms.wheel_jacobian[:, 1, :] - dz[:, None] * terms.wheel_jacobian[:, 0, :]
        g[1:4] -= np.linalg.solve(jac[:, 1:4], residual)
    raise RuntimeError(f"no configuration with all wheels on the path {path.name!r} at x0 = {x0} m")


def _manifold_direction(params: RoverParams, path: WheelPath, g: Array) -> Array:
    """ġ with ẋ0 = 1, wheel rates 0 and Ψ_g ġ = 0 (motion along the path)."""
    terms = dynamics_terms(params, g, np.zeros(7))
    dz = path.slope(terms.wheel_centres[:, 0])
    jac = terms.wheel_jacobian[:, 1, :] - dz[:, None] * terms.wheel_jacobian[:, 0, :]
    direction = np.zeros(7)
    direction[0] = 1.0
    direction[1:4] = np.linalg.solve(jac[:, 1:4], -jac[:, 0])
    return direction
