"""Parameters of the soil-stiffness estimation models (Table 2, Table 5 and section 4 of [QC], MODELS.md A.1–A.7).

:class:`QuarterCarParams` (2-DOF quarter car) and :class:`LRVParams` (1-DOF
Lunar Roving Vehicle) configure
:class:`~terrain_estimation.models.quarter_car.QuarterCarModel` and
:class:`~terrain_estimation.models.quarter_car.LRVModel`: masses, springs and
dampers, process and measurement noise, the stiffness state, its clamp and
noise form, the discretisation and the EKF Jacobian. Importable from
:mod:`terrain_estimation.models.quarter_car` too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from terrain_estimation.checks import check_fields

__all__ = ["QuarterCarParams", "LRVParams", "Discretisation", "KtotNoiseForm", "JacobianForm", "StiffnessState"]

Discretisation = Literal["taylor4", "expm"]
KtotNoiseForm = Literal["per_step", "printed"]
JacobianForm = Literal["exact", "paper"]
StiffnessState = Literal["k_tot", "log_k_s"]

#: Default range of the ``"log_k_s"`` state s = ln(k_s/k_series): k_s between
#: k_series/100 and 100·k_series (1.75 kN/m … 17.5 MN/m on the quarter car, every
#: soil of Table 1 with a wide margin). The bound matters: with k_s ≫ k_series,
#: k_tot → k_series and the accelerations stop depending on s, so a mean thrown
#: far beyond it by one large innovation (a soil change) would stay there.
_LOG_KS_RANGE = (-math.log(100.0), math.log(100.0))


def _check_common(params: Any, positive: tuple[str, ...], n: int, p: int) -> None:
    """The checks the 2-DOF and the LRV parameter sets share (``positive``: the names that must be > 0)."""
    check_fields(params, positive)
    check_fields(params, ("c",), rule="non_negative")
    q_diag, r_diag = tuple(params.q_diag), tuple(params.r_diag)
    q_ktot_per_step, ktot_step_dt = params.q_ktot_per_step, params.ktot_step_dt
    ktot_noise_form, discretisation, ekf_jacobian = params.ktot_noise_form, params.discretisation, params.ekf_jacobian
    ktot_min_frac, ktot_max_frac = params.ktot_min_frac, params.ktot_max_frac
    stiffness_state, q_log_ks_per_step = params.stiffness_state, params.q_log_ks_per_step
    log_ks_range = tuple(params.log_ks_range)
    if len(q_diag) != n or any(not np.isfinite(q) or q < 0 for q in q_diag):
        raise ValueError(f"q_diag must hold {n} finite non-negative variances, got {q_diag}")
    if len(r_diag) != p or any(not np.isfinite(r) or r <= 0 for r in r_diag):
        raise ValueError(f"r_diag must hold {p} finite positive variances, got {r_diag}")
    if not (np.isfinite(q_ktot_per_step) and q_ktot_per_step >= 0):
        raise ValueError("q_ktot_per_step must be finite and >= 0")
    if not (np.isfinite(ktot_step_dt) and ktot_step_dt > 0):
        raise ValueError("ktot_step_dt must be finite and > 0")
    if ktot_noise_form not in ("per_step", "printed"):
        raise ValueError(f"ktot_noise_form must be 'per_step'|'printed', got {ktot_noise_form!r}")
    if discretisation not in ("taylor4", "expm"):
        raise ValueError(f"discretisation must be 'taylor4' or 'expm', got {discretisation!r}")
    if ekf_jacobian not in ("exact", "paper"):
        raise ValueError(f"ekf_jacobian must be 'exact' or 'paper', got {ekf_jacobian!r}")
    if not (0.0 < ktot_min_frac < ktot_max_frac < 1.0):
        raise ValueError("need 0 < ktot_min_frac < ktot_max_frac < 1")
    if stiffness_state not in ("k_tot", "log_k_s"):
        raise ValueError(f"stiffness_state must be 'k_tot' or 'log_k_s', got {stiffness_state!r}")
    if not (np.isfinite(q_log_ks_per_step) and q_log_ks_per_step >= 0):
        raise ValueError(f"q_log_ks_per_step must be finite and >= 0, got {q_log_ks_per_step}")
    if len(log_ks_range) != 2 or not (np.all(np.isfinite(log_ks_range)) and log_ks_range[0] < log_ks_range[1]):
        raise ValueError(f"log_ks_range must be two finite, increasing values, got {log_ks_range}")


@dataclass(frozen=True)
class QuarterCarParams:
    """Parameters of the 2-DOF estimation model (Table 2 and section 4 of [QC]).

    Attributes:
        m_s: sprung mass (kg).
        m_ns: unsprung mass (kg).
        k: suspension stiffness (N/m).
        c: suspension damping (N·s/m).
        k_t: tire stiffness (N/m); the series stiffness that bounds k_tot.
        q_diag: continuous process-noise variances σ1²…σ5² of Q (P-9), units
            m², (m/s)², m², (m/s)², (N/m)².
        r_diag: accelerometer noise variances of R, (m/s²)².
        q_ktot_per_step: k_tot random-walk variance added per filter step of
            ``ktot_step_dt`` in the ``"per_step"`` form ((N/m)²); scales
            linearly with the actual step (MODELS.md A.4).
        ktot_step_dt: step length (s) that ``q_ktot_per_step`` refers to.
        ktot_noise_form: ``"per_step"`` (recommended, A.4) or ``"printed"``
            (k_tot entry of ``Q_k = Δt G_k Q G_kᵀ``, i.e. Δt³σ5²: cannot
            re-adapt after a soil change).
        discretisation: ``"taylor4"`` (paper, P-11) or ``"expm"`` (exact).
        ekf_jacobian: ``"exact"`` (derivative of this model's discrete ``f``,
            including ∂(B_k u)/∂k_tot) or ``"paper"`` (A_x discretised with the
            same series, input term omitted, A.6).
        ktot_min_frac: lower clamp of the k_tot used by the dynamics, as a
            fraction of ``k_t``.
        ktot_max_frac: upper clamp, fraction of ``k_t``.
        stiffness_state: what the augmented last state is. ``"k_tot"``: k_tot
            itself (the paper, P-5), clamped into ``(ktot_min_frac,
            ktot_max_frac)·k_series`` where the dynamics use it.
            ``"log_k_s"``: ``s = ln(k_s/k_series)``, so ``k_tot = k_series ·
            logistic(s)`` lies in ``(0, k_series)`` for every sigma point and
            the k_s recovered from it can neither go negative nor explode as
            k_tot → k_series (MODELS.md A.10.4: the k_tot form overshoots to
            the clamp in a few runs in ten). Its random walk is relative:
            ``q_log_ks_per_step``.
        q_log_ks_per_step: variance of the random walk of ``s = ln(k_s/k_series)``
            per ``ktot_step_dt`` (``"log_k_s"`` only). Default 1e-6: a 0.1 %
            relative walk of k_s per 10 ms step, which equals the k_tot walk
            of 1e3 (N/m)² at Graneville loam on the quarter car.
        log_ks_range: ``(s_min, s_max)`` of the ``"log_k_s"`` state: the
            dynamics use s clipped into it and the estimator projects the mean
            into it. Default ``±ln 100``: k_s within a factor 100 of k_series.
            Far above k_series the accelerations barely depend on s, and a mean
            thrown beyond the range by one large innovation would stay there.
    """

    m_s: float = 455.0
    m_ns: float = 45.5
    k: float = 25_000.0
    c: float = 2_000.0
    k_t: float = 175_000.0
    q_diag: tuple[float, ...] = (1e-5, 1e-3, 1e-5, 1e-3, 1e5)
    r_diag: tuple[float, ...] = (0.5, 0.5)
    q_ktot_per_step: float = 1e3
    ktot_step_dt: float = 0.01
    ktot_noise_form: KtotNoiseForm = "per_step"
    discretisation: Discretisation = "taylor4"
    ekf_jacobian: JacobianForm = "exact"
    ktot_min_frac: float = 1e-3
    ktot_max_frac: float = 0.999
    stiffness_state: StiffnessState = "k_tot"
    q_log_ks_per_step: float = 1e-6
    log_ks_range: tuple[float, float] = _LOG_KS_RANGE

    def __post_init__(self) -> None:
        _check_common(self, ("m_s", "m_ns", "k", "k_t"), 5, 2)

    @property
    def k_series(self) -> float:
        """Stiffness in series with the soil (N/m): the tire, ``k_t``."""
        return self.k_t


@dataclass(frozen=True)
class LRVParams:
    """Parameters of the 1-DOF LRV estimation model (Table 5 of [QC], MODELS.md A.7).

    Attributes:
        m_s: lumped sprung + unsprung mass (kg).
        k: combined suspension and tire stiffness (N/m); the series stiffness
            that bounds k_tot (``k_tot = k k_s / (k + k_s)``).
        c: damping (N·s/m).
        relative_damper: False = literal reduction of the 2-DOF matrices
            (damper on the absolute velocity ẏ1); True = physical damper on
            ``ẏ1 − ḣ``, which adds ``+c/m_s`` to ``B[2]`` and the feed-through
            ``+(c/m_s)·ḣ(t)`` to the measurement, ḣ(t) at the measurement
            time (:func:`hdot_at_end`: a :class:`StepInput`'s ``hdot_end``,
            else extrapolated from the sub-step slopes).
        q_diag: variances σ1², σ2², σ5² (m², (m/s)², (N/m)²); "process and
            measurement noise unchanged" from the 2-DOF case.
        r_diag: accelerometer variance ((m/s²)²).
        q_ktot_per_step: k_tot random walk per ``ktot_step_dt`` ((N/m)²).
            Default 7.35 = the quarter car's 1e3 scaled by ``(k/k_t)² =
            (15/175)²``, i.e. the same *relative* random walk (≈ 0.03 % of
            k_tot per step). The quarter car's absolute 1e3 is 14× larger
            relative to the LRV's k_tot ≈ 9.8 kN/m: measured on ISO G at
            2 m/s (12 seeds), it holds the filter at std(k_s) ≈ 9 % and an rms
            k_s error of 5.7 % at 13 s, against 3.1 % (the Cramér–Rao level of
            the accelerometer data) with 7.35. The price is slower
            re-adaptation to a new soil where the change detector does not
            fire (a 2× change of k_s on the LRV: rms error 22 % ten seconds
            later vs 7 % with 1e3, 3.7 % with 100).
        ktot_step_dt, ktot_noise_form, discretisation, ekf_jacobian,
        ktot_min_frac, ktot_max_frac, stiffness_state, q_log_ks_per_step,
        log_ks_range: as in :class:`QuarterCarParams` (fractions of ``k``).
    """

    m_s: float = 75.0
    k: float = 15_000.0
    c: float = 1_500.0
    relative_damper: bool = False
    q_diag: tuple[float, ...] = (1e-5, 1e-3, 1e5)
    r_diag: tuple[float, ...] = (0.5,)
    q_ktot_per_step: float = 7.35
    ktot_step_dt: float = 0.01
    ktot_noise_form: KtotNoiseForm = "per_step"
    discretisation: Discretisation = "taylor4"
    ekf_jacobian: JacobianForm = "exact"
    ktot_min_frac: float = 1e-3
    ktot_max_frac: float = 0.999
    stiffness_state: StiffnessState = "k_tot"
    q_log_ks_per_step: float = 1e-6
    log_ks_range: tuple[float, float] = _LOG_KS_RANGE

    def __post_init__(self) -> None:
        _check_common(self, ("m_s", "k"), 3, 1)

    @property
    def k_series(self) -> float:
        """Stiffness in series with the soil (N/m): the combined spring ``k``."""
        return self.k
