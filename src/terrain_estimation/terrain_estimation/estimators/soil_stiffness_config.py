"""Configuration and outputs of the soil-stiffness estimator (:mod:`.soil_stiffness`).

:class:`SoilStiffnessEstimatorConfig` (one frozen object: vehicle, filter,
rates, the soil-change detector, the profile reconstruction, the waiting
rules, divergence recovery), :class:`SoilStiffnessEstimate` (one filter
step's result) and :class:`EstimatorCounters` (health counters), and the
filter registry :func:`make_filter`. Importable from
:mod:`terrain_estimation.estimators.soil_stiffness` too.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field
from typing import Any, Literal

from terrain_estimation.checks import check_fields
from terrain_estimation.filters.faults import DivergenceConfig
from terrain_estimation.models.quarter_car_params import LRVParams, QuarterCarParams
from terrain_estimation.models.quarter_car_road import RoadInputParams
from terrain_estimation.models.soil import SOIL_TABLE, SoilClass, classify_soil

__all__ = [
    "FILTER_CLASSES",
    "P0_LOG_KS",
    "EstimatorCounters",
    "SoilStiffnessEstimate",
    "SoilStiffnessEstimatorConfig",
    "make_filter",
    "soil_estimate",
]

#: Filter name → (module, class) of terrain_estimation.filters; imported lazily
#: so that the estimator module loads even where a filter is not installed.
FILTER_CLASSES: dict[str, tuple[str, str]] = {
    "sckf": ("terrain_estimation.filters.sckf", "SquareRootCubatureKalmanFilter"),
    "ckf": ("terrain_estimation.filters.ckf", "CubatureKalmanFilter"),
    "ukf": ("terrain_estimation.filters.ukf", "UnscentedKalmanFilter"),
    "ekf": ("terrain_estimation.filters.ekf", "ExtendedKalmanFilter"),
}

#: P0 used when ``p0_diag`` is None [recon, MODELS.md A.5]: motion states
#: loosely known about rest, k_tot std ≈ 0.29 of the series stiffness.
_P0_QUARTER_CAR = (1e-4, 1e-2, 1e-4, 1e-2, 50e3**2)
_P0_LRV = (1e-4, 1e-2, 4.3e3**2)
#: Last entry of P0 for the ``"log_k_s"`` state (ln units²): a std of 1.5 puts
#: the 2σ prior range at k_series·e^±3, 0.05…20 times k_series, which covers
#: every soil of Table 1 from the start guess k_s = k_series.
P0_LOG_KS = 1.5**2


def make_filter(name: str) -> Any:
    """Instantiate the filter ``name`` ("sckf" | "ckf" | "ukf" | "ekf") with its defaults.

    Raises:
        ValueError: unknown name.
        ImportError: the filter module is not available.
    """
    try:
        module_name, class_name = FILTER_CLASSES[name]
    except KeyError:
        known = sorted(FILTER_CLASSES)
        raise ValueError(f"unknown filter {name!r}; expected one of {known}") from None
    module = importlib.import_module(module_name)
    return getattr(module, class_name)()


@dataclass(frozen=True)
class SoilStiffnessEstimatorConfig:
    """Configuration of :class:`SoilStiffnessEstimator` (one frozen object).

    Attributes:
        vehicle: ``"quarter_car"`` (2-DOF, body + wheel accelerometers) or
            ``"lrv"`` (1-DOF, body accelerometer only).
        quarter_car: 2-DOF model parameters (used when vehicle is quarter_car).
        lrv: 1-DOF model parameters (used when vehicle is lrv).
        filter: ``"sckf"`` | ``"ckf"`` | ``"ukf"`` | ``"ekf"``.
        filter_rate_hz: nominal filter rate (Hz); accelerometer samples closer
            than half a period to the previous step are skipped (decimation).
        substep_rate_hz: rate of the sub-step grid the road is resampled on
            (Hz); ``N = ceil(dt · substep_rate_hz)`` sub-steps per step.
        k_tot0: initial k_tot (N/m); None → ``k_series / 2`` (the project's
            reading of "half the tire stiffness", MODELS.md A.5).
        p0_diag: initial covariance diagonal (SI², state order); None → 2-DOF
            ``(1e-4, 1e-2, 1e-4, 1e-2, (50 kN/m)²)``, LRV
            ``(1e-4, 1e-2, (4.3 kN/m)²)``; with the ``"log_k_s"`` stiffness
            state the last default entry is ``1.5²`` (ln units).
        gravity: subtracted from the specific forces (m/s²).
        convergence_rel_std: ``converged`` when ``√var(k_s)/k_s`` is below it.
        gate_threshold: NIS gate (χ²_p); None disables. A gated update leaves
            the prior and reports ``accepted = False``.
        soil_table: known soils for the classifier.
        class_log_std: within-class spread of ln k_s (see
            :func:`~terrain_estimation.models.soil.classify_soil`).
        unknown_weight: prior weight of "none of the known soils".
        change_drift: CUSUM allowance ν (σ units) of the soil-change detector
            (:mod:`~terrain_estimation.estimators.soil_change`), which runs on
            the whitened stiffness correction of every accepted update from
            the first one on. ν is about half the smallest shift of that
            correction worth detecting.
        change_threshold: CUSUM alarm level h (σ units). Larger: fewer false
            alarms, a longer delay (≈ h/(μ − ν) updates for a shift μ).
        change_clip: standardised corrections are clipped to ±clip (σ, >
            drift) before the CUSUM, so one outlier adds at most
            ``clip − drift``: with clip ≤ h no single update raises an alarm
            (defaults: two one-signed updates at least).
        change_reopen_scale: on an alarm the stiffness variance grows by
            ``σ_r²``, ``σ_r = scale · |d|`` with ``d`` the jump the
            innovations of the alarm's excursion imply, bounded below by the
            floor of the stiffness state (``change_ktot_std_frac`` /
            ``change_log_ks_std``) and above by its initial std (P0); the
            motion states' variances grow by their P0 at the same time (they
            were estimated with the old stiffness since the change). 0 with a
            zero floor disables the re-open (the paper's filter, for
            reproduction; the alarm is still reported).
        change_jump_gain: on an alarm the stiffness mean moves by
            ``gain · d``, ``d`` bounded by the initial std of the stiffness
            state (in [0, 1]; 1 = the GLR correction of Willsky and
            Jones: the filter restarts at the implied new soil, with the
            re-opened variance around it; 0 = re-open in place).
        change_ktot_std_frac: floor of the re-open for the ``"k_tot"`` state,
            as a fraction of k_series (std ``frac · k_series``).
        change_log_ks_std: floor of the re-open for the ``"log_k_s"`` state
            (std of ``ln k_s``).
        profile_smoothing_s: window w (s) of the local quadratic fit of the
            profile (see module docstring); 0 = plain linear interpolation.
            Use ≈ 0.01–0.02 s for σ_h ≈ 0.5–1 mm.
        profile_noise_std: standard deviation σ_h of the white noise on the
            profile elevations (m, ≥ 0; default 1e-4, the contract's
            simulated sensor). The measurement noise of every update is
            inflated by what this noise does to the predicted accelerations
            (module docstring, "Profile noise and the measurement"); 0 = a
            noise-free profile (R unchanged). Set it to the profile sensor's
            noise: too small a value only raises the NIS.
        hdot_window_m: length of road (m, ≥ 0; default 0.06) covered by the
            window of the local polynomial fit, centred on the measurement
            time, that gives ḣ(t) for a model with feed-through (LRV relative
            damper). The time window is ``hdot_window_m / v`` (v from the
            profile's distance channel), at most 0.1 s, and a step waits for
            the profile to cover half of it past ``t``. 0 = extrapolate the
            last two sub-step slopes (the noisy former behaviour). Ignored
            without feed-through. Longer windows lower the noise and bias ḣ
            (keep it well below a wavelength of the road's finest content:
            0.1 m at 10 cycles/m).
        profile_max_gap_s: a larger gap between profile samples inside a step
            makes the step predict-only (s).
        max_wait_s: how long a step waits for the profile, against the newest
            accelerometer stamp (s). A live executor may serve the IMU ahead
            of a 1 kHz profile backlog; the wait must cover that lag.
        max_extrapolation_s: how far past the last profile sample a timed-out
            step may extrapolate the elevation (s).
        max_step_s: a longer step restarts the motion states (s).
        max_pending: bound of the queue of waiting accelerometer samples (the
            oldest is dropped beyond it); must exceed ``max_wait_s`` times the
            accelerometer rate (raw, before decimation).
        divergence: divergence detection and recovery
            (:class:`~terrain_estimation.filters.faults.DivergenceConfig`):
            the windowed NIS against its χ² band, covariance blow-up, gate
            lock-out, non-finite or broken state; on a divergence the filter
            re-initialises from the last good estimate
            (``counters.divergences``, :attr:`SoilStiffnessEstimator.fault`
            until it is consistent again). None (default) keeps only the
            non-finite recovery of the module docstring.
        road_input: ``"profile"`` (default: the measured profile drives the
            model, this class) or ``"stochastic"`` (no profile: the road is
            ISO 8608 shaped noise, :mod:`.soil_profile_free`; build with
            :func:`~terrain_estimation.estimators.soil_select.make_estimator`).
        road: the stochastic road (``road_input = "stochastic"`` only).
    """

    vehicle: Literal["quarter_car", "lrv"] = "quarter_car"
    quarter_car: QuarterCarParams = field(default_factory=QuarterCarParams)
    lrv: LRVParams = field(default_factory=LRVParams)
    filter: Literal["sckf", "ckf", "ukf", "ekf"] = "sckf"
    filter_rate_hz: float = 100.0
    substep_rate_hz: float = 1000.0
    k_tot0: float | None = None
    p0_diag: tuple[float, ...] | None = None
    gravity: float = 9.80665
    convergence_rel_std: float = 0.05
    gate_threshold: float | None = None
    soil_table: tuple[SoilClass, ...] = SOIL_TABLE
    class_log_std: float = 0.1
    unknown_weight: float = 0.05
    change_drift: float = 0.5
    change_threshold: float = 20.0
    change_reopen_scale: float = 0.5
    change_clip: float = 20.0
    change_jump_gain: float = 1.0
    change_ktot_std_frac: float = 0.2
    change_log_ks_std: float = 0.3
    profile_smoothing_s: float = 0.0
    profile_noise_std: float = 1e-4
    hdot_window_m: float = 0.06
    profile_max_gap_s: float = 0.02
    max_wait_s: float = 0.25
    max_extrapolation_s: float = 0.005
    max_step_s: float = 0.5
    max_pending: int = 1000
    divergence: DivergenceConfig | None = None
    road_input: Literal["profile", "stochastic"] = "profile"
    road: RoadInputParams = field(default_factory=RoadInputParams)

    def __post_init__(self) -> None:
        if self.road_input not in ("profile", "stochastic"):
            raise ValueError(f"road_input must be 'profile' or 'stochastic', got {self.road_input!r}")
        if self.vehicle not in ("quarter_car", "lrv"):
            raise ValueError(f"vehicle must be 'quarter_car' or 'lrv', got {self.vehicle!r}")
        if self.filter not in FILTER_CLASSES:
            raise ValueError(f"filter must be one of {sorted(FILTER_CLASSES)}, got {self.filter!r}")
        positive = (
            "filter_rate_hz",
            "substep_rate_hz",
            "gravity",
            "convergence_rel_std",
            "class_log_std",
            "change_threshold",
            "profile_max_gap_s",
            "max_step_s",
        )
        check_fields(self, positive)
        non_negative = (
            "change_drift",
            "profile_smoothing_s",
            "profile_noise_std",
            "hdot_window_m",
            "max_wait_s",
            "max_extrapolation_s",
            "change_ktot_std_frac",
            "change_log_ks_std",
            "change_reopen_scale",
        )
        check_fields(self, non_negative, rule="non_negative")
        if not (self.change_drift < self.change_clip and math.isfinite(self.change_clip)):
            raise ValueError(f"change_clip must be finite and > change_drift, got {self.change_clip}")
        if not (0.0 <= self.change_jump_gain <= 1.0):
            raise ValueError(f"change_jump_gain must be in [0, 1], got {self.change_jump_gain}")
        if not (0.0 <= self.unknown_weight < 1.0):
            raise ValueError("unknown_weight must be in [0, 1)")
        if self.max_pending < 1:
            raise ValueError("max_pending must be >= 1")
        if not self.soil_table:
            raise ValueError("soil_table must not be empty")
        k_series = self.k_series
        if self.k_tot0 is not None and not (0.0 < self.k_tot0 < k_series):
            raise ValueError(f"k_tot0 must be in (0, {k_series}), got {self.k_tot0}")
        if self.p0_diag is not None:
            n = 5 if self.vehicle == "quarter_car" else 3
            bad = [p for p in self.p0_diag if not (math.isfinite(p) and p > 0)]
            if len(self.p0_diag) != n or bad:
                raise ValueError(f"p0_diag must hold {n} finite positive variances")
        if self.gate_threshold is not None and not (self.gate_threshold > 0):
            raise ValueError("gate_threshold must be > 0 or None")
        if self.divergence is not None and not isinstance(self.divergence, DivergenceConfig):
            raise ValueError(f"divergence must be None or a DivergenceConfig, got {type(self.divergence).__name__}")

    @property
    def vehicle_params(self) -> QuarterCarParams | LRVParams:
        """The parameters of the selected vehicle."""
        return self.quarter_car if self.vehicle == "quarter_car" else self.lrv

    @property
    def k_series(self) -> float:
        """Stiffness in series with the soil of the selected vehicle (N/m)."""
        return self.vehicle_params.k_series


@dataclass(frozen=True)
class SoilStiffnessEstimate:
    """One filter step's result; every float is finite.

    Attributes:
        t: time of the step (s), the accelerometer sample's stamp.
        k_s: soil stiffness (N/m).
        k_s_variance: its first-order variance ((N/m)², MODELS.md A.2).
        k_tot: series stiffness state (N/m).
        k_tot_variance: its filter variance ((N/m)²).
        terrain_class: nearest known soil (``SoilClass.name``).
        class_confidence: 0..1.
        converged: relative k_s standard deviation below the threshold.
        soil_change_detected: the change detector raised an alarm at this step.
        nis: normalised innovation squared of the update (0 for a predict-only
            step).
        accepted: the measurement update was applied.
        state: the full state mean, in the model's state order.
        profile_gap_ratio: the largest gap between profile samples over the
            step divided by the median spacing of the profile buffer (≈ 1 for
            an intact stream; well above 1 when samples were lost, e.g. a node
            falling behind a 1 kHz profiler: the road between the steps is then
            interpolated and k_s is biased, MODELS.md A.10).
    """

    t: float
    k_s: float
    k_s_variance: float
    k_tot: float
    k_tot_variance: float
    terrain_class: str
    class_confidence: float
    converged: bool
    soil_change_detected: bool
    nis: float
    accepted: bool
    state: tuple[float, ...] = ()
    profile_gap_ratio: float = 1.0


def soil_estimate(
    t: float,
    moments: tuple[float, float, float, float],
    config: Any,
    *,
    soil_change_detected: bool,
    nis: float,
    accepted: bool,
    state: tuple[float, ...],
    profile_gap_ratio: float = 1.0,
) -> SoilStiffnessEstimate:
    """The estimate of a step from the stiffness moments ``(k_tot, var k_tot, k_s, var k_s)``: the nearest soil
    class and the convergence test, with the estimator's ``config`` (its ``soil_table``, ``class_log_std``,
    ``unknown_weight`` and ``convergence_rel_std``)."""
    k_tot, k_var, k_s, k_s_var = moments
    cls = classify_soil(k_s, k_s_var, config.soil_table, config.class_log_std, config.unknown_weight)
    return SoilStiffnessEstimate(
        t=t,
        k_s=k_s,
        k_s_variance=k_s_var,
        k_tot=k_tot,
        k_tot_variance=k_var,
        terrain_class=cls.name,
        class_confidence=cls.confidence,
        converged=bool(math.sqrt(k_s_var) < config.convergence_rel_std * k_s),
        soil_change_detected=soil_change_detected,
        nis=nis,
        accepted=accepted,
        state=state,
        profile_gap_ratio=profile_gap_ratio,
    )


@dataclass(frozen=True)
class EstimatorCounters:
    """Health counters since the last reset (for diagnostics)."""

    steps: int = 0
    updates_accepted: int = 0
    gated: int = 0
    predict_only: int = 0
    restarts: int = 0
    recoveries: int = 0
    divergences: int = 0
    soil_changes: int = 0
    decimated: int = 0
    dropped_nonfinite: int = 0
    dropped_out_of_order: int = 0
    dropped_no_profile: int = 0
    dropped_queue_full: int = 0
    profile_rejected: int = 0
