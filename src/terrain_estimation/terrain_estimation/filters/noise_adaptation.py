"""Innovation-driven noise adaptation: whitened covariance matching of ``Q`` and ``R`` scales, with forgetting.

The paper's law (MODELS.md B.10, :func:`~.adaptive.adapt_noise_sqrt`) scales
``Q`` and ``R`` by the mean tire sideslip: a fixed schedule that never looks
at the innovations (B.12). Here the innovations drive the noise. The filter
keeps one scale per noise block, carried from step to step in its memory::

    R_k = D_k R0 D_k,   D_k = diag(√s_r)        (one scale per measurement channel)
    Q_k = s_q Q0                                 (one scale for the process noise)

so that the predicted innovation covariance is
``S = H̃ (λ P̄0 + Q_k) H̃ᵀ + R_k``, and the part of ``S`` each scale sets (its
derivative in ``ln s``) is::

    X_{r,i} = ½ (E_i R_k + R_k E_i),  E_i = e_i e_iᵀ     (channel i of R_k; Σ_i X_{r,i} = R_k)
    X_q     = H̃ Q_k H̃ᵀ,  H̃ = P_xzᵀ P̄⁻¹                 (statistical linearisation, as in B.9)

After each update, with the innovation ``ν = z − ẑ``, ``S = L Lᵀ`` and the
whitened innovation ``w = L⁻¹ν`` (``NIS = wᵀw``), the scales are matched to
what the innovations say, in whitened coordinates (``X̃ = L⁻¹ X L⁻ᵀ``), by
one damped Gauss–Newton step on ``θ = ln s`` of the one-step likelihood of
``ν`` (Fisher scoring; Mehra 1972's maximum-likelihood adaptive filter
reduced to one step, with exponential forgetting as in Sage & Husa 1969)::

    Huber clip:  w_c = g w,  g = min(1, c/√NIS),  c² = χ²_p(q_clip)
                 κ = E[min(χ²_p, c²)]/p = F_{χ²_{p+2}}(c²) + (c²/p)(1 − F_{χ²_p}(c²))
    matching:    h_j  = w_cᵀ X̃_j w_c / κ − tr(X̃_j)          (score; E[h_j] = 0 when E[ννᵀ] = S)
                 G_jk = tr(X̃_j X̃_k)                         (Fisher information, ×2)
                 (G + ε I) Δθ = h                             (ridge ε: a prior on θ)
    update:      ln s ← ln s + (1 − b) Δθ,   s clipped to [floor, ceiling]

Why this form. ``h`` and ``G`` are in whitened units, so every channel counts
in its own units (the reason for the whitened strong tracking, MODELS.md
B.12), and a scale moves in proportion to the information the innovations
carry about it: one whose part of ``S`` is large (``G_jj ≫ ε``) follows the
innovations at the rate ``1 − b`` (relative spread ≈ ``√(2 (1 − b)/(1 + b))``,
14 % for ``b = 0.98``), one with a small part (``G_jj ≪ ε``) hardly moves.
Two simpler forms were tried and rejected on the toy models of
``test/filters/test_filters_innovation_adaptation.py``: the pre-fit
covariance matching per channel, ``s_i ← b s_i + (1 − b)(ν_i² − (S − R)_ii)/R0_ii``
(Mehra; Sage–Husa), is unbiased but its noise is ``√2 S_ii/R_ii`` (tens of
times the scale where ``H P̄ Hᵀ`` dominates ``S``) and it gives the whole
excess to every block at once; the ratio ``s_j ← s_j (b + (1 − b) ρ_j)``,
``ρ_j = w_cᵀX̃_jw_c/(κ tr X̃_j)``, has bounded noise but moves a block with a
tiny part of ``S`` as fast as the dominant one (on a position-tracking toy
with ``R`` 10× too small, ``s_q`` went to 14 with ``Q`` right). The joint
step (the off-diagonal ``G_jk``) splits an excess between the blocks by how
well each explains it.

Guards, and why:

* **Positive definiteness.** ``R_k = D R0 D`` with ``s_r > 0`` and
  ``Q_k = s_q Q0`` stay positive (semi)definite: ``s`` is updated in
  ``ln s`` and clipped to ``[floor, ceiling] ∋ 1`` relative to ``R0``,
  ``Q0``. No covariance is estimated as a free matrix (Sage–Husa's
  ``ννᵀ − H P̄ Hᵀ`` loses positive definiteness).
* **Bounded memory.** A step's weight decays as ``b^k``: the memory is
  ``1/(1 − b)`` steps (50 for ``b = 0.98``); the base noise is the prior
  (``s = 1`` at a (re)start).
* **Outliers.** The whitened innovation is clipped radially at
  ``c = √χ²_p(q_clip)`` (Huber's ψ on the Mahalanobis radius), made
  unbiased by ``κ`` (the whitened innovation is spherically symmetric, so
  ``E[g² ννᵀ]/κ = S``). For one dominant block with share ``x`` of ``S``,
  one innovation of any size moves ``ln s`` by at most
  ``(1 − b)(c²/κ) x/(x² + ε) ≤ (1 − b)(c²/κ)/(2√ε)`` (a factor ≤ 1.7 for
  ``p = 3`` and the defaults), and the excess decays by
  ``≈ 1 − (1 − b) G/(G + ε)`` per step. Measured (two channels, NIS gate on):
  a 20σ innovation raises ``s_r`` 1.5× and it is back within 10 % after 100
  steps; unclipped, ×100.
* **Rejected updates.** The scales still adapt on a gated-out measurement
  (clipped): a filter whose ``R`` is too small would otherwise reject every
  measurement and never learn.

Why not the variational-Bayes adaptive filter (Särkkä & Nummenmaa 2009):
VB-AKF adapts only a diagonal ``R`` (inverse-gamma per channel), needs
fixed-point iterations per step (a new gain each) and its forgetting of the
gamma parameters is the same exponential memory as ``b`` here; its positive
definiteness comes from the conjugate prior, which the log-scales give here
at no cost. The matching here covers ``Q`` too and costs one ``p×p`` and one
``n×n`` Cholesky, an ``(m, m)`` solve (``m ≤ p + 1``) and a few small
products per step. Why not Sage–Husa's state-space ``Q`` estimate
``K ννᵀ Kᵀ + P⁺ − F P Fᵀ``: its noise relative to ``Q`` is ``(P̄ − P⁺)/Q``,
hundreds at a high sampling rate where ``Q`` per step is small (measured on
the position-tracking toy: the mean sample was 25× the true ``Q`` over 2800
steps), and it loses positive definiteness.

Identifiability. At zero lag ``Q`` and ``R`` act on the innovations only
through ``S`` (Mehra 1972 needs the lagged correlations to separate them).
Where ``H̃ Q0 H̃ᵀ`` is a small part of ``S`` (a slow state seen through a
noisy sensor) ``s_q`` hardly moves and an excess goes to ``s_r``; where both
parts are large and alike, the split of an excess between them is only as
good as the difference of their shapes (measured on a toy where ``Q``
dominates: true ``Q`` = 10 Q0 gives ``s_q ≈ 10``, Q0/10 gives
``s_q ≈ 0.15`` with ``s_r`` ≈ 0.7–0.9 absorbing the rest; ``Q`` alone:
``s_q`` = 0.10). The NIS is right either way, the floors and ceilings bound
the trade-off, and strong tracking covers the transients. Adapt one block
only (``adapt_r=False`` or ``adapt_q=False``) when the other is known.

Sources: Sage & Husa, *Adaptive filtering with unknown prior statistics*,
JACC 1969; Mehra, *Approaches to adaptive filtering*, IEEE TAC 17(5), 1972;
Myers & Tapley, *Adaptive sequential estimation with unknown noise
statistics*, IEEE TAC 21(4), 1976; Huber, *Robust statistics*, 1981;
Särkkä & Nummenmaa, *Recursive noise adaptive Kalman filtering by variational
Bayesian approximations*, IEEE TAC 54(3), 2009.

The sideslip law of B.10 stays available (``"an_stukf"``); combined with
these scales (``"adaptive_sideslip"``) its sideslip is weighted down at low
rolling speed by :class:`LowSpeedGuard` (at standstill
``α = atan2(·, |v_x| ≈ 0)`` is ≈ 1 rad and would apply the largest ``Q``
where the model is best).
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from .adaptive import _hqh, whiten
from .base import Array
from .chi2 import chi2_cdf, chi2_ppf, chi2_sf
from .sigma_points import cholesky, solve_lower

__all__ = [
    "InnovationNoiseConfig",
    "AdaptiveMemory",
    "LowSpeedGuard",
    "first_state_speed",
    "huber_clip",
    "update_noise_scales",
]


def _check_unit_interval(name: str, value: float, *, closed_low: bool = False) -> None:
    ok = (0.0 <= value < 1.0) if closed_low else (0.0 < value < 1.0)
    if not (math.isfinite(value) and ok):
        interval = "[0, 1)" if closed_low else "(0, 1)"
        raise ValueError(f"{name} must be in {interval}, got {value}")


@dataclass(frozen=True, kw_only=True)
class InnovationNoiseConfig:
    """Parameters of the innovation-driven noise adaptation (module docstring).

    Args:
        adapt_r: adapt the per-channel measurement-noise scales ``s_r``.
        adapt_q: adapt the process-noise scale ``s_q``.
        r_forgetting: ``b_r`` in [0, 1): forgetting of the ``s_r`` matching,
            ``ln s ← ln s + (1 − b_r) Δθ``; memory ``1/(1 − b_r)`` steps
            (0: a full Gauss–Newton step per innovation).
        q_forgetting: ``b_q`` in [0, 1), the same for ``s_q``.
        r_floor, r_ceiling: bounds of ``s_r`` (``R_k,ii / R0_ii``), with
            ``0 < floor ≤ 1 ≤ ceiling``.
        q_floor, q_ceiling: bounds of ``s_q`` (``Q_k / Q0``), the same.
        clip_probability: ``q_clip`` in (0, 1): innovations beyond the
            χ²_p quantile are shrunk radially to it before they enter the
            matching (Huber); ``None`` disables the clip.
        ridge: ``ε > 0`` of the Gauss–Newton step: a scale whose whitened
            part of ``S`` carries information ``tr(X̃²) ≪ ε`` hardly moves
            (its share of the innovations is too small to tell), one with
            ``tr(X̃²) ≫ ε`` follows the innovations at the rate ``1 − b``.
            The default 0.1: a block holding a third of ``S`` in one channel
            (``tr(X̃²) ≈ 0.1``) moves at half the rate, one holding 10 % at a
            tenth, and a 1 % share (``s_q`` on a slow state seen through a
            noisy sensor) stays where it is.
    """

    adapt_r: bool = True
    adapt_q: bool = True
    r_forgetting: float = 0.98
    q_forgetting: float = 0.98
    r_floor: float = 0.1
    r_ceiling: float = 100.0
    q_floor: float = 0.01
    q_ceiling: float = 100.0
    clip_probability: float | None = 0.999
    ridge: float = 0.1

    def __post_init__(self) -> None:
        _check_unit_interval("r_forgetting", self.r_forgetting, closed_low=True)
        _check_unit_interval("q_forgetting", self.q_forgetting, closed_low=True)
        for lo_name, hi_name in (("r_floor", "r_ceiling"), ("q_floor", "q_ceiling")):
            lo, hi = getattr(self, lo_name), getattr(self, hi_name)
            if not (math.isfinite(lo) and 0.0 < lo <= 1.0):
                raise ValueError(f"{lo_name} must be in (0, 1], got {lo}")
            if not (math.isfinite(hi) and hi >= 1.0):
                raise ValueError(f"{hi_name} must be finite and >= 1, got {hi}")
        if self.clip_probability is not None:
            _check_unit_interval("clip_probability", self.clip_probability)
        if not (math.isfinite(self.ridge) and self.ridge > 0.0):
            raise ValueError(f"ridge must be finite and > 0, got {self.ridge}")


@dataclass(frozen=True)
class AdaptiveMemory:
    """What the innovation-adaptive filter carries from step to step.

    Packed into one float array (:meth:`pack`) so that it travels through
    the ``memory`` of :class:`~.an_stukf.AnStukfResult` like the STUKF's
    ``V_k`` (the estimator keeps it opaque). Layout for ``p`` channels,
    length ``p² + p + 2``::

        [ V_k (p·p, row-major) | s_r (p) | s_q | 1 if V_k holds an estimate else 0 ]

    Attributes:
        V: strong-tracking innovation-covariance estimate ``V_{k−1}``
            ``(p, p)``, or ``None`` before the first step.
        r_scale: per-channel measurement-noise scales ``s_r`` ``(p,)``.
        q_scale: process-noise scale ``s_q``.
    """

    V: Array | None
    r_scale: Array
    q_scale: float

    @staticmethod
    def fresh(p: int) -> AdaptiveMemory:
        """The memory of a (re)started filter: no ``V``, all scales 1 (the base noise)."""
        return AdaptiveMemory(V=None, r_scale=np.ones(p), q_scale=1.0)

    @staticmethod
    def size(p: int) -> int:
        """Length ``p² + p + 2`` of the packed array."""
        return p * p + p + 2

    def pack(self) -> Array:
        """The memory as one ``(p² + p + 2,)`` float array (layout in the class docstring)."""
        p = self.r_scale.shape[0]
        out = np.zeros(self.size(p))
        if self.V is not None:
            out[: p * p] = self.V.ravel()
            out[-1] = 1.0
        out[p * p : p * p + p] = self.r_scale
        out[p * p + p] = self.q_scale
        return out

    @staticmethod
    def unpack(memory: Array | None, p: int) -> AdaptiveMemory:
        """Read a packed memory; ``None`` is a fresh one, a ``(p, p)`` array a bare ``V_k``.

        A ``(p, p)`` array is what the paper's variants carry: accepted so that
        a filter can switch variant on the fly, with fresh scales.

        Raises:
            ValueError: on any other shape, a non-finite entry or a scale ``≤ 0``.
        """
        if memory is None:
            return AdaptiveMemory.fresh(p)
        m = np.asarray(memory, dtype=float)
        if m.shape == (p, p):
            return AdaptiveMemory(V=m, r_scale=np.ones(p), q_scale=1.0)
        if m.shape != (AdaptiveMemory.size(p),) or not np.isfinite(m).all():
            raise ValueError(
                f"memory must be None, a (p, p) V or a finite ({AdaptiveMemory.size(p)},) packed array, "
                f"got shape {m.shape}"
            )
        r_scale = m[p * p : p * p + p]
        q_scale = float(m[p * p + p])
        if not (r_scale.min() > 0.0 and q_scale > 0.0):
            raise ValueError(f"memory scales must be > 0, got r_scale={r_scale}, q_scale={q_scale}")
        V = m[: p * p].reshape(p, p) if m[-1] != 0.0 else None
        return AdaptiveMemory(V=V, r_scale=r_scale, q_scale=q_scale)


def first_state_speed(x: Array) -> float:
    """``|x[0]|``: the rolling speed of a vehicle state whose first element is the forward speed.

    The default :attr:`LowSpeedGuard.speed` hook (the skid-steer state is
    ``[v_x, v_y, r]``). A model with another layout passes its own hook.
    """
    return abs(float(x[0]))


@dataclass(frozen=True, kw_only=True)
class LowSpeedGuard:
    """Weights the tire-sideslip term of B.10 down at low rolling speed.

    ``ᾱ_eff = w(v) ᾱ`` with ``w(v) = min(1, v / v_min)`` (``v = speed(x̄) ≥ 0``
    at the predicted mean): continuous (no chattering at the threshold), 0 at
    standstill, where ``α = atan2(v_y, |v_x|)`` tends to ±π/2 and carries no
    information about the tire-model error.

    Args:
        min_speed: ``v_min > 0``, in the units of ``speed`` (m/s for the
            default hook on the skid steer).
        speed: hook ``x̄ ↦ v ≥ 0``; default :func:`first_state_speed` (the
            only place a state layout is assumed; documented there).
    """

    min_speed: float = 0.5
    speed: Callable[[Array], float] = field(default=first_state_speed)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_speed) and self.min_speed > 0.0):
            raise ValueError(f"min_speed must be finite and > 0, got {self.min_speed}")
        if not callable(self.speed):
            raise ValueError(f"speed must be callable, got {type(self.speed).__name__}")

    def weight(self, x: Array) -> float:
        """``w = min(1, speed(x)/v_min)`` in [0, 1] (0 for a non-finite speed)."""
        v = abs(float(self.speed(x)))
        if not math.isfinite(v):
            return 0.0
        return min(1.0, v / self.min_speed)


@lru_cache(maxsize=256)
def huber_clip(p: int, probability: float) -> tuple[float, float]:
    """``(c², κ)`` of the radial Huber clip at the χ²_p quantile of ``probability`` (cached).

    ``κ = E[min(X, c²)]/p`` for ``X ~ χ²_p``, using ``E[X 1{X ≤ c²}] = p F_{χ²_{p+2}}(c²)``:
    ``κ = F_{χ²_{p+2}}(c²) + (c²/p)(1 − F_{χ²_p}(c²))``. Clipped and divided by
    ``κ``, a consistent innovation still has ``E[ν_c ν_cᵀ]/κ = S`` (the
    whitened innovation is spherically symmetric).

    Raises:
        ValueError: on ``p < 1`` or a probability outside (0, 1).
    """
    if int(p) != p or p < 1:
        raise ValueError(f"p must be a positive integer, got {p!r}")
    _check_unit_interval("probability", probability)
    c2 = chi2_ppf(probability, p)
    kappa = chi2_cdf(c2, p + 2) + c2 / p * chi2_sf(c2, p)
    return c2, kappa


def update_noise_scales(
    memory: AdaptiveMemory,
    config: InnovationNoiseConfig,
    *,
    innovation: Array,
    P_zz: Array,
    R: Array,
    P_xz: Array,
    P_prior: Array,
    Q: Array,
    whitened: tuple[Array, Array] | None = None,
) -> tuple[Array, float]:
    """One Gauss–Newton matching step of the scales ``s_r, s_q`` (module docstring for the equations).

    Args:
        memory: the scales ``s_r`` ``(p,)``, ``s_q`` used at this step.
        config: forgetting, ridge, bounds and clip.
        innovation: ``ν = z − ẑ`` of the update ``(p,)``.
        P_zz: innovation covariance ``S`` the update used ``(p, p)``.
        R: ``R_k`` the update used ``(p, p)``.
        P_xz: state–measurement cross covariance of the update ``(n, p)``.
        P_prior: ``P̄ = λ P̄0 + Q_k`` the update's points were drawn from ``(n, n)``.
        Q: ``Q_k`` of the step ``(n, n)``.
        whitened: ``(L⁻¹, L⁻¹ν)`` of ``S = L Lᵀ`` if the caller has it
            (:func:`~.adaptive.whiten`); computed here otherwise.

    Returns:
        ``(s_r, s_q)`` for the next step, inside their bounds; unchanged when
        ``S`` is not positive definite (the update's NIS is infinite).
    """
    r_scale, q_scale = memory.r_scale, memory.q_scale
    adapt_r, adapt_q = config.adapt_r, config.adapt_q
    if not (adapt_r or adapt_q):
        return r_scale, q_scale
    if whitened is None:
        whitened = whiten(P_zz, innovation)
        if whitened is None:
            return r_scale, q_scale
    W, w = whitened  # L⁻¹, L⁻¹ν
    p = w.shape[0]
    nis = float(w @ w)
    if not math.isfinite(nis):
        return r_scale, q_scale
    g2, kappa = 1.0, 1.0
    if config.clip_probability is not None:
        c2, kappa = huber_clip(p, config.clip_probability)
        if nis > c2:
            g2 = c2 / nis  # radial Huber clip of the whitened innovation: w_c = g w
    # Whitened covariance matching, linearised in θ = ln s (Gauss–Newton with ridge ε):
    #   (G + ε I) Δθ = h,   G_jk = tr(X̃_j X̃_k),   h_j = w_cᵀ X̃_j w_c / κ − tr(X̃_j),   X̃ = L⁻¹ X L⁻ᵀ
    # with the whitened parts of S, one symmetric (p, p) slice each:
    #   R blocks X_{r,i} = ½(E_i R + R E_i):  X̃_{r,i} = ½(a_i b_iᵀ + b_i a_iᵀ),  a_i = L⁻¹e_i, b_i = L⁻¹R e_i
    #   Q block  X_q = H̃ Q_k H̃ᵀ:              X̃_q = L⁻¹ X_q L⁻ᵀ
    # For symmetric slices tr(X̃_j X̃_k) = Σ X̃_j ∘ X̃_k: G is one product of the flattened slices.
    m = (p if adapt_r else 0) + (1 if adapt_q else 0)
    X = np.empty((m, p, p))
    if adapt_r:
        outer = W.T[:, :, None] * (W @ R).T[:, None, :]  # a_i b_iᵀ
        np.add(outer, outer.transpose(0, 2, 1), out=X[:p])
        X[:p] *= 0.5
    if adapt_q:
        X[m - 1] = W @ _hqh_spd(P_xz, P_prior, Q) @ W.T
    X = X.reshape(m, p * p)
    G = X @ X.T
    h = X @ ((g2 / kappa) * (w[:, None] * w).ravel()) - X[:, :: p + 1].sum(axis=1)
    G.flat[:: m + 1] += config.ridge
    try:
        Lg = cholesky(G)
    except np.linalg.LinAlgError:
        return r_scale, q_scale
    step = solve_lower(Lg, solve_lower(Lg, h), transpose=True)
    if not np.isfinite(step).all():
        return r_scale, q_scale
    if adapt_r:
        r_scale = np.minimum(
            np.maximum(r_scale * np.exp((1.0 - config.r_forgetting) * step[:p]), config.r_floor), config.r_ceiling
        )
    if adapt_q:
        q_scale = q_scale * math.exp((1.0 - config.q_forgetting) * float(step[-1]))
        q_scale = min(max(q_scale, config.q_floor), config.q_ceiling)
    return r_scale, float(q_scale)


def _hqh_spd(P_xz: Array, P_prior: Array, Q: Array) -> Array:
    """``H̃ Q H̃ᵀ``, ``H̃ = P_xzᵀ P̄⁻¹``, by a Cholesky of ``P̄`` (:func:`~.adaptive._hqh` when it is singular)."""
    try:
        L = cholesky(P_prior)
    except np.linalg.LinAlgError:
        return _hqh(P_xz, P_prior, Q)
    Ht = solve_lower(L, solve_lower(L, P_xz), transpose=True)  # H̃ᵀ = P̄⁻¹ P_xz
    return np.asarray(Ht.T @ Q @ Ht, dtype=float)
