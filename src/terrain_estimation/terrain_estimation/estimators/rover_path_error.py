"""The geometric contact angles' error from the path beyond the parabola, and from the sinkage model (issue 21).

Estimator 2 takes each wheel's contact angle γ̌ from the parabola through the
three wheel centres; the wheels' true slopes differ from the parabola's by
Simpson's rule's error on the slope profile over the wheelbase (zero for a path
quartic over it, RMS Δ/6 for a kink Δ passing under the rover).
:class:`PathQuadratureError` evaluates that error on the profile the wheels' own
earlier estimates traced (they run in one track), and
:func:`sinkage_tilt_variance` the tilt the sinkage model's differential sinkage
gives the fitted path. Both enter σ_b of
:class:`~terrain_estimation.estimators.rover_noise.ContactAngleBias` when its
``path_error`` / ``sinkage_relative_error`` ask for them (off by default).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from terrain_estimation.filters.base import Array
from terrain_estimation.filters.sigma_points import solve

__all__ = ["PathQuadratureError", "sinkage_tilt_variance"]


def _parabola_node_slopes(x: Array, z: Array) -> Array:
    """Slopes at the nodes x (3,) of the parabola through (x, z)."""
    xc = x - float(x.mean())
    coef = solve(np.column_stack([np.ones(3), xc, xc * xc]), z)
    out: Array = coef[1] + 2.0 * coef[2] * xc
    return out


def sinkage_tilt_variance(node_x: ArrayLike, sinkage: ArrayLike, weights: ArrayLike, relative_error: float) -> float:
    """Variance (rad²) of γ̌'s common error from a relative error of the modelled wheel sinkages.

    The centres are lifted by the modelled sinkage s_j before the parabola is
    fitted (:func:`~terrain_estimation.models.rover_estimator_kinematics.path_tangent_angles`);
    a height error ε_j tilts the fitted tangents by the parabola's slopes
    through ε at the nodes, and ż0^R, hence every γ̌, takes their weighted sum
    Σ c_j (c: the error-cancelling weights; for equal spacing this is
    (ε_front − ε_rear)/l_w). The model's sinkages scale with the soil as
    (k_c/b + k_φ)^(−2/(2n+1)): a soil within a factor 2 of the nominal
    stiffness moves them by −35 … +54 % (n = 1.1), all wheels alike, so
    ε = ρ s with ρ = ``relative_error``; a common depth does not tilt.
    """
    if relative_error <= 0.0:
        return 0.0
    x = np.asarray(node_x, dtype=float)
    s = np.asarray(sinkage, dtype=float)
    c = np.asarray(weights, dtype=float)
    tilt = float(c @ _parabola_node_slopes(x, relative_error * s))
    return tilt * tilt


class PathQuadratureError:
    """γ̌'s common error from the path beyond the parabola, evaluated on the path the estimates trace.

    ż0^R, hence every γ̌, is taken from the parabola through the three wheel
    centres (:func:`~terrain_estimation.models.rover_estimator_kinematics.contact_angles_with_vertical_speed`):
    the weighted sum Σ c_j (γ_j − γ_geo,j) of its tangents' errors at the
    nodes becomes a common error of all three γ̌. For equal spacing h the
    parabola's weighted tangent is (z_f − z_r)/2h, the path's *mean* slope
    over the wheelbase, while c = (1, 4, 1)/6 weighs the true slopes at the
    nodes: the error is Simpson's rule's error on the slope profile over the
    wheelbase, zero for a path quartic over it, and of the order of the
    slope change itself where the path bends within the wheelbase (a step's
    edge: a kink of Δ in slope gives errors from −Δ/3 to +Δ/6 as it passes
    under the rover, RMS Δ/6). At one instant it cannot be seen (the
    estimates are made to satisfy the parabola), but the wheels run in one
    track: each has traced the ground ahead of the wheel behind it, at
    earlier times and configurations. The estimates γ̂_j(s), placed where
    each wheel was, are the slope profile ``t = −tan γ̂`` over the span the
    rover stands on now, the node heights its integral, and the error is
    evaluated on it exactly (no constant: the geometry of the method). Where
    the ground has not been traced yet (within a wheel spacing of travel
    after a start; gaps longer than a quarter of ``curvature_length``) the
    slope is taken linear across the gap and a kink of the slope change
    across it may hide there: (Δ_gap/6)² is added per gap. Each place is
    taken as first traced (the wheel ahead's older estimate, its error made
    elsewhere), not from the wheel standing there now, whose estimate
    satisfies the parabola by construction. The profile's own errors enter
    through the node values: each sample carries its filter variance P_j and
    the path error stated when it was made, σ_j², so ``Σ c_j² (P_j + σ_j²)``
    is subtracted from the square (E[Ê²] = E² + that, if the stated
    variances are right; with estimates better than stated the measure falls
    short of the exact error, never above it); the result is averaged over
    ``memory`` steps and floored at 0 (as :class:`RepeatPassError`).

    :attr:`curvature`: max |dγ/ds| over the span, from each wheel's own
    trace as least-squares slopes over a travel of ``curvature_length``
    (m). At ≥ 1/l_w the path is beyond the method's validity ([RB] V-B): the
    estimates tracing the profile then err as much as the error evaluated on
    them, so the variance is at least that of a kink of the profile's whole
    slope change over the span (RMS Δ/6, above), and :attr:`beyond_validity`
    is set.
    """

    def __init__(self, memory: float, curvature_length: float) -> None:
        self._b = 1.0 - 1.0 / memory
        self._length = float(curvature_length)
        self.reset()

    def reset(self) -> None:
        """Forget the history (after a re-initialisation)."""
        self._place: list[list[float]] = [[], [], []]
        self._gamma: list[list[float]] = [[], [], []]
        self._noise: list[list[float]] = [[], [], []]  # P_γ + the path's σ² of each sample when it was made
        self._distance: float | None = None
        self._average = 0.0
        self._curvature: float | None = None
        self._beyond = False

    @property
    def variance(self) -> float:
        """The path's share of σ_b² (rad²): the unfloored average, floored at 0."""
        return max(self._average, 0.0)

    @property
    def curvature(self) -> float | None:
        """max |dγ/ds| (m⁻¹) over the span, None before a wheel has traced ``curvature_length``."""
        return self._curvature

    @property
    def beyond_validity(self) -> bool:
        """True while the span's curvature is ≥ 1/l_w (the last update)."""
        return self._beyond

    def update(
        self, distance: float, gamma: ArrayLike, gamma_var: ArrayLike, node_x: ArrayLike, weights: ArrayLike
    ) -> float:
        """Add γ̂, P_γ (3,) at travelled ``distance``; returns the path's share of σ_b² (rad²).

        ``node_x``: the wheel centres' x (rear, middle, front) (m); ``weights``: c of
        :func:`~terrain_estimation.models.rover_estimator_kinematics.path_tangent_angles`.
        """
        x = np.asarray(node_x, dtype=float)
        c = np.asarray(weights, dtype=float)
        g3 = np.asarray(gamma, dtype=float)
        v3 = np.asarray(gamma_var, dtype=float)
        if self._distance is not None and distance <= self._distance:  # standing or reversing: nothing new
            return self.variance
        self._distance = float(distance)
        span = float(x[2] - x[0])
        if span <= 0.0:
            return self.variance
        nodes = distance + (x - x[0])  # places of the rear, middle, front wheel now
        for j in range(3):
            place, g, nv = self._place[j], self._gamma[j], self._noise[j]
            place.append(float(nodes[j]))
            g.append(float(g3[j]))
            nv.append(float(v3[j]) + self.variance)
            while len(place) > 2 and place[1] <= distance:
                del place[0], g[0], nv[0]
        # Each place as first traced: the wheel ahead's older estimate (its error made elsewhere), not the
        # current estimate of the wheel standing there, which satisfies the parabola by construction.
        parts_p, parts_g, parts_n = [], [], []
        first = math.inf
        for j in (2, 1, 0):
            p_j, g_j = np.asarray(self._place[j]), np.asarray(self._gamma[j])
            keep = p_j < first if j < 2 else np.ones(p_j.size, dtype=bool)
            if j < 2 and p_j.size and p_j[-1] < first and not np.all(keep):
                keep[-1] = True
            parts_p.append(p_j[keep])
            parts_g.append(g_j[keep])
            parts_n.append(np.asarray(self._noise[j])[keep])
            if p_j.size:
                first = min(first, float(p_j[0]))
        ps = np.concatenate(parts_p)
        gs = np.concatenate(parts_g)
        ns = np.concatenate(parts_n)
        order = np.argsort(ps, kind="stable")
        ps, gs, ns = ps[order], gs[order], ns[order]
        # The node values' errors: each sample's P_γ and the path's own error when it was made (σ² then).
        near = np.clip(np.searchsorted(ps, nodes), 0, ps.size - 1)
        noise = float(np.sum(c * c * ns[near]))
        inside = (ps > nodes[0]) & (ps < nodes[2])
        grid = np.concatenate([nodes[:1], ps[inside], nodes[2:]])
        t = -np.tan(np.interp(grid, ps, gs))
        heights = np.concatenate([[0.0], np.cumsum(0.5 * (t[1:] + t[:-1]) * np.diff(grid))])
        z = np.interp(nodes, grid, heights)
        fitted = _parabola_node_slopes(nodes, z)
        true = np.interp(nodes, grid, t)
        error = float(c @ (np.arctan(true) - np.arctan(fitted)))  # γ = −atan(slope)
        sample = error * error - noise
        # Ground not traced yet (after a start): a kink of the slope change across each such gap may hide there.
        gaps = np.diff(grid) > 0.25 * self._length
        if np.any(gaps):
            across = np.diff(np.interp(grid, ps, gs))[gaps] / 6.0
            sample += float(across @ across)
        kappas = [
            self._profile_curvature(np.asarray(p), np.asarray(g)) for p, g in zip(self._place, self._gamma, strict=True)
        ]
        known = [k for k in kappas if k is not None]
        self._curvature = max(known) if known else None
        self._beyond = self._curvature is not None and self._curvature * span >= 1.0
        if self._beyond:
            span_g = gs[(ps >= nodes[0]) & (ps <= nodes[2])]
            kink = float(span_g.max() - span_g.min()) / 6.0 if span_g.size else 0.0
            sample = max(sample, kink * kink - float(np.sum(c * c * v3)))
        self._average = self._b * self._average + (1.0 - self._b) * sample
        return self.variance

    def _profile_curvature(self, s: Array, g: Array) -> float | None:
        """max |dγ/ds| over windows of ``curvature_length`` of travel (least squares), None if too short."""
        if s.size < 3 or float(s[-1] - s[0]) < self._length:
            return None
        # Sliding least-squares slopes from cumulative sums: every window ends at a sample and spans
        # the last ``curvature_length`` of travel before it (at least half of it, three samples).
        start = np.searchsorted(s, s - self._length, side="left")
        ok = (s - s[start] >= 0.5 * self._length) & (np.arange(s.size) - start >= 2)
        if not np.any(ok):
            return None
        s0 = s - s[0]
        cum = [np.concatenate([[0.0], np.cumsum(v)]) for v in (np.ones_like(s0), s0, g, s0 * s0, s0 * g)]
        end = np.arange(s.size)[ok] + 1
        first = start[ok]
        n, sx, sg, sxx, sxg = (c[end] - c[first] for c in cum)
        den = n * sxx - sx * sx
        slopes = np.abs(n * sxg - sx * sg) / np.where(den > 0.0, den, np.inf)
        return float(np.max(slopes))
