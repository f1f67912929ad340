"""Estimation models for soil stiffness from ride vibration (MODELS.md Part A).

Two models implement :class:`~terrain_estimation.filters.base.StateSpaceModel`
and :class:`~terrain_estimation.filters.base.JacobianModel`:

* :class:`QuarterCarModel` — the 2-DOF quarter car of Reina, Leanza, Messina
  (P-4…P-9, appendix A.1–A.4): ``x = [y1 − y2, ẏ1, y2 − h, ẏ2, k_tot]``,
  ``z = [ÿ1, ÿ2]``.
* :class:`LRVModel` — the 1-DOF Lunar Roving Vehicle (section 5.3, MODELS.md
  A.7): ``x = [y1 − h, ẏ1, k_tot]``, ``z = [ÿ1]``.

Both are bilinear: ``ẋ = A(x) x + B u + G w`` with ``A(x) = A0 + k_tot·E``,
where ``E`` has a single non-zero entry (−1/m_ns at [4, 3] for the quarter car,
−1/m_s at [2, 1] for the LRV, 1-based) and the k_tot row of ``A`` is zero
(random-walk parameter). ``z = C(x) x + D u`` with ``C(x)`` the acceleration
rows of ``A(x)`` (A.4) and ``D`` the same rows of ``B`` (zero except for the
LRV relative-damper option).

**Input between filter steps (MODELS.md A.10).** ``u`` for one filter step of
length ``dt`` is a 1-D array of the terrain elevation rate ḣ (m/s) over ``N``
equal sub-steps spanning ``dt`` (a scalar means ``N = 1``). ``f`` applies the
discrete transition sub-step by sub-step, ``x_{j+1} = Φ(k) x_j + Γ(k) B u_j``,
with ``Φ = e^{Aδ}``, ``Γ = ∫0^δ e^{As} ds`` (P-11…P-13) evaluated per point
(``(m, n, n)`` batches). Holding ḣ constant over a sub-step is exact for an
elevation that is piecewise linear between the sub-step grid points, which
is what the estimator reconstructs from a 1 kHz profile; with ``N = 1`` this
is the paper's zero-order hold over the whole 10 ms step, which biases k_tot
by +2…3 % against a smooth road (A.10.1).

**Feed-through (LRV relative damper).** With the damper on ``ẏ1 − ḣ`` the
measurement holds ``(c/m_s)·ḣ(t)`` at the measurement time (c/m_s = 20 s⁻¹
for Table 5). ``u`` may then be a :class:`StepInput` that carries ḣ(t)
besides the sub-step values; a plain array falls back to extrapolating the
last two sub-step values (:func:`hdot_at_end`), which amplifies profile noise.
:meth:`~_BilinearKtotModel.profile_error_gains` gives the sensitivity of
``z`` to errors of the reconstructed elevation and of ḣ(t), from which the
estimator inflates ``R`` by the profile noise.

**Discretisation.** ``"taylor4"`` is the paper's fourth-order series
(``A_k = Σ_{j≤4} (Aδ)^j/j!``, ``Γ_k = Σ_{j≤4} A^j δ^{j+1}/(j+1)!``);
``"expm"`` is the exact matrix exponential (augmented-matrix form). The local
truncation error of the series is ``≈ ρ(Aδ)^5/5!``: with ρ(A) ≈ 60 rad/s (wheel
hop) it is ≈ 6·10⁻⁴ at δ = 10 ms (the −0.09 % k_tot bias of A.10.2) and
≈ 6·10⁻⁹ at the 1 ms sub-steps, hence the default ``"taylor4"``.

**Keeping k_tot physical.** k_tot is the series stiffness of tire (or LRV
spring) and soil, so it lies in ``(0, k_series)``. Inside every model
evaluation (f, h, Jacobians, Q) the k_tot *used by the dynamics* is clamped to
``[ktot_min_frac·k_series, ktot_max_frac·k_series]``; the k_tot *state*
itself passes through ``f`` unchanged (exact random walk, row 5 of A.1 is
zero), so cubature points outside the range keep their spread and the
filter's covariance is not distorted. The clamped dynamics are stable and
finite for every finite input, so no NaN is produced. In the Jacobians the
derivative with respect to a clamped k_tot is zero, consistent with ``f``.
The estimator (``estimators.soil_stiffness``) additionally projects the
posterior mean into the same range.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from terrain_estimation.filters.base import Array
from terrain_estimation.models.quarter_car_discrete import (
    StepInput,
    _clip,
    _discretise_with_input,
    _run_substeps,
    discretise,
    hdot_at_end,
    substep_inputs,
)
from terrain_estimation.models.quarter_car_params import (
    _LOG_KS_RANGE,
    Discretisation,
    JacobianForm,
    KtotNoiseForm,
    LRVParams,
    QuarterCarParams,
    StiffnessState,
)
from terrain_estimation.models.soil import soil_stiffness_from_k_tot

__all__ = [
    "QuarterCarParams",
    "LRVParams",
    "QuarterCarModel",
    "LRVModel",
    "StepInput",
    "discretise",
    "substep_inputs",
    "hdot_at_end",
]


# ---------------------------------------------------------------------------
# Shared bilinear model
# ---------------------------------------------------------------------------


class _BilinearKtotModel:
    """``ẋ = (A0 + k_tot E) x + B u + G w``, ``z = C(x) x + D u`` with k_tot the last state.

    Subclasses fill the constant matrices in ``__init__``. All public methods
    accept one state ``(n,)`` or a point set ``(m, n)``.
    """

    _a0: Array
    _e: Array
    _b: Array
    _g: Array
    _rows: Array
    _sigma_q: Array
    _sqrt_r: Array
    _k_series: float
    _kmin: float
    _kmax: float
    _method: Discretisation
    _noise_form: KtotNoiseForm
    _q_ktot_per_step: float
    _ktot_step_dt: float
    _jacobian_form: JacobianForm
    _stiffness_state: StiffnessState = "k_tot"
    _q_log_ks_per_step: float = 0.0
    _log_ks_range: tuple[float, float] = _LOG_KS_RANGE

    def _finish_init(self, p: QuarterCarParams | LRVParams) -> None:
        """The settings both models take from their parameters, once the subclass has set its matrices."""
        self._sigma_q = np.sqrt(np.asarray(p.q_diag, dtype=float))
        self._sqrt_r = np.sqrt(np.asarray(p.r_diag, dtype=float))
        self._k_series = p.k_series
        self._kmin = p.ktot_min_frac * p.k_series
        self._kmax = p.ktot_max_frac * p.k_series
        self._method = p.discretisation
        self._noise_form = p.ktot_noise_form
        self._q_ktot_per_step = p.q_ktot_per_step
        self._ktot_step_dt = p.ktot_step_dt
        self._jacobian_form = p.ekf_jacobian
        self._stiffness_state = p.stiffness_state
        self._q_log_ks_per_step = p.q_log_ks_per_step
        self._log_ks_range = (float(p.log_ks_range[0]), float(p.log_ks_range[1]))
        n = self._a0.shape[0]
        k = n - 1
        # The decoupling that lets √Q_k be written column by column (A.4):
        # row and column k of G are the unit vector e_k, and column k of A is
        # zero for every k_tot (k_tot enters A only through E's single entry).
        e_k = np.zeros(n)
        e_k[k] = 1.0
        assert np.array_equal(self._g[:, k], e_k) and np.array_equal(self._g[k, :], e_k)
        assert not np.any(self._a0[k, :]) and not np.any(self._e[k, :])
        assert not np.any(self._a0[:, k]) and not np.any(self._e[:, k])
        assert self._b[k] == 0.0
        self._c0 = self._a0[self._rows]
        self._ce = self._e[self._rows]
        self._d = self._b[self._rows]
        self._feedthrough = bool(np.any(self._d))
        self._noise_cache: tuple[float, float, Array] | None = None

    # -- protocol -----------------------------------------------------------
    @property
    def state_dim(self) -> int:
        """Number of states ``n``."""
        return int(self._a0.shape[0])

    @property
    def measurement_dim(self) -> int:
        """Number of measured accelerations ``p``."""
        return int(self._rows.size)

    @property
    def k_series(self) -> float:
        """Stiffness in series with the soil (N/m); k_tot lies in ``(0, k_series)``."""
        return self._k_series

    @property
    def ktot_bounds(self) -> tuple[float, float]:
        """Clamp range of the k_tot used inside the model (N/m)."""
        return self._kmin, self._kmax

    @property
    def B(self) -> Array:  # noqa: N802 - the symbol of the paper
        """Input vector ``B`` ``(n,)`` (A.2)."""
        return self._b.copy()

    @property
    def G(self) -> Array:  # noqa: N802
        """Process-noise input matrix ``G`` ``(n, n)`` (A.3)."""
        return self._g.copy()

    def clamp_ktot(self, k_tot: Any) -> Array:
        """k_tot used by the dynamics: clipped into :attr:`ktot_bounds` (N/m)."""
        return _clip(np.asarray(k_tot, dtype=float), self._kmin, self._kmax)

    # -- the augmented stiffness state ("k_tot" or "log_k_s") ----------------
    @property
    def stiffness_state(self) -> StiffnessState:
        """What the last state is: ``"k_tot"`` (N/m) or ``"log_k_s"`` (ln(k_s/k_series))."""
        return self._stiffness_state

    def ktot_of(self, v: Any) -> Array:
        """k_tot (N/m) the dynamics use for the last-state value(s) ``v``.

        ``"k_tot"``: ``v`` clamped into :attr:`ktot_bounds`; ``"log_k_s"``:
        ``k_series · logistic(v)`` (``v`` clipped into ``log_ks_range``),
        always inside ``(0, k_series)``.
        """
        v = np.asarray(v, dtype=float)
        if self._stiffness_state == "log_k_s":
            lo, hi = self._log_ks_range
            return self._k_series / (1.0 + np.exp(-_clip(v, lo, hi)))
        return self.clamp_ktot(v)

    def ktot_slope(self, v: float) -> float:
        """``dk_tot/dv`` of :meth:`ktot_of` at one value (0 where clamped or clipped)."""
        if self._stiffness_state == "log_k_s":
            lo, hi = self._log_ks_range
            if not lo < v < hi:
                return 0.0
            sig = 1.0 / (1.0 + math.exp(-v))
            return self._k_series * sig * (1.0 - sig)
        return 1.0 if self._kmin < v < self._kmax else 0.0

    def stiffness_state_of_ktot(self, k_tot: float) -> float:
        """The last-state value that represents ``k_tot`` (inverse of :meth:`ktot_of`)."""
        k = float(self.clamp_ktot(k_tot))
        if self._stiffness_state == "log_k_s":
            return self.project_stiffness_state(math.log(k / (self._k_series - k)))
        return k

    def project_stiffness_state(self, v: float) -> float:
        """Project a posterior value into the model's range (k_tot clamp or ``log_ks_range``)."""
        lo, hi = self._log_ks_range if self._stiffness_state == "log_k_s" else (self._kmin, self._kmax)
        return float(min(max(v, lo), hi))  # np.clip's value for a float, NaN included

    def stiffness_moments(self, v: float, var: float) -> tuple[float, float, float, float]:
        """``(k_tot, var k_tot, k_s, var k_s)`` of a last-state mean and variance.

        First-order propagation (MODELS.md A.2). ``"k_tot"``: k_s from P-3
        inverted; ``"log_k_s"``: ``k_s = k_series e^v``, ``var k_s = k_s² var``
        and ``var k_tot = (dk_tot/dv)² var``. Non-finite or negative variances
        are reported as ``k_series²`` (k_tot form) or as a variance of 1 in
        ln k_s (log form): unknown, never NaN.
        """
        if self._stiffness_state == "log_k_s":
            lo, hi = self._log_ks_range
            s = float(min(max(v, lo), hi))  # np.clip's value for a float, NaN included
            var_s = var if (math.isfinite(var) and var >= 0.0) else 1.0
            k_s = self._k_series * math.exp(s)
            slope = self.ktot_slope(s)
            return self._ktot_of_float(s), slope**2 * var_s, k_s, k_s**2 * var_s
        k_var = var if (math.isfinite(var) and var >= 0.0) else self._k_series**2
        clamp_frac = max(self._kmin / self._k_series, 1.0 - self._kmax / self._k_series)
        k_s, k_s_var = soil_stiffness_from_k_tot(v, k_var, self._k_series, clamp_frac)
        return float(v), k_var, k_s, k_s_var

    @property
    def stiffness_state_max_variance(self) -> float:
        """Largest last-state variance a restart carries over."""
        return 25.0 if self._stiffness_state == "log_k_s" else self._k_series**2

    def _mean_ktot(self, x: Any) -> float:
        """Clamped k_tot of the mean last state of ``x`` (``(n,)`` or ``(m, n)``); ``kmin`` if not finite.

        One state is its own mean (x/1 is exact), so the common case skips
        ``np.mean``, which costs more than the rest of the noise models.
        """
        x = np.asarray(x, dtype=float)
        if x.ndim == 1 and x.size:
            k_mean = float(x[-1])
        else:
            k_mean = float(np.mean(x[..., -1])) if x.size else 0.0
        return self._ktot_of_float(k_mean) if math.isfinite(k_mean) else self._kmin

    def _ktot_of_float(self, v: float) -> float:
        """:meth:`ktot_of` of one float: the same value without 0-d array round trips.

        ``min(max(v, lo), hi)`` clamps a float as ``np.clip`` does (a NaN
        ``v`` stays NaN: it is the first argument of both); the logistic keeps
        numpy's ``exp``, which may differ from libm's in the last bit. Called
        three times per filter step, where numpy's scalar overhead was most of
        the cost.
        """
        if self._stiffness_state == "log_k_s":
            lo, hi = self._log_ks_range
            return float(self._k_series / (1.0 + np.exp(-min(max(v, lo), hi))))
        return float(min(max(v, self._kmin), self._kmax))

    def A(self, x: Array) -> Array:  # noqa: N802
        """Continuous state matrix ``A(x)`` (A.1) with the clamped k_tot.

        Args:
            x: state ``(n,)`` or points ``(m, n)``.

        Returns:
            ``(n, n)`` or ``(m, n, n)``.
        """
        x = np.asarray(x, dtype=float)
        k = self.ktot_of(x[..., -1])
        return self._a0 + k[..., None, None] * self._e

    def C(self, x: Array) -> Array:  # noqa: N802
        """Measurement matrix ``C(x)``: the acceleration rows of ``A(x)`` (A.4).

        Returns:
            ``(p, n)`` or ``(m, p, n)``.
        """
        return self.A(x)[..., self._rows, :]

    def continuous_derivative(self, x: Array, u: Any = 0.0) -> Array:
        """``ẋ = A(x) x + B u`` (P-8) for a scalar input ḣ (m/s); ``(n,)`` or ``(m, n)``."""
        x = np.asarray(x, dtype=float)
        return (self.A(x) @ x[..., None])[..., 0] + self._b * float(u)

    def f(self, x: Array, u: Any, dt: float) -> Array:
        """Propagate over one filter step through the sub-steps of ``u`` (P-13, A.10).

        Args:
            x: state ``(n,)`` or points ``(m, n)``.
            u: ḣ (m/s) on ``N`` equal sub-steps spanning ``dt``, ``(N,)``; a
                scalar is one sub-step.
            dt: filter step (s), > 0.

        Returns:
            Propagated state(s), same shape as ``x``. The k_tot component is
            passed through unchanged (random walk); the dynamics use the
            clamped k_tot of each point.
        """
        x = np.asarray(x, dtype=float)
        single = x.ndim == 1
        pts = x if x.ndim == 2 else np.atleast_2d(x)
        us = substep_inputs(u)
        delta = float(dt) / us.size
        phi, gb = _discretise_with_input(self.A(pts), self._b, delta, self._method)
        y = _run_substeps(pts, phi, gb, us)
        return y[0] if single else y

    def h(self, x: Array, u: Any = None) -> Array:
        """Predicted accelerations ``z = C(x) x + D ḣ`` (P-9, A.4) in m/s².

        Args:
            x: state ``(n,)`` or points ``(m, n)``.
            u: the step's input (sub-step ḣ array or :class:`StepInput`);
                its end value (:func:`hdot_at_end`, ḣ at the measurement
                time) feeds the LRV relative-damper term. Ignored otherwise.

        Returns:
            ``(p,)`` or ``(m, p)``.
        """
        x = np.asarray(x, dtype=float)
        k = self.ktot_of(x[..., -1])
        z = x @ self._c0.T + k[..., None] * (x @ self._ce.T)
        if self._feedthrough:
            z = z + self._d * hdot_at_end(u)
        return z

    def measurement_noise_sqrt(self) -> Array:
        """``√R`` ``(p, p)`` (diagonal, P-9)."""
        return np.diag(self._sqrt_r)

    def profile_error_gains(self, x: Array) -> tuple[Array, Array]:
        """Sensitivity of the predicted measurement to errors of the measured road.

        The filter tracks its states relative to the *reconstructed* road:
        the sub-step inputs telescope, so an error ``ε_h`` of the elevation at
        the measurement time leaves the state at ``x + B ε_h`` (first order;
        the ``ẏ1`` part of the LRV relative damper decays with the damping),
        and an error ``ε_ḣ`` of the fed-through ḣ enters ``z`` directly. Hence
        ``δz ≈ C(x) B ε_h + D ε_ḣ``. The estimator adds
        ``[g_h g_ḣ] Σ_ε [g_h g_ḣ]ᵀ`` to ``R``, ``Σ_ε`` the covariance of
        ``(ε_h, ε_ḣ)`` from the profile noise.

        Args:
            x: state ``(n,)`` or points ``(m, n)``; the mean clamped k_tot is used.

        Returns:
            ``(g_h, g_ḣ)``, each ``(p,)``: ``C(x̄) B`` (s⁻², m/s² per m) and
            ``D`` (s⁻¹, m/s² per m/s). Quarter car: ``g_h = [0, k_tot/m_ns]``,
            ``g_ḣ = 0``; LRV: ``g_h = k_tot/m_s − (c/m_s)² `` (relative damper,
            ``k_tot/m_s`` otherwise), ``g_ḣ = c/m_s`` (relative) or 0.
        """
        return self._road_gain(x), self._d.copy()

    def _road_gain(self, x: Array) -> Array:
        """``g_h = C(x̄) B`` of :meth:`profile_error_gains` alone (the estimator's every update)."""
        k_c = self._mean_ktot(x)
        c = self._c0 + k_c * self._ce
        return c @ self._b

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        """Square-root factor ``L`` of ``Q_k`` over one filter step, ``(n, n)`` (A.4).

        Motion states: ``√Δt · Γ_k(Δt) G diag(σ)`` (the printed
        ``Q_k ≈ Δt G_k Q G_kᵀ``, G_k over the whole filter step ``Δt = dt``)
        evaluated at the clamped k_tot of ``x`` (the mean; for a point set
        the mean of the points). k_tot column: ``√(q_ktot_per_step ·
        dt/ktot_step_dt) e_k`` in the ``"per_step"`` form, ``√Δt · Δt · σ_k e_k``
        in the ``"printed"`` one (exact, since Γ_k e_k = Δt e_k).
        """
        k_c = self._mean_ktot(x)
        dt = float(dt)
        cache = self._noise_cache
        if cache is not None and cache[0] == dt and cache[1] == k_c:
            return cache[2].copy()
        a = self._a0 + k_c * self._e
        _, gam = discretise(a, dt, self._method)
        lq = self._noise_factor(gam, dt)
        self._noise_cache = (dt, k_c, lq)
        return lq.copy()

    def _noise_factor(self, gam: Array, dt: float) -> Array:
        """``√Q_k`` of :meth:`process_noise_sqrt` from ``Γ_k(dt)`` at the mean k_tot."""
        lq = math.sqrt(dt) * (gam @ self._g) * self._sigma_q
        lq[:, -1] = 0.0
        lq[-1, -1] = self._stiffness_noise_sqrt(dt)
        return lq

    def _stiffness_noise_sqrt(self, dt: float) -> float:
        """The stiffness random walk's entry of ``√Q_k`` over ``dt`` (its last diagonal entry)."""
        # math.sqrt: IEEE square roots are correctly rounded, numpy's as libm's.
        if self._stiffness_state == "log_k_s":
            return math.sqrt(self._q_log_ks_per_step * dt / self._ktot_step_dt)
        if self._noise_form == "per_step":
            return math.sqrt(self._q_ktot_per_step * dt / self._ktot_step_dt)
        return float(math.sqrt(dt) * dt * self._sigma_q[-1])

    # -- Jacobians (EKF, A.6) -------------------------------------------------
    def transition_jacobian(self, x: Array, u: Any, dt: float) -> Array:
        """``∂f/∂x`` at one state ``(n,)``, shape ``(n, n)``.

        ``"exact"``: the derivative of this model's discrete ``f`` through all
        sub-steps, ``J_{j+1} = Φ J_j + (∂Φ/∂k x_j + ∂Γ/∂k B u_j) ∂k/∂x``,
        including the ``∂(B_k u)/∂k_tot`` term the paper omits (A.10.3). The
        k-derivatives of Φ and Γ come from discretising the block matrix
        ``[[A, E], [0, A]]`` with the same method (its upper-right blocks are
        the directional derivatives, exactly for the truncated series too).

        ``"paper"``: the product over sub-steps of ``A_x(x_j)`` discretised by
        the same series, ``A_x = ∂(A(x)x)/∂x`` (A.6), input term omitted.
        """
        x = np.asarray(x, dtype=float)
        if x.shape != (self.state_dim,):
            raise ValueError(f"x must have shape ({self.state_dim},), got {x.shape}")
        us = substep_inputs(u)
        delta = float(dt) / us.size
        n = self.state_dim
        k_raw = float(x[-1])
        k = float(self.ktot_of(k_raw))
        slope = self.ktot_slope(k_raw)
        a = self._a0 + k * self._e
        jac = np.eye(n)
        xj = x.copy()
        if self._jacobian_form == "paper":
            phi, gam = discretise(a, delta, self._method)
            gb = gam @ self._b
            for uj in us:
                a_x = a.copy()
                a_x[:, -1] += (self._e @ xj) * slope
                phi_x, _ = discretise(a_x, delta, self._method)
                jac = phi_x @ jac
                xj = phi @ xj + gb * uj
                xj[-1] = k_raw
            return jac
        block = np.zeros((2 * n, 2 * n))
        block[:n, :n] = a
        block[n:, n:] = a
        block[:n, n:] = self._e
        phi_b, gam_b = discretise(block, delta, self._method)
        phi, dphi = phi_b[:n, :n], phi_b[:n, n:]
        gb, dgb = gam_b[:n, :n] @ self._b, gam_b[:n, n:] @ self._b
        for uj in us:
            sens = (dphi @ xj + dgb * uj) * slope
            jac = phi @ jac + np.outer(sens, jac[-1])
            xj = phi @ xj + gb * uj
            xj[-1] = k_raw
        jac[-1] = 0.0
        jac[-1, -1] = 1.0
        return jac

    def measurement_jacobian(self, x: Array, u: Any = None) -> Array:
        """``∂h/∂x`` at one state ``(n,)``, shape ``(p, n)``: rows of ``A_x`` (A.6)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.state_dim,):
            raise ValueError(f"x must have shape ({self.state_dim},), got {x.shape}")
        k_raw = float(x[-1])
        k = float(self.ktot_of(k_raw))
        hx = self._c0 + k * self._ce
        hx[:, -1] += (self._ce @ x) * self.ktot_slope(k_raw)
        return hx


class QuarterCarModel(_BilinearKtotModel):
    """2-DOF quarter car on deformable ground (P-4…P-9, appendix A.1–A.4).

    State ``x = [y1 − y2, ẏ1, y2 − h, ẏ2, k_tot]`` (m, m/s, m, m/s, N/m),
    input ``u = ḣ`` (m/s) per sub-step, measurement ``z = [ÿ1, ÿ2]`` (m/s²,
    gravity removed).

    Args:
        params: vehicle and noise parameters (defaults: Table 2 and P-9).
    """

    def __init__(self, params: QuarterCarParams | None = None) -> None:
        p = params if params is not None else QuarterCarParams()
        self.params = p
        ms, mns, k, c = p.m_s, p.m_ns, p.k, p.c
        # (A.1) with the k_tot entry [4, 3] (1-based) split off into E.
        self._a0 = np.array(
            [
                [0.0, 1.0, 0.0, -1.0, 0.0],
                [-k / ms, -c / ms, 0.0, c / ms, 0.0],
                [0.0, 0.0, 0.0, 1.0, 0.0],
                [k / mns, c / mns, 0.0, -c / mns, 0.0],
                [0.0, 0.0, 0.0, 0.0, 0.0],
            ]
        )
        self._e = np.zeros((5, 5))
        self._e[3, 2] = -1.0 / mns
        self._b = np.array([0.0, 0.0, -1.0, 0.0, 0.0])  # (A.2)
        self._g = np.array(  # (A.3)
            [
                [0.0, 1.0, 0.0, 1.0, 0.0],
                [1.0, 1.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0, 0.0],
                [1.0, 1.0, 1.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 0.0, 1.0],
            ]
        )
        self._rows = np.array([1, 3])  # (A.4): rows 2 and 4 of A(x)
        self._finish_init(p)


class LRVModel(_BilinearKtotModel):
    """1-DOF Lunar Roving Vehicle model (section 5.3 of [QC], MODELS.md A.7).

    State ``x = [y1 − h, ẏ1, k_tot]``, input ``u = ḣ`` per sub-step,
    measurement ``z = [ÿ1]``. ``A``, ``B``, ``G`` are the literal reduction of
    the 2-DOF matrices (rows/columns 1, 2, 5 with the stiffness entry made the
    k_tot state); with ``relative_damper`` the damper acts on ``ẏ1 − ḣ``.

    Args:
        params: vehicle and noise parameters (defaults: Table 5).
    """

    def __init__(self, params: LRVParams | None = None) -> None:
        p = params if params is not None else LRVParams()
        self.params = p
        ms, c = p.m_s, p.c
        self._a0 = np.array(
            [
                [0.0, 1.0, 0.0],
                [0.0, -c / ms, 0.0],
                [0.0, 0.0, 0.0],
            ]
        )
        self._e = np.zeros((3, 3))
        self._e[1, 0] = -1.0 / ms
        self._b = np.array([-1.0, c / ms if p.relative_damper else 0.0, 0.0])
        self._g = np.array(
            [
                [0.0, 1.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ]
        )
        self._rows = np.array([1])
        self._finish_init(p)
