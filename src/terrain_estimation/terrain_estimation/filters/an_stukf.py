"""UKF, strong-tracking UKF and AN-STUKF as one step ([SS] section 4; MODELS.md B.8–B.10).

:class:`AdaptiveStrongTrackingUKF` composes the building blocks of
:mod:`.ukf` and :mod:`.adaptive` (no filter equation is re-implemented here)::

    variant "ukf":      state = ukf.predict(...);  state, info = ukf.update(...)          (B.8)
    variant "stukf":    pred = ukf.propagate(...)                                          (x̄, P̄0, Q_k)
                        moments at (x̄, P̄0 + Q_k) → e, P_zz, P_xz
                        λ, V = suboptimal_fading_factor(e, ..., V_prev)                   (B.9)
                        state, info = ukf.update(pred.state(λ), z, ...)                   (P̄ = λ P̄0 + Q_k)
    variant "an_stukf": as "stukf", but first                                              (B.10)
                        ᾱ = mean |α_ij(x̄)|  (tire sideslip at the PREDICTED mean)
                        Q_k = Q0 (1 + K_q ᾱ),  R_k = R0 / (1 + K_r ᾱ)   (adapt_noise_sqrt)
                        and Q_k, R_k are used for the fading factor and the update.

The "stukf" path is exactly :func:`~.adaptive.strong_tracking_predict`
followed by the update; it is spelled out from the same parts (``propagate``,
``measurement_moments``, ``suboptimal_fading_factor``,
``SigmaPointPrediction.state``) so that the AN-STUKF can evaluate the
sideslip at the predicted mean ``x̄`` and swap in the adapted ``Q_k`` without
propagating the points a second time (``x̄`` does not depend on Q; the
propagation is the expensive part, a vehicle model with Euler sub-steps).
Once :meth:`~AdaptiveStrongTrackingUKF.step` has checked its arguments it
calls the UKF's private cores of those methods (``_propagate_points``,
``_moments``, ``_gain_update``: the one implementation of each, which the
public methods run after their own checks) and the arithmetic of
:func:`~.adaptive.adapt_noise_sqrt`, so nothing is checked twice per step
(the skid-steer estimator runs one step per IMU sample; a test compares the
step with the composition of the former public calls, bit for bit).

The adaptation needs the model to give the tire sideslip angles at a state:
:class:`TireSideslipModel` (e.g.
:class:`~terrain_estimation.models.skid_steer_observer.SkidSteerObserverModel`).

Innovation-adaptive variants (MODELS.md B.12; :mod:`.noise_adaptation`), which
act on what the innovations say rather than on a schedule::

    variant "adaptive":  s_r, s_q, V_{k−1} from memory (fresh: 1, 1, None)
                         Q_k = s_q Q0,  R_k = D R0 D,  D = diag(√s_r)
                         x̄, P̄0 = propagate;  moments at (x̄, P̄0 + Q_k) → e, S = P_zz, P_xz
                         λ, V = suboptimal_fading_factor(..., criterion="whitened")      (B.12)
                              active when eᵀS⁻¹e > χ²_p(probability),
                              c = tr(S⁻¹N)/tr(S⁻¹M),  λ = min(max(1, c), λ_max)
                         update from P̄ = λ P̄0 + Q_k                                      (B.8)
                         ln s_r, ln s_q ← + (1 − b) Δθ: one Gauss–Newton step matching the
                                    whitened innovation covariance to S (Huber clip, ridge,
                                    floors and ceilings; update_noise_scales)
    variant "adaptive_sideslip": as "adaptive", with the B.10 law on top:
                         ᾱ_eff = w(v) mean|α_ij(x̄)|,  w = min(1, v/v_min)   (LowSpeedGuard)
                         Q_k = s_q (1 + K_q ᾱ_eff) Q0,  R_k = D R0 D / (1 + K_r ᾱ_eff)

The scales adapt after the update and act from the next step (one moment
evaluation per step, as the STUKF). They travel in ``memory`` packed with
``V_k`` (:class:`~.noise_adaptation.AdaptiveMemory`): the estimator keeps it
opaque, as it keeps the STUKF's ``V_k``.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from terrain_estimation.checks import check_fields

from .adaptive import (
    StrongTrackingConfig,
    _adapted_noise_factors,
    _checked_slip_angles,
    _whitened_fading_factor,
    innovation_covariance_estimate,
    suboptimal_fading_factor,
    whiten,
)
from .base import Array, GaussianState, StateSpaceModel, check_square, check_vector
from .kalman import check_factor, check_measurement, symmetrise
from .noise_adaptation import AdaptiveMemory, InnovationNoiseConfig, LowSpeedGuard, update_noise_scales
from .ukf import UnscentedKalmanFilter

__all__ = [
    "Variant",
    "VARIANTS",
    "ADAPTIVE_VARIANTS",
    "TireSideslipModel",
    "AnStukfResult",
    "AdaptiveStrongTrackingUKF",
]

Variant = Literal["ukf", "stukf", "an_stukf", "adaptive", "adaptive_sideslip"]
#: The filter variants of [SS]: plain UKF (B.8), + strong tracking (B.9), + adaptive noise (B.10);
#: then the innovation-adaptive ones (B.12): whitened strong tracking + innovation-matched noise
#: scales, and the same with the B.10 sideslip law guarded at low speed.
VARIANTS: tuple[str, ...] = ("ukf", "stukf", "an_stukf", "adaptive", "adaptive_sideslip")
#: The variants whose noise follows the innovations (memory: a packed AdaptiveMemory).
ADAPTIVE_VARIANTS: tuple[str, ...] = ("adaptive", "adaptive_sideslip")


@runtime_checkable
class TireSideslipModel(StateSpaceModel, Protocol):
    """A model that also gives the tire sideslip angles that drive the noise adaptation (B.10)."""

    def tire_sideslip(self, x: Array, u: Any) -> Array:
        """Tire sideslip angles α (rad) at the state ``x`` ``(n,)``, any shape."""
        ...


@dataclass(frozen=True)
class AnStukfResult:
    """What one :meth:`AdaptiveStrongTrackingUKF.step` did.

    Attributes:
        fading_factor: strong-tracking ``λ_k ≥ 1`` (1 for the plain UKF).
        noise_scale: ``Q_k / Q0`` of the step: ``1 + K_q ᾱ_k`` for "an_stukf",
            ``s_q`` for "adaptive", ``s_q (1 + K_q ᾱ_eff)`` for
            "adaptive_sideslip", 1 otherwise.
        mean_abs_sideslip: ``ᾱ_k`` (rad) at the predicted mean, after the
            low-speed weight if one applies (0 unless the variant uses B.10).
        nis: normalised innovation squared of the update.
        innovation: ``z − ẑ`` of the update, at the (possibly inflated)
            prediction ``(p,)``.
        innovation_cov: its covariance ``P_zz`` ``(p, p)``.
        accepted: the update was applied (False only when the UKF's gate rejects).
        memory: strong-tracking innovation-covariance estimate ``V_k``
            ``(p, p)``; for the innovation-adaptive variants ``V_k`` and the
            noise scales packed in one ``(p² + p + 2,)`` array
            (:class:`~.noise_adaptation.AdaptiveMemory`). Pass it back as
            ``memory`` at the next step (None for the plain UKF, which does
            not keep one).
        measurement_noise_scale: ``R_k,ii / R0_ii`` per channel ``(p,)`` of
            the step (None for the paper's variants, whose ``R`` scale is
            ``1/(1 + K_r ᾱ)`` for every channel).
        prior_cov: the predicted covariance ``P̄`` the update started from
            ``(n, n)`` (after any fading).
        cross_cov: ``P_xz`` of the update ``(n, p)``: with ``innovation_cov``
            the gain ``K = P_xz P_zz⁻¹``, and ``P⁺ P̄⁻¹ = I − K H̃`` with the
            filter's statistical linearisation ``H̃`` (a consider analysis
            needs both, :mod:`terrain_estimation.estimators.skid_steer_consider`).
    """

    fading_factor: float
    noise_scale: float
    mean_abs_sideslip: float
    nis: float
    innovation: Array
    innovation_cov: Array
    accepted: bool
    memory: Array | None
    measurement_noise_scale: Array | None = None
    prior_cov: Array | None = None
    cross_cov: Array | None = None


@dataclass(frozen=True, kw_only=True)
class AdaptiveStrongTrackingUKF:
    """UKF / STUKF / AN-STUKF step over a :class:`~.base.GaussianState` (MODELS.md B.8–B.10).

    Variants (equations in the module docstring):

    * ``"ukf"``: B.8. ``"stukf"``: B.8 + B.9. ``"an_stukf"``: B.8 + B.9 +
      B.10, the paper's filter as reconstructed (bit for bit as before the
      innovation-adaptive variants were added).
    * ``"adaptive"``: B.8 + strong tracking on whitened innovations (B.12) +
      innovation-matched noise scales (:mod:`.noise_adaptation`); ``k_q``, ``k_r``
      are not used.
    * ``"adaptive_sideslip"``: ``"adaptive"`` with the B.10 sideslip law on
      top, its ``ᾱ`` weighted by :class:`~.noise_adaptation.LowSpeedGuard`.

    Args:
        variant: one of :data:`VARIANTS`.
        ukf: the unscented filter (sigma-point parameters α, β, κ; NIS gate).
        strong_tracking: ``ρ, β_w, γ_th, λ_max``, criterion and χ²
            probability of the fading factor (B.9, B.12). A criterion of
            ``None`` means ``"paper"`` for "stukf"/"an_stukf" and
            ``"whitened"`` for the innovation-adaptive variants.
        k_q: ``K_q ≥ 0`` (rad⁻¹), growth of Q with the mean tire sideslip (B.10).
        k_r: ``K_r ≥ 0`` (rad⁻¹), shrinking of R with it.
        q0_sqrt: factor of the base process noise ``Q0`` ``(n, q)``; None uses
            ``model.process_noise_sqrt(x, u, dt)`` (which may scale with dt).
        r0_sqrt: factor of the base measurement noise ``R0`` ``(p, r)``; None
            uses ``model.measurement_noise_sqrt()``.
        noise: the innovation-driven adaptation (innovation-adaptive variants only).
        low_speed_guard: weight of the sideslip term at low speed. ``None``
            means none for "an_stukf" (the paper's law as reconstructed) and
            ``LowSpeedGuard()`` (``v_min = 0.5``, ``v = |x̄[0]|``) for
            "adaptive_sideslip"; give one to guard "an_stukf" too.
    """

    variant: Variant = "an_stukf"
    ukf: UnscentedKalmanFilter = field(default_factory=UnscentedKalmanFilter)
    strong_tracking: StrongTrackingConfig = field(default_factory=StrongTrackingConfig)
    k_q: float = 5.0
    k_r: float = 2.0
    q0_sqrt: Array | None = None
    r0_sqrt: Array | None = None
    noise: InnovationNoiseConfig = field(default_factory=InnovationNoiseConfig)
    low_speed_guard: LowSpeedGuard | None = None
    _st: StrongTrackingConfig = field(init=False, repr=False, compare=False)
    _guard: LowSpeedGuard | None = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {VARIANTS}, got {self.variant!r}")
        if not isinstance(self.ukf, UnscentedKalmanFilter):
            raise ValueError(f"ukf must be an UnscentedKalmanFilter, got {type(self.ukf).__name__}")
        if not isinstance(self.strong_tracking, StrongTrackingConfig):
            raise ValueError("strong_tracking must be a StrongTrackingConfig")
        if not isinstance(self.noise, InnovationNoiseConfig):
            raise ValueError(f"noise must be an InnovationNoiseConfig, got {type(self.noise).__name__}")
        if self.low_speed_guard is not None and not isinstance(self.low_speed_guard, LowSpeedGuard):
            raise ValueError(
                f"low_speed_guard must be None or a LowSpeedGuard, got {type(self.low_speed_guard).__name__}"
            )
        adaptive = self.variant in ADAPTIVE_VARIANTS
        st = self.strong_tracking
        if adaptive and st.criterion is None:
            st = dataclasses.replace(st, criterion="whitened")
        object.__setattr__(self, "_st", st)
        guard = self.low_speed_guard
        if guard is None and self.variant == "adaptive_sideslip":
            guard = LowSpeedGuard()
        object.__setattr__(self, "_guard", guard)
        check_fields(self, ("k_q", "k_r"), rule="non_negative")
        for name in ("q0_sqrt", "r0_sqrt"):
            value = getattr(self, name)
            if value is not None:
                arr = np.array(value, dtype=float)
                if arr.ndim != 2 or arr.size == 0 or not np.isfinite(arr).all():
                    raise ValueError(f"{name} must be None or a finite non-empty 2-D factor, got shape {arr.shape}")
                arr.setflags(write=False)
                object.__setattr__(self, name, arr)

    def initial_state(self, x0: Any, P0: Any) -> GaussianState:
        """``GaussianState`` from a finite mean ``(n,)`` and a symmetric ``P0`` ``(n, n)``."""
        return self.ukf.initial_state(x0, P0)

    def step(
        self,
        state: GaussianState,
        z: Any,
        model: StateSpaceModel,
        u: Any,
        dt: float,
        memory: Array | None = None,
    ) -> tuple[GaussianState, AnStukfResult]:
        """One predict + update of the selected variant.

        Args:
            state: posterior at step k−1, ``x`` ``(n,)``, ``P`` ``(n, n)``.
            z: measurement at step k ``(p,)``, finite.
            model: the model (``f``, ``h`` vectorised over points); for
                ``"an_stukf"`` a :class:`TireSideslipModel`.
            u: input over the step, passed to ``f``, ``h`` and ``tire_sideslip``.
            dt: step length (s).
            memory: the previous step's ``result.memory`` (``V_{k−1}``, or the
                packed :class:`~.noise_adaptation.AdaptiveMemory` of the
                innovation-adaptive variants); None at the first step or after
                a restart (fresh scales: the base noise).

        Returns:
            ``(posterior, result)``.

        Raises:
            ValueError: on wrong shapes, non-finite ``z`` or model outputs, or a
                model without ``tire_sideslip`` for "an_stukf".
        """
        n, p = model.state_dim, model.measurement_dim
        x = check_vector("state.x", state.x, n)
        zv = check_measurement(z, p)
        return self._step(state, x, zv, model, u, dt, memory)

    def _step(
        self, state: GaussianState, x: Array, zv: Array, model: StateSpaceModel, u: Any, dt: float, memory: Array | None
    ) -> tuple[GaussianState, AnStukfResult]:
        """:meth:`step` once ``x = state.x`` is a float ``(n,)`` array and ``zv`` a finite float ``(p,)``
        measurement (the skid-steer estimator, whose state and measurement are that by construction,
        calls it directly; the rest is checked here)."""
        n, p = model.state_dim, model.measurement_dim
        Lq0 = None if self.q0_sqrt is None else check_factor("q0_sqrt", self.q0_sqrt, n)
        Rs0 = None if self.r0_sqrt is None else check_factor("r0_sqrt", self.r0_sqrt, p)
        if self.variant == "ukf":
            # UnscentedKalmanFilter.predict + update, with the update's moments kept for the result.
            prior = self.ukf.predict(state, model, u, dt, process_noise_sqrt=Lq0)
            mm = self.ukf.measurement_moments(prior, model, u, measurement_noise_sqrt=Rs0)
            nu = zv - mm.z_hat
            return _gain_step(self.ukf, prior.x, prior.P, nu, mm.P_zz, mm.P_xz, 1.0, 1.0, 0.0, memory)

        if Lq0 is None:
            Lq0 = check_factor("model.process_noise_sqrt", model.process_noise_sqrt(x, u, dt), n)
        if Rs0 is None:
            Rs0 = check_factor("model.measurement_noise_sqrt", model.measurement_noise_sqrt(), p)
        if self.variant in ADAPTIVE_VARIANTS:
            return self._adaptive_step(state, x, zv, model, u, dt, memory, Lq0, Rs0)
        # From here on the arguments are checked: the UKF's cores (the same arithmetic as its
        # propagate / measurement_moments / update) run without repeating the checks.
        ukf = self.ukf
        P = check_square("state.P", state.P, n)
        x_bar, P0 = ukf._propagate_points(x, P, model, u, dt)  # x̄, P̄0 (B.8)
        Lq, Rs = Lq0, Rs0
        noise_scale, a_bar = 1.0, 0.0
        if self.variant == "an_stukf":
            # B.10: the tire sideslip at the predicted mean x̄ drives Q_k and R_k (x̄ and P̄0 do not depend on Q).
            alpha = self._sideslip(model, x_bar, u)
            Lq, Rs, noise_scale, a_bar = _adapted_noise_factors(Lq0, Rs0, alpha, self.k_q, self.k_r)
        Q = Lq @ Lq.T
        # B.9, as strong_tracking_predict: moments at the plain prediction, λ, P̄ = λ P̄0 + Q_k.
        # SigmaPointPrediction.state() is symmetrise(λ P̄0 + Q_k); at λ = 1 the product is P̄0 exactly.
        P_prior = symmetrise(P0 + Q)
        z_hat, P_zz, P_xz, R = ukf._moments(x_bar, P_prior, Rs, model, u)
        nu = zv - z_hat
        lam, V = suboptimal_fading_factor(nu, P_zz, P_xz, P_prior, R, Q, memory, self._st)
        if lam != 1.0:
            # Inflated: the update redraws the points from P̄ = λ P̄0 + Q_k (at λ = 1 its points and
            # moments would be the ones just computed).
            P_prior = symmetrise(lam * P0 + Q)
            z_hat, P_zz, P_xz, _ = ukf._moments(x_bar, P_prior, Rs, model, u)
            nu = zv - z_hat
        return _gain_step(ukf, x_bar, P_prior, nu, P_zz, P_xz, lam, noise_scale, a_bar, V)

    def _sideslip(self, model: StateSpaceModel, x_bar: Array, u: Any) -> Array:
        """Tire sideslip angles at ``x̄`` (B.10), times the low-speed weight when a guard applies.

        ``mean|w α| = w mean|α|`` for ``w ≥ 0``, so weighting the angles weights ``ᾱ``.
        """
        sideslip = getattr(model, "tire_sideslip", None)  # TireSideslipModel (cheaper than isinstance)
        if not callable(sideslip):
            raise ValueError(f"variant {self.variant!r} needs a model with tire_sideslip(x, u) (TireSideslipModel)")
        alpha = _checked_slip_angles(sideslip(x_bar, u))
        if self._guard is not None:
            alpha = self._guard.weight(x_bar) * alpha
        return alpha

    def _adaptive_step(
        self,
        state: GaussianState,
        x: Array,
        zv: Array,
        model: StateSpaceModel,
        u: Any,
        dt: float,
        memory: Array | None,
        Lq0: Array,
        Rs0: Array,
    ) -> tuple[GaussianState, AnStukfResult]:
        """The "adaptive" / "adaptive_sideslip" step (module docstring) on checked arguments."""
        n, p = x.shape[0], zv.shape[0]
        mem = AdaptiveMemory.unpack(memory, p)
        ukf = self.ukf
        P = check_square("state.P", state.P, n)
        x_bar, P0 = ukf._propagate_points(x, P, model, u, dt)  # x̄, P̄0 (B.8)
        q_gain, r_gain, a_bar = 1.0, 1.0, 0.0
        if self.variant == "adaptive_sideslip":
            alpha = self._sideslip(model, x_bar, u)
            a_bar = float(np.abs(alpha).sum() / alpha.size)  # ᾱ_eff (B.10 with the low-speed weight)
            q_gain, r_gain = 1.0 + self.k_q * a_bar, 1.0 + self.k_r * a_bar
        # Q_k = s_q g_q Q0;  R_k = D R0 D / g_r with D = diag(√s_r): positive definite for s > 0.
        noise_scale = mem.q_scale * q_gain
        Lq = Lq0 * math.sqrt(noise_scale)
        r_scale = mem.r_scale / r_gain
        Rs = np.sqrt(r_scale)[:, None] * Rs0
        Q = Lq @ Lq.T
        P_prior = symmetrise(P0 + Q)
        z_hat, P_zz, P_xz, R = ukf._moments(x_bar, P_prior, Rs, model, u)
        nu = zv - z_hat
        st = self._st
        whitened: tuple[Array, Array] | None = None
        if st.criterion == "whitened":
            # suboptimal_fading_factor's whitened branch, keeping L⁻¹, L⁻¹ν for the noise matching (B.12).
            whitened = whiten(P_zz, nu)
            V = innovation_covariance_estimate(nu, mem.V, st.rho)
            lam = _whitened_fading_factor(nu, V, P_zz, P_xz, P_prior, R, Q, st, whitened)
        else:
            lam, V = suboptimal_fading_factor(nu, P_zz, P_xz, P_prior, R, Q, mem.V, st)
        if lam != 1.0:  # P̄ = λ P̄0 + Q_k: redraw the points, as in the STUKF
            P_prior = symmetrise(lam * P0 + Q)
            z_hat, P_zz, P_xz, _ = ukf._moments(x_bar, P_prior, Rs, model, u)
            nu = zv - z_hat
            whitened = None
        # Matching of the whitened innovation, also on a rejected update (clipped): the scales act from k + 1.
        s_r, s_q = update_noise_scales(
            mem, self.noise, innovation=nu, P_zz=P_zz, R=R, P_xz=P_xz, P_prior=P_prior, Q=Q, whitened=whitened
        )
        memory = AdaptiveMemory(V=V, r_scale=s_r, q_scale=s_q).pack()
        return _gain_step(ukf, x_bar, P_prior, nu, P_zz, P_xz, lam, noise_scale, a_bar, memory, r_scale)


def _gain_step(
    ukf: UnscentedKalmanFilter,
    x_bar: Array,
    P_prior: Array,
    nu: Array,
    P_zz: Array,
    P_xz: Array,
    fading_factor: float,
    noise_scale: float,
    a_bar: float,
    memory: Array | None,
    r_scale: Array | None = None,
) -> tuple[GaussianState, AnStukfResult]:
    """The gated gain update of every variant (the UKF's) from ``(x̄, P̄)`` and its moments, and the step's result.

    On a rejection the posterior is the prior ``(x̄, P̄)``; ``memory`` is what the next step takes back and
    ``r_scale`` the measurement-noise scales of the innovation-adaptive variants (None for the others).
    """
    updated, nis = ukf._gain_update(x_bar, P_prior, nu, P_zz, P_xz)
    post = GaussianState(x=x_bar, P=P_prior) if updated is None else GaussianState(x=updated[0], P=updated[1])
    return post, AnStukfResult(
        fading_factor=float(fading_factor),
        noise_scale=float(noise_scale),
        mean_abs_sideslip=float(a_bar),
        nis=float(nis),
        innovation=nu,
        innovation_cov=P_zz,
        accepted=updated is not None,
        memory=memory,
        measurement_noise_scale=r_scale,
        prior_cov=P_prior,
        cross_cov=P_xz,
    )
