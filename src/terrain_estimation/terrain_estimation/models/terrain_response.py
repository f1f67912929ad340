"""2-D polynomial terrain-response model DP(i, W), τ_R(i, W): weighted least-squares fit and evaluation.

Setterfield & Ellery ([RB], MODELS.md C.2, C.7): drawbar pull and resistive
torque are approximated by an O-th order polynomial in slip i (–) and normal
load W (N) with (O + 1)(O + 2)/2 coefficients p_kl, term p_kl i^k W^l,
k + l ≤ O. The same model serves the simulator's 4th-order global surrogate of
the Wong–Reece wheel (``vehicle_sim.terrain.terramechanics_surrogate``) and the
2nd-order models fitted from the estimator's (i, W, DP, τ_R) samples.

Coefficient order (``terrain_msgs/TerrainResponseModel``): for total degree
d = 0..O, for k = d..0, the term i^k W^(d−k). Order 2:
``[1, i, W, i², i·W, W²]`` — also the order of MATLAB's ``polyfitweighted2``
(``[p00 p10 p01 p20 p11 p02 …]`` with x = i, y = W).

Fitting scales i and W to [−1, 1] over the data before solving (a raw design
matrix with W up to 200 N and W⁴ terms is badly conditioned), then expands the
scaled polynomial back to raw coefficients exactly, so a message's
coefficients evaluate in plain i and W.

Weights multiply the *squared* residuals, Σ w (p(i, W) − y)² (e.g. inverse
variances). MATLAB's ``polyfitweighted2`` multiplies the residuals themselves,
Σ (w (p − y))², so its w is √ of these.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = [
    "PolynomialFit",
    "PolynomialModel2D",
    "ValidityRegion",
    "coefficient_count",
    "design_matrix",
    "fit_polynomial_2d",
    "order_from_coefficient_count",
    "polynomial_exponents",
]


def coefficient_count(order: int) -> int:
    """(O + 1)(O + 2)/2, the number of coefficients of an O-th order 2-D polynomial."""
    if order < 0:
        raise ValueError(f"polynomial order must be ≥ 0, got {order}")
    return (order + 1) * (order + 2) // 2


def order_from_coefficient_count(count: int) -> int:
    """Inverse of :func:`coefficient_count`; ValueError if ``count`` is not a triangular number."""
    order = int(round((math.sqrt(8 * count + 1) - 3) / 2)) if count > 0 else -1
    if order < 0 or coefficient_count(order) != count:
        raise ValueError(f"{count} coefficients do not make a complete 2-D polynomial ((O+1)(O+2)/2)")
    return order


def polynomial_exponents(order: int) -> tuple[tuple[int, int], ...]:
    """Exponents (k, l) of i^k W^l in coefficient (message) order: d = 0..O, k = d..0, l = d − k."""
    coefficient_count(order)
    return tuple((k, d - k) for d in range(order + 1) for k in range(d, -1, -1))


def design_matrix(slip: ArrayLike, load: ArrayLike, order: int) -> Array:
    """Rows [i^k W^l for (k, l) in :func:`polynomial_exponents`], shape (n, (O+1)(O+2)/2).

    Inputs are broadcast against each other and flattened.
    """
    i, w = np.broadcast_arrays(np.asarray(slip, dtype=float), np.asarray(load, dtype=float))
    i, w = i.ravel(), w.ravel()
    i_powers = i[:, None] ** np.arange(order + 1)
    w_powers = w[:, None] ** np.arange(order + 1)
    return np.stack([i_powers[:, k] * w_powers[:, m] for k, m in polynomial_exponents(order)], axis=1)


@dataclass(frozen=True, kw_only=True)
class ValidityRegion:
    """Rectangle of (i, W) covered by a fit's data; outside it the polynomial extrapolates.

    Attributes:
        slip_min, slip_max: slip range (–).
        load_min, load_max: load range (N).
    """

    slip_min: float
    slip_max: float
    load_min: float
    load_max: float

    def __post_init__(self) -> None:
        values = (self.slip_min, self.slip_max, self.load_min, self.load_max)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"ValidityRegion bounds must be finite, got {values}")
        if self.slip_min > self.slip_max or self.load_min > self.load_max:
            raise ValueError(f"ValidityRegion needs min ≤ max, got {values}")

    @classmethod
    def from_samples(cls, slip: ArrayLike, load: ArrayLike) -> ValidityRegion:
        """Smallest rectangle holding all (i, W) samples."""
        i, w = np.broadcast_arrays(np.asarray(slip, dtype=float), np.asarray(load, dtype=float))
        if i.size == 0:
            raise ValueError("no samples")
        return cls(slip_min=float(i.min()), slip_max=float(i.max()), load_min=float(w.min()), load_max=float(w.max()))

    def contains(self, slip: ArrayLike, load: ArrayLike) -> NDArray[np.bool_]:
        """True where (i, W) lies inside the region (bounds included)."""
        i = np.asarray(slip, dtype=float)
        w = np.asarray(load, dtype=float)
        return (i >= self.slip_min) & (i <= self.slip_max) & (w >= self.load_min) & (w <= self.load_max)


@dataclass(frozen=True, kw_only=True)
class PolynomialModel2D:
    """Polynomial Σ p_kl i^k W^l in slip i (–) and load W (N), [RB] section II-E.

    Attributes:
        order: total degree O.
        coefficients: (O + 1)(O + 2)/2 values p_kl in message order (see
            :func:`polynomial_exponents`), units of the modelled quantity per
            unit of i^k W^l.
        validity: data region of the fit, or None if unknown.
    """

    order: int
    coefficients: tuple[float, ...]
    validity: ValidityRegion | None = None

    def __post_init__(self) -> None:
        coefficients = tuple(float(c) for c in np.asarray(self.coefficients, dtype=float).ravel())
        object.__setattr__(self, "coefficients", coefficients)
        if len(coefficients) != coefficient_count(self.order):
            raise ValueError(
                f"order {self.order} needs {coefficient_count(self.order)} coefficients, got {len(coefficients)}"
            )
        if not all(math.isfinite(c) for c in coefficients):
            raise ValueError("polynomial coefficients must be finite")

    @classmethod
    def from_coefficients(cls, coefficients: ArrayLike, validity: ValidityRegion | None = None) -> PolynomialModel2D:
        """Model from message-ordered coefficients, the order inferred from their number."""
        values = tuple(float(c) for c in np.asarray(coefficients, dtype=float).ravel())
        return cls(order=order_from_coefficient_count(len(values)), coefficients=values, validity=validity)

    @property
    def exponents(self) -> tuple[tuple[int, int], ...]:
        """(k, l) of each coefficient's term i^k W^l."""
        return polynomial_exponents(self.order)

    def evaluate(self, slip: ArrayLike, load: ArrayLike) -> Array:
        """Σ p_kl i^k W^l at the broadcast (i, W) (Horner in W within each power of i)."""
        i, w = np.broadcast_arrays(np.asarray(slip, dtype=float), np.asarray(load, dtype=float))
        # q_k(W) = Σ_l p_kl W^l (l written m), then Σ_k q_k(W) i^k, both by Horner's scheme.
        table = np.zeros((self.order + 1, self.order + 1))
        for (k, m), c in zip(self.exponents, self.coefficients, strict=True):
            table[k, m] = c
        result = np.zeros(i.shape)
        for k in range(self.order, -1, -1):
            q = np.zeros(w.shape)
            for m in range(self.order - k, -1, -1):
                q = q * w + table[k, m]
            result = result * i + q
        return result

    def residual_rms(
        self, slip: ArrayLike, load: ArrayLike, values: ArrayLike, weights: ArrayLike | None = None
    ) -> float:
        """RMS of model − values, √(Σ w r² / Σ w) (plain RMS when ``weights`` is None)."""
        i, w, y = np.broadcast_arrays(
            np.asarray(slip, dtype=float), np.asarray(load, dtype=float), np.asarray(values, dtype=float)
        )
        residual = self.evaluate(i, w) - y
        if weights is None:
            return float(np.sqrt(np.mean(residual**2)))
        weight = np.broadcast_to(np.asarray(weights, dtype=float), residual.shape)
        return float(np.sqrt(np.sum(weight * residual**2) / np.sum(weight)))


