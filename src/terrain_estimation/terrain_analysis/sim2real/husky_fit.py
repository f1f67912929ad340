"""Fits and baselines of the Husky real-data check (:mod:`terrain_analysis.sim2real.husky`).

The tire scales (and optionally one effect) fitted by least squares over training runs, with standard errors
corrected for the residual's autocorrelation; the effective-track baseline; the residual RMS of every model on a
run; the engine's verdict against the baseline on its held-out samples.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from terrain_analysis.sim2real.husky_model import CHANNELS
from terrain_analysis.sim2real.skid_steer_replay import SkidSteerReplay

__all__ = [
    "PhysicsFit",
    "RunScore",
    "cropped_model",
    "effective_track",
    "encoder_yaw_rate",
    "fit_effective_track",
    "fit_physics",
    "integrated_autocorrelation",
    "score_run",
    "split_of",
    "verdict_baseline",
]

FloatArray = NDArray[np.float64]


@dataclass
class RunScore:
    """Residual RMS of every model on one run (channel → value) and what the run is like."""

    run: str
    terrain: str
    seconds: float
    mean_speed: float
    mean_abs_encoder_yaw_rate: float
    gyro_over_encoder: float
    rate_floor: float
    sigma: dict[str, float]
    rms: dict[str, dict[str, float]]  # model → channel → residual RMS


@dataclass
class PhysicsFit:
    """A least-squares fit of the replay's tire scales (and optionally one effect) on training runs.

    Attributes:
        values: fitted nuisance (scale factors of the config's C_x, C_α, μ).
        effects: fitted effect parameters ({effect: {parameter: value}}; empty: none).
        std: Gauss–Newton standard errors as if the samples were independent.
        std_corrected: the same × √τ, τ the integrated autocorrelation time of
            the residual in samples (an effective sample size n/τ).
        reduced_chi2: residual power per degree of freedom (units of the noise budget).
        tau: τ (samples), averaged over runs and channels weighted by their length.
        runs: training runs used.
    """

    values: dict[str, float]
    effects: dict[str, dict[str, float]]
    std: dict[str, float]
    std_corrected: dict[str, float]
    reduced_chi2: float
    tau: float
    runs: int


def _use(model: SkidSteerReplay) -> NDArray[np.bool_]:
    return np.asarray(model.data.t >= model.data.t[0] + model.warmup)


def _residuals(
    model: SkidSteerReplay, nuisance: Mapping[str, float], effects: Mapping[str, Mapping[str, float]] | None = None
) -> FloatArray:
    pred = model.predict(effects or {}, nuisance)
    use = _use(model)
    return np.concatenate([((model.measured[c.name] - pred[c.name]) / c.noise_std)[use] for c in model.channels])


def integrated_autocorrelation(r: FloatArray, max_lag: int = 2000) -> float:
    """τ = 1 + 2 Σ ρ_k (samples) over the initial positive sequence of the autocorrelation (Geyer 1992).

    The variance of a mean of n correlated samples is σ² τ / n: n/τ is the
    effective sample size. 1 for white noise.
    """
    x = np.asarray(r, dtype=float) - float(np.mean(r))
    n = x.size
    if n < 4 or not np.any(x):
        return 1.0
    size = 1 << int(math.ceil(math.log2(2 * n)))
    spectrum = np.fft.rfft(x, size)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), size)[: min(n, max_lag + 1)]
    acf = acf / acf[0]
    tau = 1.0
    for k in range(1, acf.size):
        if acf[k] <= 0.0:
            break
        tau += 2.0 * float(acf[k])
    return tau


def fit_physics(
    models: Sequence[SkidSteerReplay],
    effect: str | None = None,
    *,
    start: Mapping[str, float] | None = None,
    max_nfev: int = 40,
) -> PhysicsFit:
    """Least-squares nuisance (and ``effect``'s parameters) over all samples of ``models``.

    Starts from ``start`` (nuisance values; default their off values) and the
    effect's parameters at off + their typical size. The standard errors are
    given twice: white (Gauss–Newton s²(JᵀJ)⁻¹) and corrected for the
    residual's autocorrelation (× √τ, :func:`integrated_autocorrelation`).
    """
    params = list(models[0].nuisance)
    extra = list(models[0].candidates[effect].parameters) if effect is not None else []
    layout = params + extra
    start = start or {}
    x0 = np.array([start.get(p.name, p.off) for p in params] + [p.off + p.scale for p in extra], dtype=float)
    lo = np.array([p.bounds[0] for p in layout])
    hi = np.array([p.bounds[1] for p in layout])

    def unpack(x: FloatArray) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
        nuisance = {p.name: float(v) for p, v in zip(params, x[: len(params)], strict=True)}
        effects = {}
        if effect is not None:
            effects[effect] = {p.name: float(v) for p, v in zip(extra, x[len(params) :], strict=True)}
        return nuisance, effects

    def fun(x: FloatArray) -> FloatArray:
        nuisance, effects = unpack(x)
        return np.concatenate([_residuals(m, nuisance, effects) for m in models])

    span = hi - lo
    best = optimize.least_squares(
        fun,
        np.clip(x0, lo + 1e-4 * span, hi - 1e-4 * span),
        bounds=(lo, hi),
        x_scale=np.array([p.scale for p in layout]),
        diff_step=1e-3,
        max_nfev=max_nfev,
    )
    r = best.fun
    dof = max(1, r.size - len(x0))
    s2 = float(np.dot(r, r)) / dof
    try:
        jtj = best.jac.T @ best.jac
        sd = np.sqrt(np.clip(np.diag(np.linalg.pinv(jtj) * s2), 0.0, None))
        sd[np.diag(jtj) <= 0.0] = math.nan  # the residual does not depend on it here (e.g. at an active bound)
    except np.linalg.LinAlgError:
        sd = np.full(len(x0), math.nan)
    nuisance, effects = unpack(best.x)
    taus, weights = [], []
    for m in models:
        pred = m.predict(effects, nuisance)
        use = _use(m)
        for c in m.channels:
            res = (m.measured[c.name] - pred[c.name])[use]
            taus.append(integrated_autocorrelation(res))
            weights.append(res.size)
    tau = float(np.average(taus, weights=weights)) if taus else 1.0
    names = [p.name for p in layout]
    return PhysicsFit(
        values=nuisance,
        effects=effects,
        std={n: float(v) for n, v in zip(names, sd, strict=True)},
        std_corrected={n: float(v) * math.sqrt(tau) for n, v in zip(names, sd, strict=True)},
        reduced_chi2=s2,
        tau=tau,
        runs=len(models),
    )


def encoder_yaw_rate(model: SkidSteerReplay) -> FloatArray:
    """(v_R − v_L)/B from the side wheel speeds (rad/s): the no-slip (kinematic) yaw rate."""
    return model.no_slip_motion()[1]


def effective_track(model: SkidSteerReplay, chi: float) -> dict[str, FloatArray]:
    """The effective-track model's channels: yaw rate χ (v_R − v_L)/B and lateral specific force (speed × it)."""
    speed, encoder = model.no_slip_motion()
    return {"yaw_rate": chi * encoder, "ay": speed * chi * encoder}


def fit_effective_track(models: Sequence[SkidSteerReplay]) -> float:
    """χ of the effective-track model yaw = χ (v_R − v_L)/B: least squares over the runs' samples.

    The field engineer's model of a skid steer: the vehicle turns as if its
    track were B/χ. One parameter, no tire, no mass.
    """
    num = den = 0.0
    for m in models:
        use = _use(m)
        enc = encoder_yaw_rate(m)[use]
        num += float(np.dot(enc, m.data.yaw_rate[use]))
        den += float(np.dot(enc, enc))
    return num / den if den > 0.0 else 1.0


def _rms(x: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.asarray(x) ** 2))) if np.size(x) else math.nan


