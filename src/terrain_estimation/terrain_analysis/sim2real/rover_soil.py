"""The rover replay's soil: DP(W, i), τ_R(W, i) and the sinkage z*(W, i), and the per-wheel inversion.

:class:`_SoilModel` is the plant's terramechanics surrogate with the catalogue's soil effects (slip-sinkage,
grousers, a changed soil) and the steady sinkage of the same Wong–Reece soil (:class:`_DepthTable`);
:func:`_solve_wheels` finds each wheel's load and slip from its load cell and resistive torque (relation 3 of the
docstring of :mod:`terrain_analysis.sim2real.rover`). How the sinkage moves: :mod:`.rover_sinkage`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.models.rover import RoverParams

FloatArray = NDArray[np.float64]

_LOCAL_ORDER = 4
_FIT_GRID_POINTS = 30  # per axis, of the surrogate fit of a changed soil or grouser wheel
_DEPTH_LOAD_STEP = 1.0  # N, load step of the nominal sinkage table
_DEPTH_SLIP_POINTS = 51  # slips 0, 0.02, …, 1 of the nominal sinkage table


class _Polynomial:
    """Σ c[k, m] |i|^k W^m (k + m ≤ 4) in slip magnitude |i| (–) and load W (N), evaluated by Horner's scheme."""

    def __init__(self, table: FloatArray) -> None:
        self.table = np.asarray(table, dtype=float)
        self.order = self.table.shape[0] - 1

    @classmethod
    def from_model(cls, model: Any) -> _Polynomial:
        """From a :class:`~terrain_estimation.models.terrain_response.PolynomialModel2D` (the plant's surrogate)."""
        table = np.zeros((model.order + 1, model.order + 1))
        for (k, m), c in zip(model.exponents, model.coefficients, strict=True):
            table[k, m] = c
        return cls(table)

    def __add__(self, other: _Polynomial) -> _Polynomial:
        return _Polynomial(self.table + other.table)

    def __call__(self, slip: FloatArray | float, load: FloatArray) -> FloatArray:
        result = np.zeros(np.shape(load))
        for k in range(self.order, -1, -1):
            q = np.zeros(np.shape(load))
            for m in range(self.order - k, -1, -1):
                q = q * load + self.table[k, m]
            result = result * slip + q
        return result


def _powers(x: FloatArray, order: int) -> FloatArray:
    """(n, order + 1) matrix of x⁰ … x^order."""
    out = np.empty((x.size, order + 1))
    out[:, 0] = 1.0
    for k in range(1, order + 1):
        out[:, k] = out[:, k - 1] * x
    return out


class _SurrogateFit:
    """The plant's surrogate fit (4th order, equal weights, basis |i|^k W^m over 0 ≤ i ≤ 1, 0.1 ≤ W ≤ 200 N) on a
    coarser grid (30 × 30 instead of 100 × 100), so that a changed soil costs one 900-point Wong–Reece solve."""

    def __init__(self, order: int = _LOCAL_ORDER, points: int = _FIT_GRID_POINTS) -> None:
        from vehicle_sim.terrain.terramechanics_surrogate import SURROGATE_LOAD_RANGE, SURROGATE_SLIP_RANGE

        self.order = order
        self.exponents = [(k, m) for k in range(order + 1) for m in range(order + 1 - k)]
        load = np.linspace(*SURROGATE_LOAD_RANGE, points)
        slip = np.linspace(*SURROGATE_SLIP_RANGE, points)
        lm, sm = np.meshgrid(load, slip, indexing="ij")
        self.grid_load, self.grid_slip = lm.ravel(), sm.ravel()
        self._load_scale = float(SURROGATE_LOAD_RANGE[1])
        features = np.stack(
            [self.grid_slip**k * (self.grid_load / self._load_scale) ** m for k, m in self.exponents], axis=1
        )
        self._pinv = np.linalg.pinv(features)

    def fit(self, values: FloatArray) -> _Polynomial:
        c = self._pinv @ values
        table = np.zeros((self.order + 1, self.order + 1))
        for (k, m), value in zip(self.exponents, c, strict=True):
            table[k, m] = value / self._load_scale**m
        return _Polynomial(table)


