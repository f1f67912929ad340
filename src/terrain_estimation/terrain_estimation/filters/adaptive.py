"""Building blocks of the adaptive (AN-)STUKF: strong tracking and noise adaptation.

Pure functions over arrays and filter states; the skid-steer AN-STUKF
composes them around an :class:`~terrain_estimation.filters.ukf.UnscentedKalmanFilter`
(AN-STUKF = UKF + strong tracking + noise adaptation, MODELS.md B.8–B.10)::

    noise = adapt_noise_sqrt(Q0_sqrt, R0_sqrt, slip_angles, k_q=..., k_r=...)     # B.10
    st = strong_tracking_predict(ukf, state, model, u, dt, z, V_prev=V,
                                 process_noise_sqrt=noise.process_noise_sqrt,
                                 measurement_noise_sqrt=noise.measurement_noise_sqrt)  # B.9
    state, info = ukf.update(st.state, z, model, u,
                             measurement_noise_sqrt=noise.measurement_noise_sqrt)
    V = st.V

Two activation criteria and fading-factor sizes (:attr:`StrongTrackingConfig.criterion`):

* ``"paper"`` (MODELS.md B.9, the reconstruction): active when
  ``eᵀe > γ_th tr(P_zz)``, ``c = tr(N)/tr(M)``. Both sums add channels in
  their own units (m/s² and rad/s for the skid steer), so a channel whose
  variance is a small part of the trace never counts (MODELS.md B.12: a
  yaw-rate bias with ν²/P_zz ≈ 7 fires it on 0 % of the steps).
* ``"whitened"`` (MODELS.md B.12): active when the normalised innovation
  squared ``NIS = eᵀ S⁻¹ e`` (``S = P_zz``) exceeds the χ²_p quantile of
  probability :attr:`~StrongTrackingConfig.probability`, and
  ``c = tr(S⁻¹ N)/tr(S⁻¹ M) = tr(L⁻¹ N L⁻ᵀ)/tr(L⁻¹ M L⁻ᵀ)`` with
  ``S = L Lᵀ``: Zhou–Frank's factor for the whitened measurement ``L⁻¹ z``,
  whose predicted innovation covariance is the identity. Both the test and
  ``c`` are invariant under any invertible rescaling of the measurement
  (``z → D z``: ``S → D S Dᵀ``, ``N → D N Dᵀ``), so every channel counts in
  its own units.

Sources: Zhou & Frank, *Fault diagnosis and fault tolerant control*, 1996
(strong tracking filter, suboptimal fading factor), as reconstructed in
MODELS.md B.9; the whitened criterion is MODELS.md B.12; the noise law is the
reconstruction of MODELS.md B.10. Innovation-driven noise adaptation is in
:mod:`.noise_adaptation`.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Literal

import numpy as np

from .base import Array, GaussianState, StateSpaceModel
from .chi2 import chi2_ppf
from .kalman import check_measurement
from .sigma_points import cholesky, solve_lower
from .ukf import SigmaPointKalmanFilter

__all__ = [
    "StrongTrackingConfig",
    "StrongTrackingPrediction",
    "NoiseAdaptation",
    "Criterion",
    "CRITERIA",
    "innovation_is_consistent",
    "nis_threshold",
    "whitened_innovation_is_consistent",
    "suboptimal_fading_factor",
    "innovation_covariance_estimate",
    "whiten",
    "strong_tracking_predict",
    "adapt_noise_sqrt",
]


Criterion = Literal["paper", "whitened"]
#: Activation test and fading-factor size: the paper's unwhitened traces (B.9) or whitened innovations (B.12).
CRITERIA: tuple[str, ...] = ("paper", "whitened")


@dataclass(frozen=True, kw_only=True)
class StrongTrackingConfig:
    """Parameters of the suboptimal fading factor (MODELS.md B.9, B.12).

    Args:
        rho: forgetting factor ``ρ`` of the innovation-covariance estimate,
            ``0 < ρ ≤ 1`` (the paper calls it β; renamed to avoid the UKF β).
        beta_w: weakening factor ``β_w ≥ 1``; larger values make the fading
            factor less eager (smoother, less tracking).
        gamma_th: activation threshold ``γ_th ≥ 1`` of the ``"paper"``
            criterion: the filter counts as consistent, ``λ = 1``, while
            ``eᵀe ≤ γ_th tr(P_zz)``. ``None`` computes the fading factor at
            every step (plain Zhou–Frank).
        lambda_max: cap on ``λ`` (≥ 1); bounds the covariance inflation one
            outlier can cause.
        simplified: use ``N = V − β_w R``, ``M = P_zz − R`` (the variant common
            in STUKF code) instead of removing ``H̃ Q H̃ᵀ`` as well.
        criterion: ``"paper"`` (B.9: ``eᵀe`` against ``γ_th tr(P_zz)``,
            ``c = tr(N)/tr(M)``) or ``"whitened"`` (B.12: ``NIS = eᵀS⁻¹e``
            against the χ²_p quantile of ``probability``,
            ``c = tr(S⁻¹N)/tr(S⁻¹M)``). ``None`` (default) lets the user of
            the config choose: :func:`suboptimal_fading_factor` reads it as
            ``"paper"``; :class:`~.an_stukf.AdaptiveStrongTrackingUKF` as
            ``"paper"`` for the paper's variants and ``"whitened"`` for the
            innovation-adaptive ones.
        probability: χ²_p probability of the ``"whitened"`` activation test,
            in (0, 1): on consistent innovations the fading factor is
            computed on a fraction ``1 − probability`` of the steps. ``None``
            computes it at every step.
    """

    rho: float = 0.95
    beta_w: float = 1.0
    gamma_th: float | None = 3.0
    lambda_max: float = 10.0
    simplified: bool = False
    criterion: Criterion | None = None
    probability: float | None = 0.99

    def __post_init__(self) -> None:
        if not (0.0 < self.rho <= 1.0):
            raise ValueError(f"rho must be in (0, 1], got {self.rho}")
        if not (math.isfinite(self.beta_w) and self.beta_w >= 1.0):
            raise ValueError(f"beta_w must be finite and >= 1, got {self.beta_w}")
        if self.gamma_th is not None and not (math.isfinite(self.gamma_th) and self.gamma_th >= 1.0):
            raise ValueError(f"gamma_th must be None or finite and >= 1, got {self.gamma_th}")
        if not (math.isfinite(self.lambda_max) and self.lambda_max >= 1.0):
            raise ValueError(f"lambda_max must be finite and >= 1, got {self.lambda_max}")
        if self.criterion is not None and self.criterion not in CRITERIA:
            raise ValueError(f"criterion must be None or one of {CRITERIA}, got {self.criterion!r}")
        if self.probability is not None and not (0.0 < self.probability < 1.0):
            raise ValueError(f"probability must be None or in (0, 1), got {self.probability}")


def innovation_is_consistent(innovation: Array, P_zz: Array, gamma_th: float) -> bool:
    """Activation test of MODELS.md B.9: ``eᵀe ≤ γ_th · tr(P_zz)``.

    Args:
        innovation: ``e = z − ẑ`` ``(p,)``.
        P_zz: predicted innovation covariance ``(p, p)``.
        gamma_th: threshold coefficient ``γ_th ≥ 1``.

    Returns:
        True while the innovation is as large as the filter expects it to be
        (no fading needed).
    """
    e = np.asarray(innovation, dtype=float)
    return bool(e @ e <= gamma_th * float(np.asarray(P_zz, dtype=float).trace()))


@lru_cache(maxsize=256)
def nis_threshold(p: int, probability: float) -> float:
    """χ²_p quantile of ``probability``: the NIS bound of a consistent innovation (cached).

    Args:
        p: measurement dimension ``≥ 1`` (degrees of freedom).
        probability: in (0, 1).

    Raises:
        ValueError: on ``p < 1`` or a probability outside (0, 1).
    """
    if int(p) != p or p < 1:
        raise ValueError(f"p must be a positive integer, got {p!r}")
    if not (0.0 < probability < 1.0):
        raise ValueError(f"probability must be in (0, 1), got {probability}")
    return chi2_ppf(probability, int(p))


def whitened_innovation_is_consistent(innovation: Array, P_zz: Array, probability: float) -> bool:
    """Whitened activation test (MODELS.md B.12): ``eᵀ P_zz⁻¹ e ≤ χ²_p(probability)``.

    Args:
        innovation: ``e = z − ẑ`` ``(p,)``.
        P_zz: predicted innovation covariance ``(p, p)``, positive definite.
        probability: χ²_p probability in (0, 1).

    Returns:
        True while the NIS is within the quantile. A ``P_zz`` that is not
        positive definite gives False (the NIS is infinite).
    """
    e = np.asarray(innovation, dtype=float)
    try:
        L = cholesky(np.asarray(P_zz, dtype=float))
    except np.linalg.LinAlgError:
        return False
    w = solve_lower(L, e)
    nis = float(w @ w)
    return bool(nis <= nis_threshold(e.shape[0], probability))


def suboptimal_fading_factor(
    innovation: Array,
    P_zz: Array,
    P_xz: Array,
    P_pred: Array,
    R: Array,
    Q: Array,
    V_prev: Array | None,
    config: StrongTrackingConfig | None = None,
) -> tuple[float, Array]:
    """Suboptimal fading factor ``λ_k ≥ 1`` (Zhou–Frank 1996; MODELS.md B.9, B.12).

    Equations (``e_k = z_k − ẑ_k``, ``S = P_zz = L Lᵀ``)::

        V_1 = e_1 e_1ᵀ;   V_k = (ρ V_{k−1} + e_k e_kᵀ) / (1 + ρ)
        H̃   = P_xzᵀ P̄⁻¹                    (statistical linearisation of h)
        N_k = V_k − β_w R_k − H̃ Q_k H̃ᵀ
        M_k = P_zz − R_k − H̃ Q_k H̃ᵀ        (≈ H F P Fᵀ Hᵀ)
        "paper":     c_k = tr(N_k) / tr(M_k)
        "whitened":  c_k = tr(L⁻¹ N_k L⁻ᵀ) / tr(L⁻¹ M_k L⁻ᵀ) = tr(S⁻¹ N_k) / tr(S⁻¹ M_k)
        λ_k = min(max(1, c_k), λ_max)

    ``λ_k = 1`` when the activation test passes (``"paper"``:
    :func:`innovation_is_consistent`; ``"whitened"``: ``eᵀS⁻¹e ≤ χ²_p``,
    :func:`whitened_innovation_is_consistent`), when the denominator is
    ``≤ 0`` (the propagated spread carries no
    information to rescale) or when ``c_k`` is not finite. ``V_k`` is updated
    at every step, active or not: it is a running estimate of the innovation
    covariance and would go stale if it were frozen while the filter is
    consistent.

    Args:
        innovation: ``e_k`` ``(p,)``.
        P_zz: predicted innovation covariance (with ``R``) ``(p, p)``.
        P_xz: predicted state–measurement cross covariance ``(n, p)``.
        P_pred: predicted covariance ``P̄ = P̄0 + Q_k`` the points were drawn
            from ``(n, n)``.
        R: measurement noise covariance ``(p, p)``.
        Q: process noise covariance of the step ``(n, n)``.
        V_prev: previous ``V_{k−1}`` ``(p, p)``, or ``None`` at the first step.
        config: ``ρ, β_w, γ_th, λ_max``, the variant and the criterion;
            defaults of B.9 (criterion ``None`` reads as ``"paper"``).

    Returns:
        ``(λ_k, V_k)``.
    """
    cfg = config if config is not None else StrongTrackingConfig()
    e = np.asarray(innovation, dtype=float)
    V = innovation_covariance_estimate(e, V_prev, cfg.rho)
    if cfg.criterion == "whitened":
        S = np.asarray(P_zz, dtype=float)
        return _whitened_fading_factor(e, V, S, P_xz, P_pred, R, Q, cfg, whiten(S, e)), V
    if cfg.gamma_th is not None and innovation_is_consistent(e, P_zz, cfg.gamma_th):
        return 1.0, V
    N, M = _fading_numerator_denominator(V, P_zz, P_xz, P_pred, R, Q, cfg)
    tr_m = float(np.trace(M))
    if not tr_m > 0.0:
        return 1.0, V
    c = float(np.trace(N)) / tr_m
    if not math.isfinite(c):
        return 1.0, V
    return min(max(1.0, c), cfg.lambda_max), V


def _fading_numerator_denominator(
    V: Array, P_zz: Array, P_xz: Array, P_pred: Array, R: Array, Q: Array, cfg: StrongTrackingConfig
) -> tuple[Array, Array]:
    """``N_k = V_k − β_w R_k − H̃ Q_k H̃ᵀ`` and ``M_k = P_zz − R_k − H̃ Q_k H̃ᵀ`` of the fading factor
    (without the ``H̃ Q_k H̃ᵀ`` terms in the ``simplified`` variant)."""
    N = V - cfg.beta_w * R
    M = P_zz - R
    if not cfg.simplified:
        HQH = _hqh(P_xz, P_pred, Q)
        N = N - HQH
        M = M - HQH
    return N, M


def _hqh(P_xz: Array, P_pred: Array, Q: Array) -> Array:
    """``H̃ Q H̃ᵀ`` with ``H̃ = P_xzᵀ P̄⁻¹`` (least squares when ``P̄`` is singular)."""
    try:
        H_t = np.linalg.solve(P_pred, P_xz)  # H̃ᵀ = P̄⁻¹ P_xz (P̄ symmetric)
    except np.linalg.LinAlgError:
        # P̄ singular: the least-squares H̃ is the natural linearisation on its range.
        H_t = np.linalg.lstsq(P_pred, P_xz, rcond=None)[0]
    return np.asarray(H_t.T @ Q @ H_t, dtype=float)


def innovation_covariance_estimate(e: Array, V_prev: Array | None, rho: float) -> Array:
    """``V_k = (ρ V_{k−1} + e eᵀ)/(1 + ρ)``, ``V_1 = e eᵀ`` (Zhou–Frank's running estimate, B.9)."""
    ee = e[:, None] * e  # e eᵀ
    return ee if V_prev is None else (rho * np.asarray(V_prev, dtype=float) + ee) / (1.0 + rho)


@lru_cache(maxsize=16)
def _identity(p: int) -> Array:
    """A read-only ``(p, p)`` identity (``np.eye`` once per dimension, not once per step)."""
    eye = np.eye(p)
    eye.setflags(write=False)
    return eye


def whiten(S: Array, e: Array) -> tuple[Array, Array] | None:
    """``(W, w) = (L⁻¹, L⁻¹ e)`` with ``S = L Lᵀ`` (one Cholesky, one triangular solve).

    ``NIS = wᵀw``, ``S⁻¹ = WᵀW`` and ``tr(S⁻¹ X) = tr(W X Wᵀ) = Σ_ij (W X)_ij W_ij``;
    ``S`` is never inverted as a whole. ``None`` when ``S`` is not positive definite.
    """
    p = e.shape[0]
    try:
        L = cholesky(S)
    except np.linalg.LinAlgError:
        return None
    rhs = np.empty((p, p + 1))
    rhs[:, :p] = _identity(p)
    rhs[:, p] = e
    sol = solve_lower(L, rhs)
    return sol[:, :p], sol[:, p]


def _whitened_fading_factor(
    e: Array,
    V: Array,
    S: Array,
    P_xz: Array,
    P_pred: Array,
    R: Array,
    Q: Array,
    cfg: StrongTrackingConfig,
    whitened: tuple[Array, Array] | None,
) -> float:
    """``λ_k`` of the ``"whitened"`` criterion (B.12) once ``V_k`` and ``whiten(S, e)`` are known."""
    if whitened is None:
        return 1.0  # S not positive definite: the update's NIS is infinite and it rejects anyway.
    W, w = whitened
    p = e.shape[0]
    if cfg.probability is not None and float(w @ w) <= nis_threshold(p, cfg.probability):
        return 1.0
    N, M = _fading_numerator_denominator(V, S, P_xz, P_pred, R, Q, cfg)
    tr_m = float(((W @ M) * W).sum())  # tr(L⁻¹ M L⁻ᵀ)
    if not tr_m > 0.0:
        return 1.0
    c = float(((W @ N) * W).sum()) / tr_m
    if not math.isfinite(c):
        return 1.0
    return min(max(1.0, c), cfg.lambda_max)


@dataclass(frozen=True)
class StrongTrackingPrediction:
    """Result of :func:`strong_tracking_predict`.

    Attributes:
        state: predicted state with ``P̄ = λ P̄0 + Q_k`` (update it next with
            the same filter, measurement and noise).
        fading_factor: ``λ_k ≥ 1`` (publish as ``fading_factor``, B.9).
        V: innovation-covariance estimate ``V_k`` ``(p, p)``; pass it back as
            ``V_prev`` at the next step.
        innovation: ``e_k = z − ẑ`` at the unscaled prediction ``(p,)``.
    """

    state: GaussianState
    fading_factor: float
    V: Array
    innovation: Array


def strong_tracking_predict(
    filt: SigmaPointKalmanFilter,
    state: GaussianState,
    model: StateSpaceModel,
    u: Any,
    dt: float,
    z: Any,
    *,
    V_prev: Array | None = None,
    config: StrongTrackingConfig | None = None,
    process_noise_sqrt: Any = None,
    measurement_noise_sqrt: Any = None,
) -> StrongTrackingPrediction:
    """Strong-tracking time update for a full-covariance sigma-point filter (B.9).

    1. ``x̄, P̄0, Q_k`` from ``filt.propagate`` (UKF prediction, B.8).
    2. ``ẑ, P_zz, P_xz`` from points drawn at ``(x̄, P̄0 + Q_k)``; ``e = z − ẑ``.
    3. ``λ_k`` by :func:`suboptimal_fading_factor`.
    4. ``P̄ ← λ_k P̄0 + Q_k``: only the propagated spread is inflated, not the
       process noise (Zhou–Frank scale ``F P Fᵀ``).

    The caller then runs the normal ``filt.update`` on the returned state,
    which redraws the points and recomputes ``P_zz, P_xz`` from the inflated
    covariance, as B.9 prescribes.

    Args:
        filt: an :class:`~terrain_estimation.filters.ukf.UnscentedKalmanFilter`
            (or any full-covariance sigma-point filter).
        state: posterior at step k, ``x`` ``(n,)``, ``P`` ``(n, n)``.
        model: the model; ``u`` is passed to both ``f`` and ``h``.
        u: input over the step.
        dt: step length (s).
        z: the measurement ``(p,)`` that will be used in the update.
        V_prev: ``V_{k−1}`` from the previous step, ``None`` at the first.
        config: strong-tracking parameters (defaults of B.9).
        process_noise_sqrt: ``(n, q)`` override of ``√Q_k`` (noise adaptation).
        measurement_noise_sqrt: ``(p, r)`` override of ``√R_k``; pass the same
            one to the update.

    Returns:
        The (possibly inflated) prediction, ``λ_k``, ``V_k`` and ``e_k``.

    Raises:
        ValueError: on wrong shapes, non-finite ``z`` or model outputs.
    """
    zv = check_measurement(z, model.measurement_dim)
    pred = filt.propagate(state, model, u, dt, process_noise_sqrt=process_noise_sqrt)
    prior = pred.state()
    mm = filt.measurement_moments(prior, model, u, measurement_noise_sqrt=measurement_noise_sqrt)
    e = zv - mm.z_hat
    lam, V = suboptimal_fading_factor(e, mm.P_zz, mm.P_xz, prior.P, mm.R, pred.Q, V_prev, config)
    out = prior if lam == 1.0 else pred.state(lam)
    return StrongTrackingPrediction(state=out, fading_factor=lam, V=V, innovation=e)


@dataclass(frozen=True)
class NoiseAdaptation:
    """Result of :func:`adapt_noise_sqrt`.

    Attributes:
        process_noise_sqrt: ``√Q_k = √Q0 · √(1 + K_q ᾱ)`` ``(n, q)``.
        measurement_noise_sqrt: ``√R_k = √R0 / √(1 + K_r ᾱ)`` ``(p, r)``.
        noise_scale: ``1 + K_q ᾱ`` (publish as ``noise_scale``, B.10).
        mean_abs_slip: ``ᾱ_k`` (rad).
    """

    process_noise_sqrt: Array
    measurement_noise_sqrt: Array
    noise_scale: float
    mean_abs_slip: float


def adapt_noise_sqrt(
    q0_sqrt: Any,
    r0_sqrt: Any,
    slip_angles: Any,
    *,
    k_q: float,
    k_r: float,
) -> NoiseAdaptation:
    """Sideslip-driven noise adaptation (MODELS.md B.10, [SS] eqs. 32–34 reconstructed).

    ::

        ᾱ_k = mean_ij |α_ij(x̄_k, u_k)|       ((1/6) Σ over the six tires, rad)
        Q_k = Q0 · (1 + K_q ᾱ_k)             (Q grows with the tire-model error)
        R_k = R0 / (1 + K_r ᾱ_k)             (large manoeuvres: measurements weigh more)

    Applied to factors (``√Q_k = √Q0 √(1 + K_q ᾱ)``) so no covariance is
    factored. ``K_q = K_r = 0`` returns the base noise (plain UKF/STUKF).

    Args:
        q0_sqrt: factor of ``Q0`` ``(n, q)``, per step.
        r0_sqrt: factor of ``R0`` ``(p, r)``.
        slip_angles: tire sideslip angles ``α_ij`` (rad), any shape, finite,
            evaluated by the vehicle model at the predicted state.
        k_q: ``K_q ≥ 0`` (rad⁻¹); B.10 suggests 5.
        k_r: ``K_r ≥ 0`` (rad⁻¹); B.10 suggests 2.

    Returns:
        The adapted factors, ``noise_scale`` and ``ᾱ_k``.

    Raises:
        ValueError: on negative gains, non-finite or empty slip angles, or
            factors that are not 2-D.
    """
    if not (math.isfinite(k_q) and k_q >= 0.0):
        raise ValueError(f"k_q must be finite and >= 0, got {k_q}")
    if not (math.isfinite(k_r) and k_r >= 0.0):
        raise ValueError(f"k_r must be finite and >= 0, got {k_r}")
    alpha = _checked_slip_angles(slip_angles)
    q0 = np.asarray(q0_sqrt, dtype=float)
    r0 = np.asarray(r0_sqrt, dtype=float)
    for name, arr in (("q0_sqrt", q0), ("r0_sqrt", r0)):
        if arr.ndim != 2 or arr.size == 0:
            raise ValueError(f"{name} must be a non-empty 2-D factor, got shape {arr.shape}")
    q, r, q_scale, a_bar = _adapted_noise_factors(q0, r0, alpha, k_q, k_r)
    return NoiseAdaptation(process_noise_sqrt=q, measurement_noise_sqrt=r, noise_scale=q_scale, mean_abs_slip=a_bar)


def _checked_slip_angles(slip_angles: Any) -> Array:
    """``slip_angles`` as a float array; ValueError if it is empty or not finite."""
    alpha = np.asarray(slip_angles, dtype=float)
    if alpha.size == 0 or not np.isfinite(alpha).all():
        raise ValueError("slip_angles must be non-empty and finite")
    return alpha


def _adapted_noise_factors(
    q0: Array, r0: Array, alpha: Array, k_q: float, k_r: float
) -> tuple[Array, Array, float, float]:
    """The arithmetic of :func:`adapt_noise_sqrt` on checked arguments: ``(√Q_k, √R_k, 1 + K_q ᾱ, ᾱ)``."""
    a_bar = float(np.abs(alpha).sum() / alpha.size)  # np.mean's own arithmetic, without its dispatch
    q_scale = 1.0 + k_q * a_bar
    r_scale = 1.0 + k_r * a_bar
    return q0 * math.sqrt(q_scale), r0 / math.sqrt(r_scale), q_scale, a_bar
