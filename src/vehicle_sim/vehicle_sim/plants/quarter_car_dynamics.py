"""Equations of motion of the soil-stiffness plant and their RK4 integration (eq. 2, MODELS.md A.7).

Scalar code: a few floats per stage, called ~10⁴ times per simulated second.
The model, its coordinates and the contact: :mod:`vehicle_sim.plants.quarter_car`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from vehicle_sim.plants.quarter_car_effects import FRICTION_VELOCITY_SCALE
from vehicle_sim.plants.quarter_car_vehicles import LRVVehicle, QuarterCarVehicle
from vehicle_sim.terrain.soils import k_tot


def _rk4_two_dof(
    accelerations: Callable[[float, float, float, float, int], tuple[float, float]],
    state: tuple[float, float, float, float],
    substeps: int,
    dt: float,
    record: list[tuple[float, float]] | None = None,
) -> tuple[float, float, float, float]:
    """Classical RK4 of (y1, v1, y2, v2) over ``substeps`` steps of ``dt``.

    ``accelerations(y1, v1, y2, v2, j)`` gives (ÿ1, ÿ2) with the road and
    stiffness at half-step index ``j`` (2i, 2i + 1, 2i + 2 for step i).
    ``record``, if given, receives (ÿ1, ÿ2) at the start of every step.
    """
    y1, v1, y2, v2 = state
    half, sixth = 0.5 * dt, dt / 6.0
    for i in range(substeps):
        j = 2 * i
        a1, b1 = accelerations(y1, v1, y2, v2, j)
        if record is not None:
            record.append((a1, b1))
        p1, q1 = v1 + half * a1, v2 + half * b1
        a2, b2 = accelerations(y1 + half * v1, p1, y2 + half * v2, q1, j + 1)
        p2, q2 = v1 + half * a2, v2 + half * b2
        a3, b3 = accelerations(y1 + half * p1, p2, y2 + half * q1, q2, j + 1)
        p3, q3 = v1 + dt * a3, v2 + dt * b3
        a4, b4 = accelerations(y1 + dt * p2, p3, y2 + dt * q2, q3, j + 2)
        y1 += sixth * (v1 + 2.0 * p1 + 2.0 * p2 + p3)
        y2 += sixth * (v2 + 2.0 * q1 + 2.0 * q2 + q3)
        v1 += sixth * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        v2 += sixth * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
    return y1, v1, y2, v2


def _rk4_one_dof(
    acceleration: Callable[[float, float, int], float],
    state: tuple[float, float],
    substeps: int,
    dt: float,
    record: list[tuple[float, float]] | None = None,
) -> tuple[float, float]:
    """Classical RK4 of (y1, v1); ``acceleration(y1, v1, j)`` and ``record`` as in :func:`_rk4_two_dof`."""
    y1, v1 = state
    half, sixth = 0.5 * dt, dt / 6.0
    for i in range(substeps):
        j = 2 * i
        a1 = acceleration(y1, v1, j)
        if record is not None:
            record.append((a1, 0.0))
        p1 = v1 + half * a1
        a2 = acceleration(y1 + half * v1, p1, j + 1)
        p2 = v1 + half * a2
        a3 = acceleration(y1 + half * p1, p2, j + 1)
        p3 = v1 + dt * a3
        a4 = acceleration(y1 + dt * p2, p3, j + 2)
        y1 += sixth * (v1 + 2.0 * p1 + 2.0 * p2 + p3)
        v1 += sixth * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return y1, v1


def _lrv_ground_force(
    y1: float, v1: float, h: float, h_rate: float, kt: float, vehicle: LRVVehicle
) -> tuple[float, float]:
    """(dynamic ground force F_d, damper force acting on the body from outside the contact)."""
    if vehicle.damper_reference == "ground":
        return kt * (h - y1) + vehicle.damping * (h_rate - v1), 0.0
    return kt * (h - y1), -vehicle.damping * v1


def _bekker_chain_force(
    deflection: float, series_stiffness: float, k_s: float, load: float, n: float, origin: float = 1.0
) -> float:
    """Dynamic force F_d (N) of a linear spring in series with the Bekker-type soil.

    The chain carries the total force F = W + F_d; the spring deflects by F/k.
    The soil (:class:`QuarterCarEffects` ``soil_exponent`` n, ``soil_origin_ratio`` ζ)
    compresses beyond static by δ = ζ z₀ (σ(1 + (F/W − 1)/ζ)^(1/n) − 1)
    (σ: odd continuation), z₀ = W/k_s; ζ = 1: z = z₀ σ(F/W)^(1/n).
    Solves (F − W)/k + δ = deflection, deflection the chain's compression
    beyond static (h − y), by safeguarded Newton in x = F/W (the left side
    increases strictly with x).
    """
    if load <= 0.0:
        # No static sinkage to scale the law around: fall back to the linear chain.
        return float(k_tot(k_s, series_stiffness)) * deflection
    ratio = k_s / series_stiffness  # (k_s/k): the spring's share in units of z₀
    target = deflection * k_s / load  # deflection / z₀
    inv_n = 1.0 / n
    zeta = origin

    def residual(x: float) -> float:
        if zeta == 1.0:
            root = abs(x) ** inv_n
            return ratio * (x - 1.0) + math.copysign(root, x) - 1.0 - target
        u = 1.0 + (x - 1.0) / zeta
        return ratio * (x - 1.0) + zeta * (math.copysign(abs(u) ** inv_n, u) - 1.0) - target

    x = 1.0 + target / (1.0 + ratio)  # the linear chain's answer
    f = residual(x)
    if f == 0.0:
        return load * (x - 1.0)
    # Bracket the root by doubling steps away from the linear guess.
    step = max(1.0, abs(x))
    lo, hi = (x, x + step) if f < 0.0 else (x - step, x)
    while residual(lo) > 0.0:
        step *= 2.0
        lo -= step
    while residual(hi) < 0.0:
        step *= 2.0
        hi += step
    for _ in range(100):
        f = residual(x)
        if f == 0.0:
            break
        if f < 0.0:
            lo = x
        else:
            hi = x
        ax = abs(1.0 + (x - 1.0) / zeta) if zeta != 1.0 else abs(x)
        slope = ratio + inv_n * ax ** (inv_n - 1.0) if ax > 0.0 else math.inf
        x_new = x - f / slope if math.isfinite(slope) else 0.5 * (lo + hi)
        if not lo < x_new < hi:
            x_new = 0.5 * (lo + hi)
        if abs(x_new - x) <= 1e-13 * max(1.0, abs(x)):
            x = x_new
            break
        x = x_new
    return load * (x - 1.0)


@dataclass(frozen=True)
class _Dynamics:
    """The effects that change the equations of motion, resolved for one simulator."""

    soil_exponent: float  # 0: linear soil
    friction: float  # F_c (N)
    tire_damping: float  # c_t (N·s/m)
    soil_origin: float = 1.0  # ζ of the nonlinear soil

    def ground(self, deflection: float, kt: float, k_s: float, series: float, load: float) -> float:
        """Spring part of the dynamic ground force (N) for chain compression ``deflection`` (m)."""
        if self.soil_exponent:
            return _bekker_chain_force(deflection, series, k_s, load, self.soil_exponent, self.soil_origin)
        return kt * deflection


def _two_dof_forces(
    y1: float,
    v1: float,
    y2: float,
    v2: float,
    h: float,
    h_rate: float,
    kt: float,
    k_s: float,
    vehicle: QuarterCarVehicle,
    load: float,
    dynamics: _Dynamics,
) -> tuple[float, float]:
    """(suspension force on the body, dynamic ground force F_d before lift-off) in N."""
    dv = v2 - v1
    suspension = vehicle.suspension_stiffness * (y2 - y1) + vehicle.suspension_damping * dv
    if dynamics.friction:
        suspension += dynamics.friction * math.tanh(dv / FRICTION_VELOCITY_SCALE)
    ground = dynamics.ground(h - y2, kt, k_s, vehicle.tire_stiffness, load)
    if dynamics.tire_damping:
        ground += dynamics.tire_damping * (h_rate - v2)
    return suspension, ground


def _lrv_forces(
    y1: float,
    v1: float,
    h: float,
    h_rate: float,
    kt: float,
    k_s: float,
    vehicle: LRVVehicle,
    load: float,
    dynamics: _Dynamics,
) -> tuple[float, float]:
    """:func:`_lrv_ground_force` with the nonlinear soil."""
    if not dynamics.soil_exponent:
        return _lrv_ground_force(y1, v1, h, h_rate, kt, vehicle)
    spring = dynamics.ground(h - y1, kt, k_s, vehicle.combined_stiffness, load)
    if vehicle.damper_reference == "ground":
        return spring + vehicle.damping * (h_rate - v1), 0.0
    return spring, -vehicle.damping * v1


def _advance(
    state: tuple[float, ...],
    road: list[float],
    road_rate: list[float],
    stiffness: list[float],
    soil_stiffness: list[float],
    substeps: int,
    dt: float,
    vehicle: QuarterCarVehicle | LRVVehicle,
    static_load: float,
    liftoff: bool,
    dynamics: _Dynamics | None,
    record: list[tuple[float, float]] | None = None,
) -> tuple[float, ...]:
    """RK4 over ``substeps`` steps; road, its rate, k_tot and k_s given at every half step.

    The 2-DOF quarter car (eq. 2, state (y1, ẏ1, y2, ẏ2)) or the 1-DOF LRV
    (MODELS.md A.7, state (y1, ẏ1)). ``dynamics`` None is the linear model
    (the arithmetic of the paper's equations, bit for bit); otherwise
    nonlinear soil, suspension friction and/or tire damping
    (:func:`_two_dof_forces`, :func:`_lrv_forces`).
    """
    floor = -static_load
    if isinstance(vehicle, QuarterCarVehicle):
        m1, m2 = vehicle.sprung_mass, vehicle.unsprung_mass
        k, c = vehicle.suspension_stiffness, vehicle.suspension_damping

        def accelerations(y1: float, v1: float, y2: float, v2: float, j: int) -> tuple[float, float]:
            if dynamics is None:
                suspension = k * (y2 - y1) + c * (v2 - v1)
                ground = stiffness[j] * (road[j] - y2)
            else:
                suspension, ground = _two_dof_forces(
                    y1,
                    v1,
                    y2,
                    v2,
                    road[j],
                    road_rate[j],
                    stiffness[j],
                    soil_stiffness[j],
                    vehicle,
                    static_load,
                    dynamics,
                )
            if liftoff and ground < floor:
                ground = floor
            return suspension / m1, (ground - suspension) / m2

        return _rk4_two_dof(accelerations, state, substeps, dt, record)  # type: ignore[arg-type]

    lrv = vehicle
    m = lrv.sprung_mass

    def acceleration(y1: float, v1: float, j: int) -> float:
        if dynamics is None:
            ground, skyhook = _lrv_ground_force(y1, v1, road[j], road_rate[j], stiffness[j], lrv)
        else:
            ground, skyhook = _lrv_forces(
                y1, v1, road[j], road_rate[j], stiffness[j], soil_stiffness[j], lrv, static_load, dynamics
            )
        if liftoff and ground < floor:
            ground = floor
        return (ground + skyhook) / m

    return _rk4_one_dof(acceleration, state, substeps, dt, record)  # type: ignore[arg-type]