class _DepthTable:
    """r (1 − cos θ0(W, |i|)) (m) of a soil and wheel on a (W, |i|) grid, bilinear in between.

    θ0 is the Wong–Reece contact angle that carries W at the slip ([RB] eq. 7, the
    one of the replay's soil forces); r (1 − cos θ0) is the depth of the wheel's
    lowest point below the undisturbed surface. The grid (1 N × 0.02, W to the
    surrogate's 200 N edge, loads beyond it held there) is fine enough that the
    depth's slope in W, which sets the sinking rate of a wheel whose load changes,
    changes by < 1 % from one cell to the next at 20–100 N. One 10⁴-point solve per
    replay.
    """

    def __init__(self, soil: Any, wheel: Any, load_cap: float) -> None:
        from vehicle_sim.terrain.wong_reece import contact_angle

        self.load = np.arange(0.0, load_cap + 0.5 * _DEPTH_LOAD_STEP, _DEPTH_LOAD_STEP)
        self.slip = np.linspace(0.0, 1.0, _DEPTH_SLIP_POINTS)
        lm, sm = np.meshgrid(self.load, self.slip, indexing="ij")
        theta = contact_angle(lm.ravel(), sm.ravel(), soil, wheel, overload="saturate")
        self.values = (wheel.radius * (1.0 - np.cos(np.asarray(theta, dtype=float)))).reshape(lm.shape)

    def __call__(self, load: FloatArray, slip: FloatArray) -> FloatArray:
        """Depth (m) at loads ``load`` (N) and slip magnitudes ``slip`` (–), same shape."""
        fw = np.clip(load / _DEPTH_LOAD_STEP, 0.0, self.load.size - 1.0)
        fs = np.clip(slip * (self.slip.size - 1.0), 0.0, self.slip.size - 1.0)
        iw = np.minimum(fw.astype(np.intp), self.load.size - 2)
        js = np.minimum(fs.astype(np.intp), self.slip.size - 2)
        a, b = fw - iw, fs - js
        v = self.values
        low = v[iw, js] * (1.0 - b) + v[iw, js + 1] * b
        high = v[iw + 1, js] * (1.0 - b) + v[iw + 1, js + 1] * b
        out: FloatArray = low * (1.0 - a) + high * a
        return out


@dataclass(frozen=True)
class _SoilVariant:
    """A soil and grouser height whose forces differ from the nominal surrogate."""

    soil: Any
    grouser_height: float


