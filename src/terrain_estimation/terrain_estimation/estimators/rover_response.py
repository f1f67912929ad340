"""Online terrain-response model of the rover: DP(W, i) and τ_R(W, i) from the estimates ([RB] IV-E, IV-F, V-C).

:class:`TerrainResponseAccumulator` averages the estimator's output into one
sample per wheel per period, gates the samples on curvature and speed, keeps
a bounded window and fits the polynomial models with their stated error
(:class:`TerrainResponseFit`, the fields of
``terrain_msgs/TerrainResponseModel``; MODELS.md C.7); re-exported by
:mod:`terrain_estimation.estimators.rover`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from terrain_estimation.estimators.rover_outputs import RoverEstimate, TerrainResponseCounters
from terrain_estimation.estimators.rover_windows import finite_input, wheel_triple
from terrain_estimation.filters.base import Array
from terrain_estimation.models.rover import WHEELS
from terrain_estimation.models.terrain_response import (
    PolynomialModel2D,
    ValidityRegion,
    coefficient_count,
    fit_polynomial_2d,
    polynomial_exponents,
)
from terrain_estimation.models.terrain_response_error import (
    ValidatedFit,
    bounded_update,
    model_variance,
    region_mean_variance,
    validated_fit,
)

__all__ = [
    "TerrainResponseAccumulator",
    "TerrainResponseConfig",
    "TerrainResponseFit",
]


@dataclass(frozen=True, kw_only=True)
class TerrainResponseConfig:
    """Configuration of :class:`TerrainResponseAccumulator`.

    Attributes:
        sample_period_s: estimates are averaged to one sample per wheel per
            period (2 s, [RB] V-C).
        order: polynomial order of the fits (2 over the operating range, [RB] IV-E).
        max_samples: bounded window of averaged samples kept for the fit
            (all wheels together; oldest dropped first). 900 = 10 min of
            driving with three wheels.
        min_samples: fewer kept samples → no fit; None = 2 × the number of
            coefficients.
        wheelbase: l_w (m); buckets with curvature κ ≥ 1/l_w are rejected
            ([RB] V-B: 1.43 m⁻¹ for Kapvik).
        curvature_gate: apply that gate (when a curvature is known).
        min_curvature_distance: a bucket's curvature is estimated from its
            contact angles only over at least this much travel (m).
        min_bucket_estimates: a bucket needs this many estimates (5 Hz × 2 s = 10).
        min_forward_speed: buckets slower than this are rejected (m/s): the
            slip of a rover at rest is undefined.
        wheels: wheels whose samples feed the fit (e.g. ("front",) to use the
            front wheel as a "sensing wheel" with single-axis cells, [RB] IV-E).
        weighted: weight each sample by 1/variance of its averaged estimate
            (per quantity); False: equal weights as in the paper.
        history_length: fits kept in :attr:`TerrainResponseAccumulator.history`.
        validation_blocks: the kept samples are cut into at most this many
            contiguous blocks of sample periods; each is left out in turn for
            the held-out prediction error and the jackknife covariance of the
            coefficients (:mod:`~terrain_estimation.models.terrain_response_error`).
        max_jump: a new fit moves the published model by at most this
            Mahalanobis distance in the previous model's stated covariance
            (1: one stated σ, for every coefficient and every (i, W));
            ``math.inf``: publish every fit as it is.
    """

    sample_period_s: float = 2.0
    order: int = 2
    max_samples: int = 900
    min_samples: int | None = None
    wheelbase: float = 0.70
    curvature_gate: bool = True
    min_curvature_distance: float = 0.01
    min_bucket_estimates: int = 5
    min_forward_speed: float = 0.005
    wheels: tuple[str, ...] = WHEELS
    weighted: bool = False
    history_length: int = 50
    validation_blocks: int = 10
    max_jump: float = 1.0

    def __post_init__(self) -> None:
        if not (isinstance(self.validation_blocks, int) and self.validation_blocks >= 2):
            raise ValueError(f"validation_blocks must be an int ≥ 2, got {self.validation_blocks!r}")
        if not (isinstance(self.max_jump, int | float) and self.max_jump > 0.0 and not math.isnan(self.max_jump)):
            raise ValueError(f"max_jump must be > 0 (inf: unbounded), got {self.max_jump!r}")
        for name in ("sample_period_s", "wheelbase", "min_curvature_distance"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if not (math.isfinite(self.min_forward_speed) and self.min_forward_speed >= 0.0):
            raise ValueError(f"min_forward_speed must be finite and ≥ 0, got {self.min_forward_speed!r}")
        if not (isinstance(self.order, int) and 0 <= self.order <= 6):
            raise ValueError(f"order must be an int in 0..6, got {self.order!r}")
        for name in ("max_samples", "min_bucket_estimates", "history_length"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"{name} must be an int ≥ 1, got {value!r}")
        if self.min_samples is not None and not (
            isinstance(self.min_samples, int) and coefficient_count(self.order) <= self.min_samples <= self.max_samples
        ):
            raise ValueError(
                f"min_samples must be None or an int in [{coefficient_count(self.order)}, max_samples], "
                f"got {self.min_samples!r}"
            )
        if not self.wheels or any(w not in WHEELS for w in self.wheels) or len(set(self.wheels)) != len(self.wheels):
            raise ValueError(f"wheels must be distinct names from {WHEELS}, got {self.wheels!r}")

    @property
    def max_curvature(self) -> float:
        """1/l_w (m⁻¹)."""
        return 1.0 / self.wheelbase

    @property
    def required_samples(self) -> int:
        """Kept samples needed for a fit."""
        return self.min_samples if self.min_samples is not None else 2 * coefficient_count(self.order)


@dataclass(frozen=True)
class TerrainResponseFit:
    """Fitted DP(W, i) and τ_R(W, i) (the fields of ``terrain_msgs/TerrainResponseModel``).

    The error figures are those of
    :mod:`~terrain_estimation.models.terrain_response_error`: the stated
    error of the model's value at (i, W) is
    σ(i, W) = √(holdout_rms² + estimate_rms² + xᵀ Σ x), x = the terms i^k W^l.

    Attributes:
        t: time of the newest sample in the fit (s).
        order: polynomial order.
        drawbar_pull: DP model (N), validity = the samples' (i, W) range.
        resistive_torque: τ_R model (N·m).
        samples: number of averaged samples fitted.
        dp_rms, tau_rms: residual RMS of the published models on the fitted samples (N, N·m).
        dp_covariance, tau_covariance: (n, n) covariance Σ of the published coefficients.
        dp_holdout_rms, tau_holdout_rms: RMS error on held-out samples (fits without their block).
        dp_estimate_rms, tau_estimate_rms: √(mean stated variance of the fitted estimates): their shared
            error, which no hold-out sees (0 when the estimates came without variances).
        dp_prediction_rms, tau_prediction_rms: √(mean σ(i, W)²) over the validity rectangle.
        validation_samples: samples predicted by a fit that did not see them.
        dp_jump, tau_jump: Mahalanobis distance of the new least-squares fit
            from the previously published model, in that model's covariance
            (0 for the first model).
        limited: the step was shortened to ``max_jump`` (for DP or τ_R).
    """

    t: float
    order: int
    drawbar_pull: PolynomialModel2D
    resistive_torque: PolynomialModel2D
    samples: int
    dp_rms: float
    tau_rms: float
    dp_covariance: Array = field(default_factory=lambda: np.zeros((0, 0)))
    tau_covariance: Array = field(default_factory=lambda: np.zeros((0, 0)))
    dp_holdout_rms: float = 0.0
    tau_holdout_rms: float = 0.0
    dp_estimate_rms: float = 0.0
    tau_estimate_rms: float = 0.0
    dp_prediction_rms: float = 0.0
    tau_prediction_rms: float = 0.0
    validation_samples: int = 0
    dp_jump: float = 0.0
    tau_jump: float = 0.0
    limited: bool = False

    def dp_std(self, slip: Sequence[float] | Array | float, load: Sequence[float] | Array | float) -> Array:
        """Stated error σ(i, W) of the DP model (N)."""
        base = self.dp_holdout_rms**2 + self.dp_estimate_rms**2
        return np.sqrt(base + model_variance(self.order, self.dp_covariance, slip, load))

    def tau_std(self, slip: Sequence[float] | Array | float, load: Sequence[float] | Array | float) -> Array:
        """Stated error σ(i, W) of the τ_R model (N·m)."""
        base = self.tau_holdout_rms**2 + self.tau_estimate_rms**2
        return np.sqrt(base + model_variance(self.order, self.tau_covariance, slip, load))

    @property
    def validity(self) -> ValidityRegion:
        """(i, W) rectangle of the samples."""
        region = self.drawbar_pull.validity
        assert region is not None
        return region

    @property
    def dp_coefficients(self) -> tuple[float, ...]:
        """DP coefficients, term order :func:`~terrain_estimation.models.terrain_response.polynomial_exponents`."""
        return self.drawbar_pull.coefficients

    @property
    def tau_coefficients(self) -> tuple[float, ...]:
        """τ_R coefficients, same term order."""
        return self.resistive_torque.coefficients

    @property
    def exponents(self) -> tuple[tuple[int, int], ...]:
        """(k, l) of each coefficient's term i^k W^l."""
        return polynomial_exponents(self.order)

    @property
    def slip_min(self) -> float:
        return self.validity.slip_min

    @property
    def slip_max(self) -> float:
        return self.validity.slip_max

    @property
    def load_min(self) -> float:
        return self.validity.load_min

    @property
    def load_max(self) -> float:
        return self.validity.load_max


