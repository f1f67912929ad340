"""Profile-free soil-stiffness models: the road as ISO 8608 shaped noise (MODELS.md A.8, issue 21 item 5).

The profile-fed models of :mod:`terrain_estimation.models.quarter_car` need the
elevation under the tire at 1 kHz (MODELS.md A.10). Few vehicles carry such a
profilometer. Here the road is not measured: it is a random input whose
spectrum is known from its ISO 8608 class, and the state is augmented with a
shaping filter of that spectrum, so that the filter sees only the
accelerometers.

**The road's spectrum in time.** ISO 8608 gives the one-sided displacement PSD
``G_d(n) = G_d(n0) (n/n0)^(−2)`` (n0 = 0.1 cycles/m, waviness w = 2). At a speed
``v`` the slope spectrum is flat: the road rate ḣ = v dh/ds is white with the
one-sided PSD ``G_ḣ = (2π n0)² G_d(n0) v`` ((m/s)²/Hz), i.e. the two-sided
intensity ``q_ḣ = G_ḣ/2`` (MODELS.md A.8, "shaped white noise"). Two first-order
filters give it the band a real road (and the simulator's road, 0.05–10
cycles/m) has::

    ṙ = ω_hi (β w − r)            (ḣ low-passed at ω_hi; omitted when band_max = 0: r ≡ β w)
    ḣ = r − α h                   (h high-passed at α = 2π band_min v)

with ``β² = q_ḣ`` for a white noise w of unit two-sided intensity. The low cut keeps h
bounded (its variance is finite); the high cut stands for the band edge
``band_max``: a first-order corner at ``ω_hi = 4 band_max v`` (i.e. ``f_c = 2
f_max/π``) carries the same slope variance as the flat spectrum cut at
``f_max = band_max·v`` (``G_ḣ f_c π/2 = G_ḣ f_max``).

**Quarter car (2-DOF).** State ``x = [y1 − y2, ẏ1, y2 − h, ẏ2, h, r, s]`` (``r``
only with the high cut), ``s`` the stiffness state (k_tot or ln(k_s/k_t), as
:class:`~terrain_estimation.models.quarter_car.QuarterCarParams` says),
measurement ``z = [ÿ1, ÿ2]`` exactly as P-9/A.4 (h and r do not enter z). The
soil is identified from the accelerations alone through the tire force
``m_s ÿ1 + m_ns ÿ2 = −k_tot (y2 − h)``: with the wheel displacement known from
its acceleration at the wheel-hop frequencies, a wrong k_tot implies a road
whose slope spectrum is not the flat ISO one. This is an output-only
identification of the wheel-hop mode; its information comes from the road's
spectrum being known in *shape* (w = 2), and only weakly from its level
G_d(n0) (the class spans a factor 4).

**LRV (1-DOF).** State ``x = [y1 − h, ẏ1, h, r, s]``, ``z = [ÿ1]``. With one
accelerometer, k_tot enters the body acceleration spectrum only through the
body mode (1.8 Hz, damping ratio 0.87 on regolith), whose level is set by the
unknown road intensity: see :mod:`terrain_estimation.estimators.soil_profile_free`
for what that means and why the mode refuses it by default.

**Discretisation.** ``Φ = e^{A(k)Δ}`` per cubature point by the paper's
fourth-order series on ``Δ/2^m`` followed by ``m`` squarings (truncation
≈ 2e-8 at ``m = 3``, 10 ms, against the −0.09 % k_tot bias of the plain series
over 10 ms, MODELS.md A.10.2). The process noise of the road is exact (Van
Loan's matrix exponential at the mean k_tot); the motion states keep the
profile-fed model's printed ``Q_k`` (A.4) and the stiffness state its random
walk, so that the only difference between the two modes is the road.

**Speed.** ``u`` of :meth:`QuarterCarRoadModel.f` and :meth:`process_noise_sqrt`
is the travel speed v (m/s, ≥ 0); it sets α, ω_hi and q_ḣ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from terrain_estimation.filters.base import Array
from terrain_estimation.filters.sigma_points import robust_sqrt
from terrain_estimation.models.quarter_car import (
    LRVModel,
    LRVParams,
    QuarterCarModel,
    QuarterCarParams,
    discretise,
)

__all__ = [
    "ISO8608_N0",
    "ISO8608_GD_N0",
    "RoadInputParams",
    "QuarterCarRoadModel",
    "road_rate_intensity",
]

ISO8608_N0 = 0.1
"""ISO 8608 reference spatial frequency n0 (cycles/m)."""

#: Class geometric means of G_d(n0) (m³), MODELS.md A.8 (the simulator's values).
ISO8608_GD_N0: dict[str, float] = {cls: 16e-6 * 4**i for i, cls in enumerate("ABCDEFGH")}

#: Squarings after the Taylor series on Δ/2^m (see the module docstring).
_SQUARINGS = 3


def road_rate_intensity(gd_n0: float, speed: float) -> float:
    """Two-sided intensity ``q_ḣ = (2π n0)² G_d(n0) v / 2`` ((m/s)²·s) of the white road rate at ``speed``.

    Args:
        gd_n0: ISO 8608 G_d(n0) (m³).
        speed: travel speed v (m/s).
    """
    return 0.5 * (2.0 * math.pi * ISO8608_N0) ** 2 * gd_n0 * speed


@dataclass(frozen=True)
class RoadInputParams:
    """The stochastic road of the profile-free mode.

    Attributes:
        iso_class: ISO 8608 class A–H whose geometric-mean G_d(n0) is assumed
            (MODELS.md A.8: A 16e-6 … H 262144e-6 m³).
        gd_n0: G_d(n0) (m³) overriding the class mean; 0 = the class mean.
            The class spans a factor 4 (mean/2 … 2·mean).
        band_min: low cut of the road (cycles/m, > 0): keeps h bounded.
        band_max: high band edge of the road (cycles/m); 0 = no high cut (ḣ
            white to infinity; one state fewer).
        speed: travel speed (m/s); 0 = measured (the estimator's speed input).
        band_order: order of the high cut: 1 (first-order low-pass of ḣ) or
            2 (Butterworth, default: closer to a band edge; measured on the
            simulator's road, first order biased k_tot by +11…13 %,
            Butterworth by +1.5…3 % on ISO D).
        memory_s: time constant (s) of the exponential forgetting of the
            evidence on k_s (the estimator's counterpart of the random walk).
        grid_step: spacing of the grid of ``ln k_s`` the estimator's bank of
            filters runs on (over ``log_ks_range`` of the vehicle model).
        change_window_s: memory (s) of the recent evidence the soil-change
            test compares with the long posterior.
        change_llr: log-likelihood ratio of the recent evidence above which
            a soil change is declared (the old evidence is dropped).
        allow_lrv: run the 1-DOF LRV in this mode although its k_tot is
            identified only through the assumed road level (see
            :mod:`terrain_estimation.estimators.soil_profile_free`).
    """

    iso_class: str = "D"
    gd_n0: float = 0.0
    band_min: float = 0.05
    band_max: float = 10.0
    speed: float = 0.0
    band_order: int = 2
    memory_s: float = 5.0
    grid_step: float = 0.05
    change_window_s: float = 1.0
    change_llr: float = 5.0
    allow_lrv: bool = False

    def __post_init__(self) -> None:
        if self.iso_class not in ISO8608_GD_N0:
            raise ValueError(f"road iso_class must be one of A-H, got {self.iso_class!r}")
        if not (math.isfinite(self.gd_n0) and self.gd_n0 >= 0.0):
            raise ValueError(f"road gd_n0 must be finite and >= 0 m^3 (0: class mean), got {self.gd_n0}")
        if not (math.isfinite(self.band_min) and self.band_min > 0.0):
            raise ValueError(f"road band_min must be finite and > 0 cycles/m, got {self.band_min}")
        if not (math.isfinite(self.band_max) and (self.band_max == 0.0 or self.band_max > self.band_min)):
            raise ValueError(
                f"road band_max must be 0 (no high cut) or above band_min = {self.band_min} cycles/m, "
                f"got {self.band_max}"
            )
        if self.band_order not in (1, 2):
            raise ValueError(f"road band_order must be 1 or 2, got {self.band_order}")
        if not (math.isfinite(self.speed) and self.speed >= 0.0):
            raise ValueError(f"road speed must be finite and >= 0 m/s (0: measured), got {self.speed}")
        if not (math.isfinite(self.memory_s) and self.memory_s > 0.0):
            raise ValueError(f"road memory_s must be finite and > 0 s, got {self.memory_s}")
        if not (math.isfinite(self.grid_step) and 1e-3 <= self.grid_step <= 0.5):
            raise ValueError(f"road grid_step must be in [0.001, 0.5] (ln k_s), got {self.grid_step}")
        if not (math.isfinite(self.change_window_s) and 0.0 < self.change_window_s):
            raise ValueError(f"road change_window_s must be finite and > 0 s, got {self.change_window_s}")
        if not (self.change_llr > 0.0):
            raise ValueError(f"road change_llr must be > 0, got {self.change_llr}")

    @property
    def level(self) -> float:
        """The G_d(n0) used (m³)."""
        return self.gd_n0 if self.gd_n0 > 0.0 else ISO8608_GD_N0[self.iso_class]


class QuarterCarRoadModel:
    """Quarter car or LRV with the road as an ISO 8608 shaping filter (module docstring).

    Implements :class:`~terrain_estimation.filters.base.StateSpaceModel`
    (``u`` = the travel speed in m/s). The stiffness state and its handling
    (clamp, ``log_k_s`` logistic, moments of k_s) are those of the
    profile-fed model it wraps (:attr:`base`), so both modes report alike.

    Args:
        params: vehicle and noise parameters (:class:`QuarterCarParams` or
            :class:`LRVParams`).
        road: the road model.
    """

    def __init__(self, params: QuarterCarParams | LRVParams, road: RoadInputParams) -> None:
        self.road = road
        self.params = params
        self.base: QuarterCarModel | LRVModel
        if isinstance(params, QuarterCarParams):
            self.base = QuarterCarModel(params)
            m_wheel = params.m_ns
            self._n_motion = 4
            self._tire_row = 3  # ÿ2 row; the tire deflection state y2 − h is index 2
            self._deflection = 2
        else:
            self.base = LRVModel(params)
            m_wheel = params.m_s
            self._n_motion = 2
            self._tire_row = 1
            self._deflection = 0
        base = self.base
        self._high_cut = road.band_max > 0.0
        self._order = road.band_order if self._high_cut else 0
        nm = self._n_motion
        self._ih = nm  # index of h
        self._ir = nm + 1 if self._high_cut else -1  # index of r (= ḣ + α h)
        n = nm + 1 + self._order + 1
        self._n = n
        # Continuous matrices at v = 0, k_tot = 0: the motion block of the base
        # model (its input column B becomes the coupling to the road states).
        a0 = np.zeros((n, n))
        a0[:nm, :nm] = base._a0[:nm, :nm]
        b = base._b[:nm]  # d(motion)/dt += b · ḣ
        self._b_motion = b.copy()
        e = np.zeros((n, n))
        e[self._tire_row, self._deflection] = -1.0 / m_wheel
        self._a0 = a0
        self._e = e
        # Rows of z: the acceleration rows of the base model, padded with the road states.
        rows = base._rows
        self._rows = rows
        self._d = base._b[rows]  # feed-through of ḣ (LRV relative damper)
        self._feedthrough = bool(np.any(self._d))
        if self._feedthrough and not self._high_cut:
            raise ValueError(
                "road band_max must be > 0 for the LRV with a ground-referenced damper: ḣ feeds its "
                "accelerometer directly and must have a finite variance"
            )
        self._sqrt_r = np.sqrt(np.asarray(params.r_diag, dtype=float))
        self._sigma_q = np.sqrt(np.asarray(params.q_diag, dtype=float))[:nm]
        self._g_motion = base._g[:nm, :nm]
        self._cache: tuple[float, float, float, Array] | None = None

    # -- protocol ---------------------------------------------------------------
    @property
    def state_dim(self) -> int:
        """Number of states (motion, road, stiffness)."""
        return self._n

    @property
    def measurement_dim(self) -> int:
        """Number of accelerometers (2 quarter car, 1 LRV)."""
        return int(self._rows.size)

    @property
    def road_state_names(self) -> tuple[str, ...]:
        """Names of the road states, in state order."""
        return ("h", "r", "r_rate")[: 1 + self._order]

    # The stiffness state, as the profile-fed model handles it.
    @property
    def k_series(self) -> float:
        """Stiffness in series with the soil (N/m)."""
        return self.base.k_series

    @property
    def ktot_bounds(self) -> tuple[float, float]:
        """Clamp range of the k_tot used by the dynamics (N/m)."""
        return self.base.ktot_bounds

    @property
    def stiffness_state(self) -> str:
        """``"k_tot"`` or ``"log_k_s"``."""
        return self.base.stiffness_state

    @property
    def stiffness_state_max_variance(self) -> float:
        """Largest last-state variance a restart carries over."""
        return self.base.stiffness_state_max_variance

    def ktot_of(self, v: Any) -> Array:
        """k_tot (N/m) the dynamics use for last-state values ``v``."""
        return self.base.ktot_of(v)

    def stiffness_state_of_ktot(self, k_tot: float) -> float:
        """The last-state value representing ``k_tot``."""
        return self.base.stiffness_state_of_ktot(k_tot)

    def project_stiffness_state(self, v: float) -> float:
        """Project a posterior stiffness value into the model's range."""
        return self.base.project_stiffness_state(v)

    def stiffness_moments(self, v: float, var: float) -> tuple[float, float, float, float]:
        """``(k_tot, var k_tot, k_s, var k_s)`` of a last-state mean and variance (first order)."""
        return self.base.stiffness_moments(v, var)

    # -- dynamics -------------------------------------------------------------
    def road_rates(self, speed: float) -> tuple[float, float, float]:
        """``(α, ω_hi, q_ḣ)`` at ``speed``: low-cut rate (1/s), high-cut corner (rad/s, 0: none), intensity."""
        v = max(float(speed), 0.0)
        alpha = 2.0 * math.pi * self.road.band_min * v
        # Corner of equal slope variance: f_c = 2 f_max/π (first order), 2√2 f_max/π (Butterworth).
        corner = (2.0 if self._order == 1 else 2.0 * math.sqrt(2.0)) / math.pi
        omega = 2.0 * math.pi * corner * self.road.band_max * v if self._high_cut else 0.0
        return alpha, omega, road_rate_intensity(self.road.level, v)

    def A(self, x: Array, speed: float) -> Array:  # noqa: N802 - the symbol of the paper
        """Continuous state matrix at ``x`` (clamped k_tot of its last state) and ``speed``; ``(…, n, n)``."""
        x = np.asarray(x, dtype=float)
        k = self.base.ktot_of(x[..., -1])
        return self._a_of(speed) + k[..., None, None] * self._e

    def _a_of(self, speed: float) -> Array:
        """``A`` at k_tot = 0: motion block, road coupling and the shaping filter."""
        alpha, omega, _ = self.road_rates(speed)
        a = self._a0.copy()
        nm, ih = self._n_motion, self._ih
        # ḣ = r − α h (high cut) or ḣ = −α h + noise; the motion states see ḣ through b.
        a[:nm, ih] += -alpha * self._b_motion
        a[ih, ih] = -alpha
        if self._high_cut:
            ir = self._ir
            a[:nm, ir] += self._b_motion
            a[ih, ir] = 1.0
            if self._order == 1:
                a[ir, ir] = -omega
            else:  # Butterworth: r̈ + √2 ω ṙ + ω² r = ω² β w
                a[ir, ir + 1] = 1.0
                a[ir + 1, ir] = -(omega**2)
                a[ir + 1, ir + 1] = -math.sqrt(2.0) * omega
        return a

    def _noise_input(self, speed: float) -> Array:
        """Column through which a white noise of unit (two-sided) intensity drives the state (``(n,)``)."""
        _, omega, q = self.road_rates(speed)
        beta = math.sqrt(q)
        g = np.zeros(self._n)
        if self._high_cut:
            if self._order == 1:
                g[self._ir] = omega * beta
            else:
                g[self._ir + 1] = omega**2 * beta
        else:
            g[: self._n_motion] = self._b_motion * beta
            g[self._ih] = beta
        return g

    def transition(self, x: Array, speed: float, dt: float) -> Array:
        """``Φ = e^{A(x) dt}`` per point (series on dt/8, three squarings); ``(…, n, n)``."""
        a = self.A(x, speed)
        phi, _ = discretise(a, float(dt) / 2**_SQUARINGS, "taylor4")
        for _ in range(_SQUARINGS):
            phi = phi @ phi
        return phi

    def f(self, x: Array, u: Any, dt: float) -> Array:
        """Propagate state(s) over ``dt`` at the speed ``u`` (m/s); the stiffness state is a random walk."""
        x = np.asarray(x, dtype=float)
        phi = self.transition(x, float(u), dt)
        y = (phi @ x[..., None])[..., 0]
        y[..., -1] = x[..., -1]
        return y

    def h(self, x: Array, u: Any = None) -> Array:
        """Predicted accelerations (m/s²): the acceleration rows of ``A(x) x``.

        With the LRV's relative damper the measurement also holds ``(c/m) ḣ``
        with ``ḣ = r − α h`` — the road rate is a state here (the high cut is
        then required: a white ḣ fed through would be white measurement noise
        of infinite variance).
        """
        x = np.asarray(x, dtype=float)
        speed = float(u) if u is not None else 0.0
        a = self.A(x, speed)
        return (a[..., self._rows, :] @ x[..., None])[..., 0]

    def measurement_noise_sqrt(self) -> Array:
        """``√R`` (diagonal)."""
        return np.diag(self._sqrt_r)

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        """Factor ``(n, 2n)`` of ``Q_k``: motion (printed form, A.4), road (exact, Van Loan), stiffness walk.

        Evaluated at the mean clamped k_tot of ``x`` and the speed ``u``.
        """
        x = np.asarray(x, dtype=float)
        s = float(np.mean(x[..., -1])) if x.ndim > 1 else float(x[-1])
        k = float(self.base.ktot_of(s)) if math.isfinite(s) else self.base.ktot_bounds[0]
        speed, dt = float(u), float(dt)
        cache = self._cache
        if cache is not None and cache[0] == k and cache[1] == speed and cache[2] == dt:
            return cache[3].copy()
        n, nm = self._n, self._n_motion
        a = self._a_of(speed) + k * self._e
        # Road: Q = ∫0^dt e^{Aτ} g gᵀ e^{Aᵀτ} dτ (Van Loan 1978).
        g = self._noise_input(speed)
        g_norm = float(np.linalg.norm(g))
        big = np.zeros((2 * n, 2 * n))
        big[:n, :n] = -a * dt
        if g_norm > 0.0:
            # Q is linear in g gᵀ: a unit g keeps the exponential's norm (and its squarings) small.
            big[:n, n:] = np.outer(g, g) * (dt / g_norm**2)
        big[n:, n:] = a.T * dt
        ex = scipy.linalg.expm(big)
        phi = ex[n:, n:].T
        q_road = (phi @ ex[:n, n:]) * g_norm**2
        q_road = 0.5 * (q_road + q_road.T)
        l_road = robust_sqrt(q_road)
        # Motion states: the profile-fed model's √Δt Γ_k G diag(σ) over the whole step.
        _, gam = discretise(a, dt, "taylor4")
        l_motion = np.zeros((n, n))
        l_motion[:, :nm] = math.sqrt(dt) * (gam[:, :nm] @ self._g_motion) * self._sigma_q
        l_stiff = np.zeros((n, 1))
        l_stiff[-1, 0] = self.base._stiffness_noise_sqrt(dt)
        lq = np.concatenate([l_motion[:, :nm], l_road, l_stiff], axis=1)
        self._cache = (k, speed, dt, lq)
        return lq.copy()

    def stationary_covariance(self, k_tot: float, speed: float, dt: float) -> Array:
        """Stationary covariance of the motion and road states at ``k_tot`` (stiffness entry 0).

        The discrete Lyapunov solution of ``P = Φ P Φᵀ + Q`` on the dynamic
        block: the prior of a start at an unknown instant of a ride.
        """
        s = self.base.stiffness_state_of_ktot(k_tot)
        x = np.zeros(self._n)
        x[-1] = s
        phi = self.transition(x, speed, dt)[:-1, :-1]
        lq = self.process_noise_sqrt(x, speed, dt)[:-1]
        q = lq @ lq.T
        p = scipy.linalg.solve_discrete_lyapunov(phi, q)
        out = np.zeros((self._n, self._n))
        out[:-1, :-1] = 0.5 * (p + p.T)
        return out