class PolynomialFit(NamedTuple):
    """Result of :func:`fit_polynomial_2d`.

    Attributes:
        model: the fitted polynomial, validity = the positively weighted data's range.
        rms: residual RMS of the fit over its data, weighted as the fit was.
    """

    model: PolynomialModel2D
    rms: float


def _scaling(values: Array) -> tuple[float, float]:
    """(centre, half-range) mapping the data to [−1, 1]; half-range 1 for constant data."""
    low, high = float(values.min()), float(values.max())
    half_range = 0.5 * (high - low)
    return 0.5 * (high + low), half_range if half_range > 0.0 else 1.0


def _unscale(scaled: Array, order: int, slip_scaling: tuple[float, float], load_scaling: tuple[float, float]) -> Array:
    """Raw coefficients of Σ q_kl u^k v^l with u = (i − c_i)/s_i, v = (W − c_W)/s_W (binomial expansion)."""
    exponents = polynomial_exponents(order)
    position = {kl: n for n, kl in enumerate(exponents)}
    a_i, b_i = 1.0 / slip_scaling[1], -slip_scaling[0] / slip_scaling[1]
    a_w, b_w = 1.0 / load_scaling[1], -load_scaling[0] / load_scaling[1]
    raw = np.zeros(len(exponents))
    for (k, m), q in zip(exponents, scaled, strict=True):
        # (a_i i + b_i)^k (a_w W + b_w)^m = Σ_a Σ_b C(k,a) a_i^a b_i^(k−a) C(m,b) a_w^b b_w^(m−b) i^a W^b
        for a in range(k + 1):
            slip_factor = math.comb(k, a) * a_i**a * b_i ** (k - a)
            for b in range(m + 1):
                raw[position[(a, b)]] += q * slip_factor * math.comb(m, b) * a_w**b * b_w ** (m - b)
    return raw