def score_run(
    model: SkidSteerReplay,
    run: str,
    terrain: str,
    physics: Mapping[str, tuple[Mapping[str, float], Mapping[str, Mapping[str, float]]]],
    track: Mapping[str, float],
) -> RunScore:
    """Residual RMS of the baselines (``track``: label → χ) and the physics models (label → (nuisance, effects))."""
    data = model.data
    use = _use(model)
    speed, encoder = model.no_slip_motion()
    rms: dict[str, dict[str, float]] = {
        "zero yaw rate": {"yaw_rate": _rms(data.yaw_rate[use]), "ay": _rms(data.accel[use, 1])}
    }
    for label, chi in track.items():
        base = effective_track(model, chi)
        rms[label] = {c: _rms((model.measured[c] - base[c])[use]) for c in CHANNELS}
    for label, (nuisance, effects) in physics.items():
        pred = model.predict(effects, nuisance)
        rms[label] = {c: _rms((model.measured[c] - pred[c])[use]) for c in CHANNELS}
    denom = float(np.dot(encoder[use], encoder[use]))
    # What the wheel-speed rate costs: the gyro itself, sampled at the joint-report times and interpolated back,
    # misses the yaw-rate content the reports cannot carry (plus the gyro noise, removed in quadrature).
    resampled = np.interp(data.t, data.joint_t, np.interp(data.joint_t, data.t, data.yaw_rate))
    floor2 = float(np.mean((data.yaw_rate - resampled)[use] ** 2)) - model.replay_vehicle.gyro_noise_std**2
    return RunScore(
        run=run,
        terrain=terrain,
        seconds=float(data.t[-1]),
        mean_speed=float(np.mean(np.abs(speed[use]))),
        mean_abs_encoder_yaw_rate=float(np.mean(np.abs(encoder[use]))),
        gyro_over_encoder=float(np.dot(encoder[use], data.yaw_rate[use]) / denom) if denom > 0 else math.nan,
        rate_floor=math.sqrt(max(floor2, 0.0)),
        sigma={c.name: c.noise_std for c in model.channels},
        rms=rms,
    )


