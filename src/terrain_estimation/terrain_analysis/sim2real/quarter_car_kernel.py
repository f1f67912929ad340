"""The replay's compiled quarter-car / LRV plant (:mod:`~terrain_analysis.sim2real.quarter_car`).

Forces of the 2-DOF quarter car and the 1-DOF LRV with every catalogue effect
that acts on the dynamics (suspension friction, tire damping, wheel lift-off,
the soil's curvature in series with the tire spring), and their RK4
integration over the road grid, all JIT-compiled. The parameter vector's
layout is :meth:`QuarterCarReplay`'s (``p[:14]``, see :func:`_forces`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.jit import compiled

FloatArray = NDArray[np.float64]

FRICTION_VELOCITY_SCALE = 0.02  # m/s, as vehicle_sim.plants.quarter_car


@compiled
def _soil_force(u: float, a: float, lam: float) -> tuple[float, float]:  # pragma: no cover
    """(G, dG/du) of the soil force F − W = W G(u), stiffness k_s s(u), s = (1 + λ a u)^(1/λ).

    The power-law family through the static point (u = 0, s = 1, s' = a)
    written regularly in (a, λ): Bekker's n = 1 + 1/λ with its origin
    1/(λ a) static sinkages away; λ → 0 is the exponential law e^(a u),
    a → 0 the linear soil. Past the law's origin (1 + λ a u ≤ 0) the force
    continues oddly when its exponent n > 0 (as the plant's), and with the
    stiffness at 1 + λ a u = 1e-6 when n ≤ 0 (a soil that locks).
    """
    if abs(a) < 1e-12:
        return u, 1.0
    if abs(lam) < 1e-9:
        e = math.exp(a * u)
        return math.expm1(a * u) / a, e
    base = 1.0 + lam * a * u
    inv = 1.0 / lam
    if abs(lam + 1.0) < 1e-9:  # n = 0: s = 1/(1 − a u), G = −ln(1 − a u)/a
        edge = 1e-6
        if base > edge:
            return -math.log(base) / a, 1.0 / base
        g_edge = -math.log(edge) / a
        u_edge = (edge - 1.0) / (lam * a)
        return g_edge + (u - u_edge) / edge, 1.0 / edge
    power = 1.0 + inv
    scale = a * (1.0 + lam)
    if base > 0.0:
        return (base**power - 1.0) / scale, base**inv
    if power > 0.0:
        mag = -base
        return (-(mag**power) - 1.0) / scale, mag**inv
    edge = 1e-6
    u_edge = (edge - 1.0) / (lam * a)
    slope = edge**inv
    return (edge**power - 1.0) / scale + slope * (u - u_edge), slope


@compiled
def _bracket_end(
    u: float, step: float, up: bool, ratio: float, target: float, a: float, lam: float
) -> float:  # pragma: no cover
    """The far end of the Newton bracket of :func:`_chain_force`: from ``u`` (where
    g(u) = (k_s/k) G(u) + u − D/z₀ has the other sign) by ``step``, doubled until g changes sign."""
    if up:  # g(u) < 0: the bracket's right end
        right = u + step
        while ratio * _soil_force(right, a, lam)[0] + right - target < 0.0:
            step *= 2.0
            right += step
        return right
    left = u - step
    while ratio * _soil_force(left, a, lam)[0] + left - target > 0.0:
        step *= 2.0
        left -= step
    return left


@compiled
def _chain_force(
    deflection: float, series: float, k_s: float, load: float, a: float, lam: float
) -> float:  # pragma: no cover
    """Dynamic force (N) of a spring ``series`` in series with the power-law soil about its static point.

    The soil's stiffness is k_s s(u) for a compression δ = u z₀ beyond the
    static point, z₀ = W/k_s (``k_s`` the fitted nuisance: the stiffness at
    the static point), F_s = W + W G(u) (:func:`_soil_force`): a > 0 stiffens
    and a < 0 softens under extra load, λ sets the law's higher orders.
    The chain's compression D = (F_s − W)/k + δ is solved for u by
    safeguarded Newton on g(u) = (k_s/k) G(u) + u − D/z₀, increasing in u,
    from the linear chain's answer u₀. The bracket [left, right] starts at u₀
    on one side and, on the other, at u₀ ± step doubled until g changes sign
    (:func:`_bracket_end`); that far end is found only when a Newton step
    needs it (it lies beyond u₀ ± step, so a step short of that is inside):
    the iterates are those of the eager bracket, number for number.
    """
    ratio = k_s / series
    target = deflection * k_s / load
    u = target / (1.0 + ratio)  # the linear chain's answer
    step = max(0.5, abs(u))
    g, slope = _soil_force(u, a, lam)
    f = ratio * g + u - target
    if f == 0.0:
        return load * g
    up = f < 0.0  # the far end is the right one (NaN: the left one, as the eager search)
    u0 = u
    near = u + step if up else u - step  # the far end lies at or beyond this
    far_known = False
    left = u if up else near
    right = near if up else u
    for i in range(60):
        if i > 0:
            g, slope = _soil_force(u, a, lam)
            f = ratio * g + u - target
            if f == 0.0:
                break
        if f < 0.0:
            left = u
            far_known = far_known or not up
        else:
            right = u
            far_known = far_known or up
        u_new = u - f / (ratio * slope + 1.0)
        short = u_new < near if up else u_new > near  # then inside the far end, wherever it lies
        if not (far_known or (short and left < u_new < right)):
            far_known = True
            far = _bracket_end(u0, step, up, ratio, target, a, lam)
            if up:
                right = far
            else:
                left = far
        if not (left < u_new < right):
            u_new = 0.5 * (left + right)
        if abs(u_new - u) <= 1e-12 * max(1.0, abs(u)):
            u = u_new
            break
        u = u_new
    return load * _soil_force(u, a, lam)[0]


@compiled
def _forces(
    y1: float,
    v1: float,
    y2: float,
    v2: float,
    h: float,
    hd: float,
    p: FloatArray,
) -> tuple[float, float]:  # pragma: no cover
    """(ÿ1, ÿ2) of the 2-DOF model (``two_dof`` = p[12] > 0) or (ÿ1, 0) of the LRV."""
    m1, m2, k, c, series, k_s, load, stiffening, liftoff, fric, ct, ground_damper, two_dof, shape = p[:14]
    kt = series * k_s / (series + k_s)
    if two_dof > 0.0:
        dv = v2 - v1
        suspension = k * (y2 - y1) + c * dv
        if fric > 0.0:
            suspension += fric * math.tanh(dv / FRICTION_VELOCITY_SCALE)
        if stiffening != 0.0:
            ground = _chain_force(h - y2, series, k_s, load, stiffening, shape)
        else:
            ground = kt * (h - y2)
        if ct > 0.0:
            ground += ct * (hd - v2)
        if liftoff > 0.0 and ground < -load:
            ground = -load
        return suspension / m1, (ground - suspension) / m2
    if stiffening != 0.0:
        spring = _chain_force(h - y1, series, k_s, load, stiffening, shape)
    else:
        spring = kt * (h - y1)
    if ground_damper > 0.0:
        ground = spring + c * (hd - v1)
        sky = 0.0
    else:
        ground = spring
        sky = -c * v1
    if liftoff > 0.0 and ground < -load:
        ground = -load
    return (ground + sky) / m1, 0.0


@compiled
def _simulate(
    h: FloatArray, hd: FloatArray, dt: float, p: FloatArray
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover
    """RK4 over the road grid from rest at h[0]; accelerations at every grid point."""
    n = h.size
    a1 = np.empty(n)
    a2 = np.empty(n)
    y1 = h[0]
    y2 = h[0]
    v1 = 0.0
    v2 = 0.0
    half = 0.5 * dt
    sixth = dt / 6.0
    for i in range(n):
        k1a, k1b = _forces(y1, v1, y2, v2, h[i], hd[i], p)
        a1[i] = k1a
        a2[i] = k1b
        if i == n - 1:
            break
        hm = 0.5 * (h[i] + h[i + 1])
        hdm = 0.5 * (hd[i] + hd[i + 1])
        p1, q1 = v1 + half * k1a, v2 + half * k1b
        k2a, k2b = _forces(y1 + half * v1, p1, y2 + half * v2, q1, hm, hdm, p)
        p2, q2 = v1 + half * k2a, v2 + half * k2b
        k3a, k3b = _forces(y1 + half * p1, p2, y2 + half * q1, q2, hm, hdm, p)
        p3, q3 = v1 + dt * k3a, v2 + dt * k3b
        k4a, k4b = _forces(y1 + dt * p2, p3, y2 + dt * q2, q3, h[i + 1], hd[i + 1], p)
        y1 += sixth * (v1 + 2.0 * p1 + 2.0 * p2 + p3)
        y2 += sixth * (v2 + 2.0 * q1 + 2.0 * q2 + q3)
        v1 += sixth * (k1a + 2.0 * k2a + 2.0 * k3a + k4a)
        v2 += sixth * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
        if not (math.isfinite(y1) and math.isfinite(y2) and abs(y1) < 1e3 and abs(y2) < 1e3):
            a1[i + 1 :] = 0.0
            a2[i + 1 :] = 0.0
            break
    return a1, a2