def fit_polynomial_2d(
    slip: ArrayLike, load: ArrayLike, values: ArrayLike, order: int, weights: ArrayLike | None = None
) -> PolynomialFit:
    """Weighted least-squares O-th order polynomial through (i, W, y) samples ([RB] C.2, C.7).

    Minimises Σ w (p(i, W) − y)² with numpy's SVD least squares on a design
    matrix in i and W scaled to [−1, 1], and returns raw coefficients in message
    order. Samples with zero weight do not count, also not for the validity
    region.

    Args:
        slip: i (–), any shape broadcasting with ``load`` and ``values``.
        load: W (N).
        values: DP (N), τ_R (N·m) or any other response.
        order: polynomial order O ≥ 0.
        weights: w ≥ 0 per sample (e.g. 1/variance); None = equal weights.

    Returns:
        (model, rms): the fitted model and the (weighted) residual RMS.

    Raises:
        ValueError: non-finite input, negative weights, or fewer distinct
            samples than the order needs (rank-deficient design).
    """
    i, w, y = np.broadcast_arrays(
        np.asarray(slip, dtype=float), np.asarray(load, dtype=float), np.asarray(values, dtype=float)
    )
    i, w, y = i.ravel(), w.ravel(), y.ravel()
    weight = np.ones(y.shape) if weights is None else np.broadcast_to(np.asarray(weights, dtype=float), y.shape).ravel()
    if not (np.all(np.isfinite(i)) and np.all(np.isfinite(w)) and np.all(np.isfinite(y))):
        raise ValueError("slip, load and values must be finite")
    if not np.all(np.isfinite(weight) & (weight >= 0.0)):
        raise ValueError("weights must be finite and ≥ 0")
    used = weight > 0.0
    i, w, y, weight = i[used], w[used], y[used], weight[used]
    terms = coefficient_count(order)
    if y.size < terms:
        raise ValueError(f"order {order} needs at least {terms} positively weighted samples, got {y.size}")

    slip_scaling, load_scaling = _scaling(i), _scaling(w)
    design = design_matrix((i - slip_scaling[0]) / slip_scaling[1], (w - load_scaling[0]) / load_scaling[1], order)
    root_weight = np.sqrt(weight)
    scaled, _, rank, _ = np.linalg.lstsq(design * root_weight[:, None], y * root_weight, rcond=None)
    if rank < terms:
        raise ValueError(
            f"order {order} fit is rank-deficient (rank {rank} < {terms}): too few distinct (i, W) samples"
        )
    model = PolynomialModel2D(
        order=order,
        coefficients=tuple(_unscale(scaled, order, slip_scaling, load_scaling)),
        validity=ValidityRegion.from_samples(i, w),
    )
    return PolynomialFit(model, model.residual_rms(i, w, y, weight))