def verdict_baseline(model: SkidSteerReplay, report: Any, chi: float) -> dict[str, Any]:
    """The verdict's model against the effective-track baseline on the engine's held-out samples (yaw rate, ay)."""
    from terrain_analysis.sim2real.attribution import AttributionSettings, held_out_mask

    _, test = held_out_mask(model, getattr(report, "settings", None) or AttributionSettings())
    chosen = report.best if getattr(report, "best", None) is not None else report.nominal
    pred = model.predict(chosen.parameters, chosen.nuisance)
    base = effective_track(model, chi)
    out: dict[str, Any] = {"model": " + ".join(chosen.effects) if chosen.effects else "nominal", "chi": chi}
    for c in CHANNELS:
        mask = test[c]
        out[c] = {
            "physics": _rms((model.measured[c] - pred[c])[mask]),
            "effective track": _rms((model.measured[c] - base[c])[mask]),
            "zero": _rms(model.measured[c][mask]) if c == "yaw_rate" else math.nan,
        }
    return out


def cropped_model(model: SkidSteerReplay, seconds: float) -> SkidSteerReplay:
    """The same run's model on its first ``seconds`` (the engine's cost grows with the length)."""
    from dataclasses import replace as dc_replace

    data = model.data
    keep = data.t <= seconds
    jkeep = data.joint_t <= seconds + 1.0
    cropped = dc_replace(
        data,
        **{name: getattr(data, name)[keep] for name in ("t", "accel", "yaw_rate", "omega")},
        **{name: getattr(data, name)[jkeep] for name in ("joint_t", "motor_velocity")},
    )
    return SkidSteerReplay(
        cropped,
        model.replay_vehicle,
        nuisance=[p.name for p in model.nuisance],
        candidates=model.candidates,
        channels=CHANNELS,
        warmup=model.warmup,
    )


def split_of(run: str) -> str:
    """``train`` for an even run number (``TERRAIN/run_04``), ``test`` for an odd one."""
    return "train" if int(run.rsplit("_", 1)[1]) % 2 == 0 else "test"