@dataclass
class _Bucket:
    index: int
    t: list[float] = field(default_factory=list)
    slip: list[Array] = field(default_factory=list)
    load: list[Array] = field(default_factory=list)
    pull: list[Array] = field(default_factory=list)
    torque: list[Array] = field(default_factory=list)
    variances: list[Array] = field(default_factory=list)  # (4, 3): slip, W, DP, τ_R
    gamma: list[Array] = field(default_factory=list)
    distance: list[float] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)
    curvature: list[float] = field(default_factory=list)


class TerrainResponseAccumulator:
    """Online terrain-response model ([RB] IV-E/F, V-C): average, gate, keep a window, fit.

    Feed it the estimator's output (:meth:`add_estimate`, or the lower-level
    :meth:`add`); estimates are grouped in buckets of ``sample_period_s``
    (2 s) on a grid from the first stamp and each closed bucket gives one
    averaged (i, W, DP, τ_R) sample per wheel of ``config.wheels``.
    :meth:`fit` fits the 2nd-order DP(W, i), τ_R(W, i) to the kept samples.

    **Curvature gate** ([RB] V-B: terrain with κ ≥ 1/l_w breaks the ż0^R ≈ 0
    assumption). A bucket is rejected when its curvature is ≥ 1/l_w. The
    curvature is, in this order: the largest ``curvature`` passed with the
    bucket's estimates (e.g. from forward-looking range data, as the paper
    proposes); otherwise estimated from the estimates themselves: the
    contact angle γ_j is the direction of wheel j's path, so its rate of
    change along the travelled distance s = ∫ẋ0^R dt is the path curvature,
    κ_j = |dγ_j/ds|, fitted by least squares over the bucket (≈ 4 cm of travel
    at 2 cm/s, where γ noise of 2e-3 rad gives ≈ 0.1 m⁻¹ of curvature noise
    against the 1.43 m⁻¹ gate); κ = max over the wheels. With too little
    travel (< ``min_curvature_distance``) the curvature is unknown and the
    bucket is not gated on it (it is still gated on ``min_forward_speed``).

    **The model's error** (issue 21; :mod:`~terrain_estimation.models.terrain_response_error`).
    The fit residual (``dp_rms``) understates the model's error 3–4× on the
    Kapvik runs (correlated samples, lack of fit, empty corners of the
    rectangle, biases the samples share). Each fit therefore carries the
    coefficients' covariance (delete-a-block jackknife over
    ``validation_blocks`` contiguous blocks of sample periods), the RMS error
    on held-out samples, and the estimates' own stated error; and a new fit
    moves the published model by at most ``max_jump`` of the previous
    model's stated σ (the step not taken is added to the covariance).

    Args:
        config: settings.
    """

    def __init__(self, config: TerrainResponseConfig | None = None) -> None:
        self.config = config if config is not None else TerrainResponseConfig()
        self._wheel_idx = [WHEELS.index(w) for w in self.config.wheels]
        self.reset()

    def reset(self) -> None:
        """Forget the buckets, samples, history and counters."""
        self._t_origin: float | None = None
        self._t_last: float | None = None
        self._bucket: _Bucket | None = None
        self._samples: deque[tuple[float, float, float, float, float, Array]] = deque(maxlen=self.config.max_samples)
        self._history: deque[TerrainResponseFit] = deque(maxlen=self.config.history_length)
        self._c: dict[str, int] = dict.fromkeys(TerrainResponseCounters.__dataclass_fields__, 0)
        self._last_curvature: float | None = None

    @property
    def counters(self) -> TerrainResponseCounters:
        return TerrainResponseCounters(**self._c)

    @property
    def sample_count(self) -> int:
        """Averaged samples kept for the fit."""
        return len(self._samples)

    @property
    def history(self) -> tuple[TerrainResponseFit, ...]:
        """Past fits, oldest first (a history of coefficients, [RB] IV-F)."""
        return tuple(self._history)

    @property
    def last_curvature(self) -> float | None:
        """Curvature of the last closed bucket (m⁻¹), None if unknown."""
        return self._last_curvature

    def samples(self) -> dict[str, Array]:
        """Kept samples as arrays: ``t``, ``slip``, ``normal_load``, ``drawbar_pull``, ``resistive_torque``.

        Also ``<quantity>_variance``: the mean of the averaged estimates' variances (ones when none were given).
        """
        rows = list(self._samples)
        names = ("t", "slip", "normal_load", "drawbar_pull", "resistive_torque")
        out = {name: np.array([r[k] for r in rows], dtype=float) for k, name in enumerate(names)}
        var = np.array([r[5] for r in rows], dtype=float).reshape(-1, 4)
        for k, name in enumerate(names[1:]):
            out[f"{name}_variance"] = var[:, k]
        return out

    def add_estimate(self, estimate: RoverEstimate, curvature: float | None = None) -> None:
        """Add one estimator output; ``curvature`` (m⁻¹) overrides the γ-based estimate for its bucket."""
        self.add(
            estimate.t,
            slip=estimate.per_wheel("slip"),
            normal_load=estimate.per_wheel("normal_load"),
            drawbar_pull=estimate.per_wheel("drawbar_pull"),
            resistive_torque=estimate.per_wheel("resistive_torque"),
            variances=np.array(
                [
                    estimate.per_wheel("slip_variance"),
                    estimate.per_wheel("normal_load_variance"),
                    estimate.per_wheel("drawbar_pull_variance"),
                    estimate.per_wheel("resistive_torque_variance"),
                ]
            ),
            contact_angle=estimate.per_wheel("contact_angle"),
            distance=estimate.distance,
            forward_speed=estimate.body.forward_speed,
            curvature=curvature,
        )

    def add(
        self,
        t: float,
        *,
        slip: Sequence[float] | Array,
        normal_load: Sequence[float] | Array,
        drawbar_pull: Sequence[float] | Array,
        resistive_torque: Sequence[float] | Array,
        variances: Array | None = None,
        contact_angle: Sequence[float] | Array | None = None,
        distance: float | None = None,
        forward_speed: float | None = None,
        curvature: float | None = None,
    ) -> None:
        """Add one set of per-wheel estimates (WHEELS order) at time ``t``.

        Args:
            t: stamp (s), increasing.
            slip, normal_load, drawbar_pull, resistive_torque: (3,) each.
            variances: (4, 3) variances of slip, W, DP, τ_R (for ``weighted``).
            contact_angle: γ (3,) (rad) and ``distance`` travelled (m): for
                the curvature estimate.
            forward_speed: (m/s), for the speed gate (None: not gated).
            curvature: known curvature (m⁻¹) at this estimate.

        Raises:
            ValueError: non-finite or mis-sized values, or a stamp not after the previous one.
        """
        where = "TerrainResponseAccumulator.add"
        tt = finite_input(where, "t", t)
        if self._t_last is not None and tt <= self._t_last:
            raise ValueError(f"{where}: t = {t!r} is not after the previous stamp {self._t_last!r}")
        named = (
            ("slip", slip),
            ("normal_load", normal_load),
            ("drawbar_pull", drawbar_pull),
            ("resistive_torque", resistive_torque),
        )
        values = [wheel_triple(where, n, v) for n, v in named]
        var = None
        if variances is not None:
            var = np.asarray(variances, dtype=float)
            if var.shape != (4, 3) or not np.isfinite(var).all():
                raise ValueError(f"{where}: variances must be finite with shape (4, 3), got {variances!r}")
        gamma = None if contact_angle is None else wheel_triple(where, "contact_angle", contact_angle)
        dist = None if distance is None else finite_input(where, "distance", distance)
        speed = None if forward_speed is None else finite_input(where, "forward_speed", forward_speed)
        kappa = None if curvature is None else abs(finite_input(where, "curvature", curvature))
        self._t_last = tt
        self._c["estimates"] += 1
        if self._t_origin is None:
            self._t_origin = tt
        index = math.floor((tt - self._t_origin) / self.config.sample_period_s + 1e-9)
        if self._bucket is not None and index != self._bucket.index:
            self._close_bucket()
        if self._bucket is None:
            self._bucket = _Bucket(index)
        b = self._bucket
        b.t.append(tt)
        b.slip.append(values[0])
        b.load.append(values[1])
        b.pull.append(values[2])
        b.torque.append(values[3])
        if var is not None:
            b.variances.append(var)
        if gamma is not None and dist is not None:
            b.gamma.append(gamma)
            b.distance.append(dist)
        if speed is not None:
            b.speed.append(speed)
        if kappa is not None:
            b.curvature.append(kappa)

    def flush(self) -> None:
        """Close the open bucket now (e.g. before fitting when the rover stops)."""
        if self._bucket is not None:
            self._close_bucket()

    def start_segment(self) -> None:
        """Close the open bucket and restart the time base, keeping the samples.

        For a new log (e.g. another traverse replayed offline) whose stamps
        start again from an earlier time.
        """
        self.flush()
        self._t_origin = None
        self._t_last = None

    def bucket_curvature(self, gamma: Array, distance: Array) -> float | None:
        """max_j |dγ_j/ds| by least squares over a bucket (m⁻¹); None with too little travel."""
        s = np.asarray(distance, dtype=float)
        if s.size < 3 or float(s.max() - s.min()) < self.config.min_curvature_distance:
            return None
        ds = s - s.mean()
        g = np.asarray(gamma, dtype=float)
        slopes = (ds @ (g - g.mean(axis=0))) / float(ds @ ds)
        return float(np.max(np.abs(slopes)))

    def _close_bucket(self) -> None:
        b = self._bucket
        self._bucket = None
        assert b is not None
        cfg = self.config
        self._c["buckets"] += 1
        if len(b.t) < cfg.min_bucket_estimates:
            self._c["rejected_sparse"] += 1
            return
        if b.curvature:
            kappa: float | None = max(b.curvature)
        elif len(b.gamma) == len(b.t):
            kappa = self.bucket_curvature(np.array(b.gamma), np.array(b.distance))
        else:
            kappa = None
        self._last_curvature = kappa
        if b.speed and float(np.mean(b.speed)) < cfg.min_forward_speed:
            self._c["rejected_speed"] += 1
            return
        if cfg.curvature_gate and kappa is not None and kappa >= cfg.max_curvature:
            self._c["rejected_curvature"] += 1
            return
        self._c["buckets_used"] += 1
        t_mean = float(np.mean(b.t))
        n = len(b.t)
        mean = [np.mean(np.array(q), axis=0) for q in (b.slip, b.load, b.pull, b.torque)]
        # Variance of a mean of n correlated filter outputs: at most the mean variance
        # (fully correlated); used only as a relative weight.
        # NaN: no variances came with the estimates (weights then equal, no estimate error stated).
        var = np.mean(np.array(b.variances), axis=0) if len(b.variances) == n else np.full((4, 3), np.nan)
        for j in self._wheel_idx:
            if len(self._samples) == self._samples.maxlen:
                self._c["samples_dropped"] += 1
            self._samples.append(
                (t_mean, float(mean[0][j]), float(mean[1][j]), float(mean[2][j]), float(mean[3][j]), var[:, j].copy())
            )

    def fit(self) -> TerrainResponseFit | None:
        """2nd-order (``config.order``) fits of DP(W, i) and τ_R(W, i) to the kept samples, with their error.

        Each fit comes with its coefficient covariance (block jackknife) and
        held-out error (:func:`~terrain_estimation.models.terrain_response_error.validated_fit`,
        blocks of whole sample periods), and moves the previously published
        model by at most ``config.max_jump`` of its stated σ
        (:func:`~terrain_estimation.models.terrain_response_error.bounded_update`).

        Returns None with fewer than ``config.required_samples`` samples or a
        rank-deficient design (e.g. all samples at one slip); a fit is also
        appended to :attr:`history`.
        """
        cfg = self.config
        if len(self._samples) < cfg.required_samples:
            return None
        rows = list(self._samples)
        stamps = np.array([r[0] for r in rows])
        slip = np.array([r[1] for r in rows])
        load = np.array([r[2] for r in rows])
        pull = np.array([r[3] for r in rows])
        torque = np.array([r[4] for r in rows])
        var = np.array([r[5] for r in rows])
        weights = np.nan_to_num(var, nan=1.0)
        w_dp = 1.0 / np.maximum(weights[:, 2], 1e-12) if cfg.weighted else None
        w_tau = 1.0 / np.maximum(weights[:, 3], 1e-12) if cfg.weighted else None
        blocks = cfg.validation_blocks
        try:
            # Errors in the variables: a sample sits at the estimated (i, W), so the errors of slip and load
            # reach the model through its slopes (τ_R and DP are steep in slip); the stated error uses
            # var_y + (∂y/∂i)² var_i + (∂y/∂W)² var_W, the slopes those of the plain least-squares fit (the
            # validated fit's coefficients are the same, issue 21).
            dp_slopes = fit_polynomial_2d(slip, load, pull, cfg.order, w_dp).model
            tau_slopes = fit_polynomial_2d(slip, load, torque, cfg.order, w_tau).model
            dp = validated_fit(
                slip,
                load,
                pull,
                cfg.order,
                groups=stamps,
                weights=w_dp,
                max_blocks=blocks,
                sample_variances=_in_variables(dp_slopes, slip, load, var[:, 2], var[:, 0], var[:, 1]),
            )
            tau = validated_fit(
                slip,
                load,
                torque,
                cfg.order,
                groups=stamps,
                weights=w_tau,
                max_blocks=blocks,
                sample_variances=_in_variables(tau_slopes, slip, load, var[:, 3], var[:, 0], var[:, 1]),
            )
        except ValueError:
            return None
        previous = self._history[-1] if self._history else None
        published = []
        for new, old_model, old_cov, weight, values in (
            (
                dp,
                None if previous is None else previous.drawbar_pull,
                None if previous is None else previous.dp_covariance,
                w_dp,
                pull,
            ),
            (
                tau,
                None if previous is None else previous.resistive_torque,
                None if previous is None else previous.tau_covariance,
                w_tau,
                torque,
            ),
        ):
            known = old_model is not None and old_cov is not None and old_cov.size > 0
            step = bounded_update(
                old_model.coefficients if known and old_model is not None else None,
                old_cov if known else None,
                new.model.coefficients,
                new.covariance,
                cfg.max_jump,
            )
            model = PolynomialModel2D(
                order=cfg.order, coefficients=tuple(step.coefficients), validity=new.model.validity
            )
            published.append((new, step, model, model.residual_rms(slip, load, values, weight)))
        (dp_fit, dp_step, dp_model, dp_rms), (tau_fit, tau_step, tau_model, tau_rms) = published
        result = TerrainResponseFit(
            t=float(stamps.max()),
            order=cfg.order,
            drawbar_pull=dp_model,
            resistive_torque=tau_model,
            samples=len(rows),
            dp_rms=dp_rms,
            tau_rms=tau_rms,
            dp_covariance=dp_step.covariance,
            tau_covariance=tau_step.covariance,
            dp_holdout_rms=dp_fit.holdout_rms,
            tau_holdout_rms=tau_fit.holdout_rms,
            dp_estimate_rms=dp_fit.estimate_rms,
            tau_estimate_rms=tau_fit.estimate_rms,
            dp_prediction_rms=_prediction_rms(dp_fit, dp_step.covariance),
            tau_prediction_rms=_prediction_rms(tau_fit, tau_step.covariance),
            validation_samples=min(dp_fit.validation_samples, tau_fit.validation_samples),
            dp_jump=dp_step.distance,
            tau_jump=tau_step.distance,
            limited=dp_step.limited or tau_step.limited,
        )
        self._c["fits"] += 1
        self._history.append(result)
        return result


def _in_variables(
    model: PolynomialModel2D, slip: Array, load: Array, var_y: Array, var_slip: Array, var_load: Array
) -> Array:
    """var_y + (∂y/∂i)² var_i + (∂y/∂W)² var_W at each sample (central differences of ``model``); NaN stays NaN."""
    di, dw = 1e-4, 1e-2
    d_slip = (model.evaluate(slip + di, load) - model.evaluate(slip - di, load)) / (2.0 * di)
    d_load = (model.evaluate(slip, load + dw) - model.evaluate(slip, load - dw)) / (2.0 * dw)
    out: Array = var_y + d_slip * d_slip * var_slip + d_load * d_load * var_load
    return out


def _prediction_rms(fit: ValidatedFit, covariance: Array) -> float:
    """√(holdout² + estimate² + mean xᵀΣx) over the fit's validity rectangle, with the published covariance."""
    region = fit.model.validity
    assert region is not None
    base = fit.holdout_rms**2 + fit.estimate_rms**2
    return math.sqrt(base + region_mean_variance(fit.model.order, covariance, region))