class _SoilModel:
    """DP(W, i), τ_R(W, i) as the plant evaluates them (``_Terramechanics``), with the catalogue's soil effects.

    Nominal: the plant's surrogate of the config soil (the same polynomials).
    A variant (changed soil and/or grousers) is the surrogate plus the fit,
    by the plant's own procedure on a 30 × 30 grid, of the Wong–Reece
    difference WR(variant) − WR(nominal): the plant fits a new surrogate to
    WR(variant) on 100 × 100 points, and the fit of a sum is the sum of the
    fits, so only the grid differs (and the surrogate's fit error, 0.1–0.3 N
    of DP near the operating point, is reproduced rather than ignored).

    The steady sinkage z*(W, i) (:meth:`depth`) is the same Wong–Reece soil's:
    the nominal soil's from a fine table (:class:`_DepthTable`); a variant's is
    the nominal table times the fit, on the same 30 × 30 grid, of the ratio of
    the two depths (both grow as ≈ W^(2/(2n+1)), so their ratio is smooth where
    their difference is not).
    """

    def __init__(self, soil: Any, params: RoverParams) -> None:
        from vehicle_sim.terrain.terramechanics_surrogate import SURROGATE_LOAD_RANGE, terramechanics_surrogate
        from vehicle_sim.terrain.wong_reece import RigidWheel

        self.soil = soil
        self.params = params
        self.wheel = RigidWheel(radius=params.wheel_radius, width=params.wheel_width)
        surrogate = terramechanics_surrogate(soil, self.wheel)
        self.nominal = (
            _Polynomial.from_model(surrogate.drawbar_pull),
            _Polynomial.from_model(surrogate.resistive_torque),
        )
        self.load_cap = SURROGATE_LOAD_RANGE[1]
        self.local = _SurrogateFit()
        self._base = self._wong_reece(soil, self.wheel)
        self._cache: dict[tuple[Any, float], tuple[_Polynomial, _Polynomial]] = {}
        self.depth_table = _DepthTable(soil, self.wheel, self.load_cap)
        self._depth_cache: dict[tuple[Any, float], _Polynomial] = {}

    def _wong_reece(self, soil: Any, wheel: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(DP, τ_R, depth r (1 − cos θ0)) of ``soil`` and ``wheel`` on the 30 × 30 grid."""
        from vehicle_sim.terrain.wong_reece import wheel_forces

        forces = wheel_forces(self.local.grid_load, self.local.grid_slip, soil, wheel, overload="saturate")
        depth = wheel.radius * (1.0 - np.cos(np.asarray(forces.contact_angle, dtype=float)))
        return np.asarray(forces.drawbar_pull, dtype=float), np.asarray(forces.resistive_torque, dtype=float), depth

    def polynomials(self, variant: _SoilVariant | None) -> tuple[_Polynomial, _Polynomial]:
        """(DP, τ_R) polynomials in (|i|, W) of the nominal soil (None) or a variant."""
        from vehicle_sim.terrain.wong_reece import RigidWheel

        if variant is None or (variant.soil == self.soil and variant.grouser_height == 0.0):
            return self.nominal
        key = (variant.soil, round(variant.grouser_height, 12))
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            wheel = RigidWheel(radius=self.params.wheel_radius + variant.grouser_height, width=self.params.wheel_width)
            dp, tau, depth = self._wong_reece(variant.soil, wheel)
            self._cache[key] = (
                self.nominal[0] + self.local.fit(dp - self._base[0]),
                self.nominal[1] + self.local.fit(tau - self._base[1]),
            )
            if len(self._depth_cache) > 64:
                self._depth_cache.clear()
            self._depth_cache[key] = self.local.fit(depth / np.maximum(self._base[2], 1e-9))
        return self._cache[key]

    def _depth_ratio(self, variant: _SoilVariant | None) -> _Polynomial | None:
        """The fitted depth ratio z*(variant)/z*(nominal) in (|i|, W) (None for the nominal soil)."""
        if variant is None or (variant.soil == self.soil and variant.grouser_height == 0.0):
            return None
        key = (variant.soil, round(variant.grouser_height, 12))
        if key not in self._depth_cache:
            self._cache.pop(key, None)
            self.polynomials(variant)
        return self._depth_cache[key]

    def forces(
        self,
        load: FloatArray,
        slip: FloatArray,
        *,
        sinkage: float = 0.0,
        grouser_height: float = 0.0,
        variants: Sequence[tuple[_SoilVariant | None, FloatArray | float]] = ((None, 1.0),),
    ) -> tuple[FloatArray, FloatArray]:
        """(DP, τ_R) at (W, i) in the plant's ``_Terramechanics`` order of effects.

        ``variants``: (variant or None for the nominal soil, weight per sample)
        blended (the soil before and after a change).
        """
        load = np.maximum(load, 0.0)
        slip = np.clip(slip, -1.0, 1.0)
        model_load, model_slip = load, slip
        scale = None
        if sinkage > 0.0:
            scale = 1.0 + sinkage * np.abs(slip)
            model_load = load * scale
        if grouser_height > 0.0:
            r = self.params.wheel_radius
            model_slip = 1.0 - (1.0 - slip) * r / (r + grouser_height)
        capped = np.minimum(model_load, self.load_cap)
        skid = model_slip < 0.0
        any_skid = bool(np.any(skid))
        load_powers = _powers(capped, _LOCAL_ORDER)
        slip_powers = _powers(np.abs(model_slip), _LOCAL_ORDER)
        dp = np.zeros_like(capped)
        tau = np.zeros_like(capped)
        for variant, weight in variants:
            p_dp, p_tau = self.polynomials(variant)
            both = slip_powers @ np.hstack([p_dp.table, p_tau.table])  # Σ_k |i|^k c_km, for DP and τ_R
            v_dp = np.einsum("nm,nm->n", both[:, : _LOCAL_ORDER + 1], load_powers)
            v_tau = np.einsum("nm,nm->n", both[:, _LOCAL_ORDER + 1 :], load_powers)
            if any_skid:  # [RB] eqs. 10-11 on the polynomials, as the plant's surrogate
                v_dp = np.where(skid, -v_dp + 2.0 * (load_powers @ p_dp.table[0]), v_dp)
                v_tau = np.where(skid, -v_tau + 2.0 * (load_powers @ p_tau.table[0]), v_tau)
            dp = dp + weight * v_dp
            tau = tau + weight * v_tau
        if scale is not None:
            dp = dp / scale
            tau = tau / scale
        return dp, tau

    def depth(
        self,
        load: FloatArray,
        slip: FloatArray,
        *,
        sinkage: float = 0.0,
        grouser_height: float = 0.0,
        variants: Sequence[tuple[_SoilVariant | None, FloatArray | float]] = ((None, 1.0),),
    ) -> FloatArray:
        """Steady sinkage z* (m) of the wheel centre below the undisturbed surface at (W, i), as the plant sinks it.

        z* = r_e (1 − cos θ0(W, |i|)) − h_g, with the slip-sinkage load W (1 + c|i|),
        the grouser tips' slip and cylinder r_e = r_w + h_g, a skidding wheel at |i|,
        and the soils of ``variants`` blended with their weights (as :meth:`forces`).
        """
        load = np.maximum(load, 0.0)
        slip = np.abs(np.clip(slip, -1.0, 1.0))
        model_load = load * (1.0 + sinkage * slip) if sinkage > 0.0 else load
        if grouser_height > 0.0:
            r = self.params.wheel_radius
            slip = 1.0 - (1.0 - slip) * r / (r + grouser_height)
        capped = np.minimum(model_load, self.load_cap)
        nominal = self.depth_table(capped, slip)
        depth = np.zeros_like(capped)
        for variant, weight in variants:
            ratio = self._depth_ratio(variant)
            depth = depth + weight * (nominal if ratio is None else nominal * ratio(slip, capped))
        out: FloatArray = np.maximum(depth - grouser_height, 0.0)
        return out


_SLIP_BOUNDS = (-0.95, 0.999)  # slip range of the per-wheel inversion
_TORQUE_TOL = 1e-6  # N·m, convergence of τ_R(W, i) = τ_R,measured
_LOAD_TOL = 1e-4  # N, convergence of W = √(F_L² + F_⊥² − DP²)


def _solve_wheels(
    forces: Callable[[NDArray[np.intp] | None, FloatArray, FloatArray], tuple[FloatArray, FloatArray]],
    tau: FloatArray,
    force2: FloatArray,
    slip: FloatArray,
    load: FloatArray,
    sweeps: Sequence[tuple[int, int]],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(W, i, DP) per sample: τ_R(W, i) = ``tau`` and W² + DP(W, i)² = ``force2`` (module docstring, 3).

    ``forces(rows, W, i)`` is (DP, τ_R) at the samples ``rows`` (None: all).
    Each sweep is a safeguarded Newton on i at fixed W followed by the update
    of W. The Newton keeps, per sample, a slip where τ_R is below the
    measurement and one where it is above (at first the slip bounds) and
    bisects whenever the step leaves that bracket or the slope is not
    positive: a changed soil's τ_R(i) is nearly flat beyond i ≈ 0.3 (loose
    soil with a high friction angle: 1.79 N·m at i = 0.3, 1.84 N·m at 0.8), where
    a plain Newton step overshoots to the slip bounds and oscillates between
    them. After the ``sweeps`` (Newton iterations, ignored), samples whose
    torque or load has not converged get more iterations and sweeps.
    """
    lo, hi = _SLIP_BOUNDS
    step = 1e-4

    def newton(
        sel: NDArray[np.intp] | None,
        i: FloatArray,
        w: FloatArray,
        target: FloatArray,
        iterations: int,
        below: FloatArray,
        above: FloatArray,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        for _ in range(iterations):
            t0 = forces(sel, w, i)[1]
            t1 = forces(sel, w, np.minimum(i + step, 1.0))[1]
            f = t0 - target
            below = np.where(f < 0.0, i, below)
            above = np.where(f > 0.0, i, above)
            slope = (t1 - t0) / step
            good = slope > 1e-3
            trial = np.clip(i - f / np.where(good, slope, 1.0), lo, hi)
            inside = good & (trial >= np.minimum(below, above)) & (trial <= np.maximum(below, above))
            i = np.where(f == 0.0, i, np.where(inside, trial, 0.5 * (below + above)))
        return i, below, above

    def converged(f: FloatArray, i: FloatArray, below: FloatArray, above: FloatArray) -> NDArray[np.bool_]:
        # The torque matches, or the bracket has closed (at a slip bound when τ_R never reaches the measurement).
        result: NDArray[np.bool_] = (np.abs(f) <= _TORQUE_TOL) | (np.abs(above - below) <= 1e-9)
        return result

    def sweep(
        sel: NDArray[np.intp] | None, i: FloatArray, w: FloatArray, iterations: int
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """One sweep on the samples ``sel``: (i, DP at the old W, new W)."""
        target = tau if sel is None else tau[sel]
        f2 = force2 if sel is None else force2[sel]
        below, above = np.full(i.size, lo), np.full(i.size, hi)
        i, below, above = newton(sel, i, w, target, iterations, below, above)
        d, t = forces(sel, w, i)
        for attempt in range(10):  # the samples the fixed iterations left unconverged
            f = t - target
            below, above = np.where(f < 0.0, i, below), np.where(f > 0.0, i, above)
            bad = np.flatnonzero(~converged(f, i, below, above))
            if not bad.size:
                break
            sub = bad if sel is None else sel[bad]
            if attempt == 0:
                # The bracket's ends may still be the slip bounds, assumed rather than evaluated: evaluate them.
                # τ_R at the lower bound above the measurement (or at the upper one below it): the bound solves.
                f_lo = forces(sub, w[bad], np.full(bad.size, lo))[1] - target[bad]
                f_hi = forces(sub, w[bad], np.full(bad.size, hi))[1] - target[bad]
                at_lo, at_hi = f_lo >= 0.0, (f_hi <= 0.0) & (f_lo < 0.0)
                below[bad] = np.where(at_lo, lo, np.where(at_hi, hi, below[bad]))
                above[bad] = np.where(at_lo, lo, np.where(at_hi, hi, above[bad]))
                i[bad] = np.where(at_lo, lo, np.where(at_hi, hi, i[bad]))
            i[bad], below[bad], above[bad] = newton(sub, i[bad], w[bad], target[bad], 4, below[bad], above[bad])
            d[bad], t[bad] = forces(sub, w[bad], i[bad])
        return i, d, np.sqrt(np.maximum(f2 - d**2, 1e-6))

    if not tau.size:
        return slip, load, np.zeros(0)
    previous = load
    for iterations, _ in sweeps:
        slip, _, updated = sweep(None, slip, load, iterations)
        previous, load = load, updated
    # Samples whose W still moved in the last sweep get up to three more (a heavily skidding wheel's W may not settle).
    for _ in range(3):
        moving = np.flatnonzero(np.abs(load - previous) > _LOAD_TOL)
        if not moving.size:
            break
        slip[moving], _, updated = sweep(moving, slip[moving], load[moving], 2)
        previous[moving], load[moving] = load[moving], updated
    dp = forces(None, load, slip)[0]
    return slip, load, dp
