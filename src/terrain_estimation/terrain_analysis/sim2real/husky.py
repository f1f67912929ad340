"""Real-data check of the skid-steer replay: BorealTC Husky A200 runs (issue 6).

``python -m terrain_analysis.sim2real.husky --data /work/shared/real_data/borealtc --out DIR``

What it does
    1. Imports every run (``imu_XX.csv`` + ``pro_XX.csv``) into a contract bag
       (:mod:`vehicle_sim.tools.borealtc`) under ``DIR/bags`` (or ``--bags``).
    2. Builds the replay model of :mod:`terrain_analysis.sim2real.skid_steer`
       for each bag with the 4-wheel Husky of ``config/husky.yaml`` (two axles
       at ±wheelbase/2, rigid chassis: no load-transfer-dynamics effect).
       Channels: yaw rate and lateral specific force (the longitudinal one
       would be a derivative of wheel speeds reported at 6.5 Hz). The side
       speeds are taken as instantaneous at their stamps and interpolated
       linearly to the 100 Hz IMU stamps.
    3. Noise budget per channel: the IMU's own high-frequency noise
       (robust σ of first differences / √2 of the 100 Hz signal: white sensor
       noise plus vibration, which no replay predicts) plus what the wheel-speed
       quantisation (0.0157 m/s steps) does through the replay.
    4. Fits the tire parameters the data set cannot give (scales of C_x, C_α
       and μ, nuisance parameters) on the *training* runs of one terrain
       (even run numbers) by least squares over all their samples, then scores
       the held-out runs of that terrain (odd numbers) and every run of the
       other terrain with the parameters fitted there and with the nominal
       (config) values, against the kinematic baseline (encoder yaw rate
       (v_R − v_L)/B, what a no-slip model predicts). Both directions
       (ASPHALT → SANDY_LOAM and back).
    5. Runs the attribution engine on a few held-out runs (nuisance started at
       the fitted values) and reports its verdicts as they are.

Writes ``DIR/husky.md`` (a Markdown section), ``DIR/husky.json`` and
``DIR/husky.png``.

The 6.5 Hz wheel speeds cost: yaw-rate content above their Nyquist
frequency (3.25 Hz) cannot be predicted, a step in the side speeds is smeared
over one report period (0.15 s), and linear interpolation lags a ramp by
nothing but misses its corners; residuals at those frequencies are model
error, not an effect.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from terrain_analysis.sim2real.model import candidates_from_catalogue
from terrain_analysis.sim2real.skid_steer import (
    ReplayVehicle,
    SkidSteerReplay,
    read_skid_steer_bag,
)
from terrain_estimation.cli import cli_main

__all__ = ["NUISANCE_NAMES", "husky_vehicle", "imu_noise_std", "build_husky_model", "main"]

FloatArray = NDArray[np.float64]

NUISANCE_NAMES = ("longitudinal_stiffness_scale", "cornering_stiffness_scale", "friction_scale")
CHANNELS = ("yaw_rate", "ay")


def imu_noise_std(x: FloatArray) -> float:
    """Robust white-noise σ of a 100 Hz signal: 1.4826 × MAD of first differences / √2."""
    d = np.diff(np.asarray(x, dtype=float))
    mad = float(np.median(np.abs(d - np.median(d))))
    return max(1.4826 * mad / math.sqrt(2.0), 1e-6)


def husky_vehicle(config: str | Path | None = None, *, accel_noise_std: float, gyro_noise_std: float) -> ReplayVehicle:
    """The Husky of ``config/husky.yaml`` as a :class:`ReplayVehicle` (rigid chassis, two axles)."""
    from vehicle_sim.tools.borealtc import read_husky_config

    c = read_husky_config(config)
    half = 0.5 * c["vehicle.wheelbase"]
    radius = c["vehicle.wheel_radius"]
    return ReplayVehicle(
        name="husky",
        mass=c["vehicle.mass"],
        yaw_inertia=c["vehicle.yaw_inertia"],
        gravity=c["vehicle.gravity"],
        axle_x=(half, -half),
        track=c["vehicle.track"],
        cg_height=c["vehicle.cg_height"],
        wheel_radius=radius,
        transmission_ratio=c["vehicle.transmission_ratio"],
        longitudinal_stiffness=c["vehicle.longitudinal_stiffness"],
        cornering_stiffness=c["vehicle.cornering_stiffness"],
        friction=c["vehicle.friction"],
        rolling_speed_floor=c["vehicle.rolling_speed_floor"],
        rolling_resistance=c["vehicle.rolling_resistance"],
        rolling_resistance_speed=c["vehicle.rolling_resistance_speed"],
        suspension=None,
        longitudinal_relaxation_length=c["vehicle.longitudinal_relaxation_length"],
        lateral_relaxation_length=c["vehicle.lateral_relaxation_length"],
        relaxation_speed_floor=c["vehicle.relaxation_speed_floor"],
        accel_noise_std=accel_noise_std,
        gyro_noise_std=gyro_noise_std,
        wheel_speed_noise_std=0.0,
        speed_step=c["sensors.wheel_speed_step"] / radius,
    )


def build_husky_model(
    bag: str | Path, config: str | Path | None = None, *, namespace: str = "/husky", warmup: float = 1.0
) -> SkidSteerReplay:
    """Replay model of one imported Husky bag (module docstring)."""
    from vehicle_sim.tools.borealtc import read_husky_config

    ratio = read_husky_config(config)["vehicle.transmission_ratio"]
    data = read_skid_steer_bag(bag, namespace=namespace, transmission_ratio=ratio, wheel_speed_timing="instantaneous")
    vehicle = husky_vehicle(
        config, accel_noise_std=imu_noise_std(data.accel[:, 1]), gyro_noise_std=imu_noise_std(data.yaw_rate)
    )
    # μ and C_α are nuisance parameters here (fitted in every model): their catalogue effects would duplicate them.
    duplicates = ("friction_change", "cornering_stiffness_change", "load_transfer_dynamics")
    candidates = candidates_from_catalogue("skid_steer", exclude=duplicates)
    model = SkidSteerReplay(
        data, vehicle, nuisance=NUISANCE_NAMES, channels=CHANNELS, warmup=warmup, candidates=candidates
    )
    model.notes.append(
        "Husky: friction_change and cornering_stiffness_change not offered (μ and C_α are fitted as nuisance); "
        "load_transfer_dynamics not offered (rigid chassis)"
    )
    model.notes.append(
        "Husky: side speeds at 6.5 Hz interpolated to the IMU; noise budget = IMU high-frequency σ + quantisation"
    )
    return model


#: Physically plausible peak tire–ground friction μ of a lugged rubber tire per BorealTC terrain (low, high):
#: dry asphalt and concrete 0.8–0.9 peak, wet 0.5–0.7; gravel 0.6; earth road 0.5–0.7 dry; packed snow 0.2,
#: ice 0.1 (Wong, *Theory of Ground Vehicles*, 4th ed., Table 1.3), widened for lugs and the robot's small
#: tires; loose soils and sand 0.3–0.8 (traction coefficients of Wong ch. 2–4). Unknown terrains:
#: :data:`DEFAULT_FRICTION`.
TERRAIN_FRICTION: Mapping[str, tuple[float, float]] = {
    "ASPHALT": (0.5, 1.1),
    "FLOORING": (0.4, 1.1),
    "CROSSGRID": (0.3, 1.1),
    "SANDY_LOAM": (0.3, 0.9),
    "SILTY_LOAM": (0.3, 0.9),
    "QUARTZ_SAND": (0.3, 0.8),
    "SNOW": (0.1, 0.5),
    "ICE": (0.05, 0.3),
}
DEFAULT_FRICTION = (0.05, 1.1)
#: Slip stiffness per unit static wheel load, C_x / F_z (–) and C_α / F_z (1/rad): 1–30. Pneumatic tires on a
#: rigid surface 10–25 (Pacejka, *Tire and Vehicle Dynamics*, ch. 1; small tires 5–10 /rad); deformable ground
#: adds the soil's shear compliance in series and lowers it, but a slip stiffness under 1 (the full load only at
#: 100 % slip) is a soil that does not carry a tire.
STIFFNESS_PER_LOAD = (1.0, 30.0)
#: A fitted value within this fraction of its fit range's span from a bound is "at the bound".
BOUND_TOLERANCE = 0.01
#: The physics "beats" a baseline on a run when its held-out yaw-rate RMS is below this fraction of the
#: baseline's, and is "worse" above its inverse (in between: equal).
BEAT_RATIO = 0.95


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
    v = model.replay_vehicle
    return np.asarray(v.wheel_radius * (model.data.omega[:, 1] - model.data.omega[:, 0]) / v.track)


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
    vehicle = model.replay_vehicle
    encoder = encoder_yaw_rate(model)
    speed = vehicle.wheel_radius * 0.5 * (data.omega[:, 0] + data.omega[:, 1])
    rms: dict[str, dict[str, float]] = {
        "zero yaw rate": {"yaw_rate": _rms(data.yaw_rate[use]), "ay": _rms(data.accel[use, 1])}
    }
    for label, chi in track.items():
        rms[label] = {
            "yaw_rate": _rms((data.yaw_rate - chi * encoder)[use]),
            "ay": _rms((data.accel[:, 1] - speed * chi * encoder)[use]),
        }
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


# ---------------------------------------------------------------------------
# Flags: parameters at a fit bound or outside their physical range
# ---------------------------------------------------------------------------


def physical_ranges(vehicle: ReplayVehicle, terrain: str) -> dict[str, tuple[str, float, float, float, str]]:
    """Nuisance name → (physical quantity, factor scale → quantity, low, high, unit) on ``terrain``."""
    load = vehicle.mass * vehicle.gravity / (2 * vehicle.n_axles)
    mu_lo, mu_hi = TERRAIN_FRICTION.get(terrain, DEFAULT_FRICTION)
    lo, hi = STIFFNESS_PER_LOAD
    return {
        "friction_scale": ("μ", vehicle.friction, mu_lo, mu_hi, "–"),
        "longitudinal_stiffness_scale": ("C_x/F_z", vehicle.longitudinal_stiffness / load, lo, hi, "–"),
        "cornering_stiffness_scale": ("C_α/F_z", vehicle.cornering_stiffness / load, lo, hi, "1/rad"),
    }


def flag_value(
    subject: str,
    name: str,
    value: float,
    bounds: tuple[float, float],
    *,
    off: float | None = None,
    physical: tuple[str, float, float, float, str] | None = None,
) -> list[dict[str, Any]]:
    """Flags of one fitted value: at a bound of its fit range (not at its off value), outside its physical range.

    ``physical`` = (quantity, factor, low, high, unit): the value × factor must lie in [low, high].
    """
    flags: list[dict[str, Any]] = []
    lo, hi = bounds
    quantity, factor, unit = name, 1.0, ""
    if physical is not None:
        quantity, factor, _, _, unit = physical
    shown = value * factor
    for bound in (lo, hi):
        # 1 % of the span, and no more than 2 % of the bound itself (a scale range 0.05–10 spans 200×).
        tol = BOUND_TOLERANCE * (hi - lo)
        if bound != 0.0:
            tol = min(tol, 2.0 * BOUND_TOLERANCE * abs(bound))
        if abs(value - bound) <= tol and (off is None or abs(bound - off) > tol):
            flags.append(
                {
                    "subject": subject,
                    "parameter": name,
                    "quantity": quantity,
                    "value": shown,
                    "unit": unit,
                    "reason": f"at the fit bound {bound * factor:.3g} of [{lo * factor:.3g}, {hi * factor:.3g}]",
                }
            )
    if physical is not None:
        _, _, plo, phi, _ = physical
        if not plo <= shown <= phi:
            flags.append(
                {
                    "subject": subject,
                    "parameter": name,
                    "quantity": quantity,
                    "value": shown,
                    "unit": unit,
                    "reason": f"outside the physical range [{plo:.3g}, {phi:.3g}]",
                }
            )
    return flags


def _effect_physical(effect: str, parameter: str) -> tuple[str, float, float, float, str] | None:
    """(quantity, 1, low, high, unit) of a catalogue parameter's plausible range (``vehicle_sim.effects``)."""
    from vehicle_sim.effects import CATALOGUE

    try:
        p = CATALOGUE["skid_steer"][effect].parameter(parameter)
    except KeyError:
        return None
    low, high = getattr(p, "plausible_range", p.fit_range)
    return (parameter, 1.0, float(low), float(high), p.unit)


def flag_fit(subject: str, fit: PhysicsFit, model: SkidSteerReplay, terrain: str) -> list[dict[str, Any]]:
    """Flags of every parameter of a :class:`PhysicsFit` (nuisance and effect)."""
    ranges = physical_ranges(model.replay_vehicle, terrain)
    flags: list[dict[str, Any]] = []
    for p in model.nuisance:
        flags += flag_value(subject, p.name, fit.values[p.name], p.bounds, physical=ranges.get(p.name))
    for name, sd in fit.std_corrected.items():
        value = fit.values.get(name, fit.effects.get(next(iter(fit.effects), ""), {}).get(name, math.nan))
        if not (math.isfinite(sd) and sd < abs(value)):
            flags.append(
                {
                    "subject": subject,
                    "parameter": name,
                    "quantity": name,
                    "value": value,
                    "unit": "",
                    "reason": f"not identified by the training runs (corrected σ {sd:.3g} ≥ |value|)",
                }
            )
    for effect, values in fit.effects.items():
        for p in model.candidates[effect].parameters:
            flags += flag_value(
                subject,
                f"{effect}.{p.name}",
                values[p.name],
                p.bounds,
                off=p.off,
                physical=_effect_physical(effect, p.name),
            )
    return flags


def flag_engine(
    subject: str, model: SkidSteerReplay, terrain: str, fitted: Any, top: Sequence[Any]
) -> list[dict[str, Any]]:
    """Flags of the engine's fitted parameters: the verdict's model and the top of its ranking."""
    ranges = physical_ranges(model.replay_vehicle, terrain)
    bounds = {p.name: p.bounds for p in model.nuisance}
    flags: list[dict[str, Any]] = []
    seen: set[tuple[str, str]] = set()
    for m in [fitted, *top]:
        if m is None:
            continue
        label = f"{subject}: {' + '.join(m.effects) if m.effects else 'nominal'}"
        for name, value in m.nuisance.items():
            if ("nuisance", name) in seen or name not in bounds:
                continue
            seen.add(("nuisance", name))
            flags += flag_value(label, name, float(value), bounds[name], physical=ranges.get(name))
        for effect, values in m.parameters.items():
            for p in model.candidates[effect].parameters:
                if p.name in values and (effect, p.name) not in seen:
                    seen.add((effect, p.name))
                    flags += flag_value(
                        label,
                        f"{effect}.{p.name}",
                        float(values[p.name]),
                        p.bounds,
                        off=p.off,
                        physical=_effect_physical(effect, p.name),
                    )
    return flags


def verdict_baseline(model: SkidSteerReplay, report: Any, chi: float) -> dict[str, Any]:
    """The verdict's model against the effective-track baseline on the engine's held-out samples (yaw rate, ay)."""
    from terrain_analysis.sim2real.attribution import AttributionSettings, held_out_mask

    _, test = held_out_mask(model, getattr(report, "settings", None) or AttributionSettings())
    chosen = report.best if getattr(report, "best", None) is not None else report.nominal
    pred = model.predict(chosen.parameters, chosen.nuisance)
    data = model.data
    encoder = encoder_yaw_rate(model)
    speed = model.replay_vehicle.wheel_radius * 0.5 * (data.omega[:, 0] + data.omega[:, 1])
    base = {"yaw_rate": chi * encoder, "ay": speed * chi * encoder}
    out: dict[str, Any] = {"model": " + ".join(chosen.effects) if chosen.effects else "nominal", "chi": chi}
    for c in CHANNELS:
        mask = test[c]
        out[c] = {
            "physics": _rms((model.measured[c] - pred[c])[mask]),
            "effective track": _rms((model.measured[c] - base[c])[mask]),
            "zero": _rms(model.measured[c][mask]) if c == "yaw_rate" else math.nan,
        }
    return out


def _cropped(model: SkidSteerReplay, seconds: float) -> SkidSteerReplay:
    """The same run's model on its first ``seconds`` (the engine's cost grows with the length)."""
    from dataclasses import replace as dc_replace

    data = model.data
    keep = data.t <= seconds
    jkeep = data.joint_t <= seconds + 1.0
    cropped = dc_replace(
        data,
        t=data.t[keep],
        accel=data.accel[keep],
        yaw_rate=data.yaw_rate[keep],
        omega=data.omega[keep],
        joint_t=data.joint_t[jkeep],
        motor_velocity=data.motor_velocity[jkeep],
    )
    return SkidSteerReplay(
        cropped,
        model.replay_vehicle,
        nuisance=[p.name for p in model.nuisance],
        candidates=model.candidates,
        channels=CHANNELS,
        warmup=model.warmup,
    )


def _split(run: str) -> str:
    return "train" if int(run.rsplit("_", 1)[1]) % 2 == 0 else "test"


def _labels(terrains: Sequence[str]) -> dict[str, list[str]]:
    """Model labels of the score tables: baselines and physics, per terrain of the fit."""
    return {
        "baselines": ["zero yaw rate", "kinematic (χ = 1)"] + [f"effective track ({t})" for t in terrains],
        "physics": ["nominal (config)"]
        + [f"physics ({t})" for t in terrains]
        + [f"physics + turning resistance ({t})" for t in terrains],
    }


@cli_main("sim2real-husky")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m terrain_analysis.sim2real.husky", description=(__doc__ or "").splitlines()[0]
    )
    parser.add_argument("--data", required=True, help="BorealTC folder (<TERRAIN>/imu_XX.csv, pro_XX.csv)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--config", help="Husky config (default config/husky.yaml)")
    parser.add_argument("--bags", help="where the imported contract bags go (default OUT/bags)")
    parser.add_argument("--overwrite", action="store_true", help="replace bags imported by an earlier run")
    parser.add_argument("--attribute", type=int, default=1, help="held-out runs per terrain given to the engine")
    parser.add_argument(
        "--attribute-seconds", type=float, default=30.0, help="first seconds of each such run given to the engine"
    )
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="re-write OUT/husky.md from OUT/husky.json of an earlier run (no fit, no figure)",
    )
    args = parser.parse_args(argv)
    from vehicle_sim.tools.borealtc import convert_run, find_runs, read_husky_config

    out = Path(args.out)
    if args.report_only:
        from terrain_analysis.reporting import write_section

        saved = json.loads((out / "husky.json").read_text())
        write_section(out / "husky.md", "husky", _markdown(saved, sorted(saved["effective_track"])))
        print(f"wrote {out / 'husky.md'} from {out / 'husky.json'}")
        return 0
    out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    cfg = read_husky_config(args.config)
    runs = find_runs(args.data)
    models: dict[str, SkidSteerReplay] = {}
    terrain_of: dict[str, str] = {}
    for run in runs:
        bag = convert_run(
            run,
            Path(args.bags) if args.bags else out / "bags",
            wheel_radius=cfg["vehicle.wheel_radius"],
            transmission_ratio=cfg["vehicle.transmission_ratio"],
            overwrite=args.overwrite,
            inputs=[args.data],
        )
        models[run.name] = build_husky_model(bag, args.config)
        terrain_of[run.name] = run.terrain
        print(f"{run.name}: {models[run.name].data.t[-1]:.1f} s", file=sys.stderr)
    terrains = sorted(set(terrain_of.values()))
    any_model = next(iter(models.values()))
    fits: dict[str, dict[str, Any]] = {}
    flags: list[dict[str, Any]] = []
    chi: dict[str, float] = {}
    for terrain in terrains:
        train = [models[n] for n in models if terrain_of[n] == terrain and _split(n) == "train"]
        chi[terrain] = fit_effective_track(train)
        start: dict[str, float] = {}
        for kind, effect in (("physics", None), ("physics + turning resistance", "turning_resistance")):
            # The turning-resistance fit starts from the tire fit (it can only add to it).
            fit = fit_physics(train, effect, start=start)
            start = dict(fit.values)
            fits.setdefault(terrain, {})[kind] = vars(fit)
            flags += flag_fit(f"{kind} fitted on {terrain}", fit, any_model, terrain)
            print(
                f"{kind} fitted on {terrain}: {fit.values} {fit.effects} (σ corrected {fit.std_corrected}), "
                f"reduced χ² {fit.reduced_chi2:.2f}, τ {fit.tau:.0f} samples",
                file=sys.stderr,
            )
        print(f"effective track on {terrain}: χ = {chi[terrain]:.3f}", file=sys.stderr)
    nominal = {p.name: p.off for p in any_model.nuisance}
    physics: dict[str, tuple[Mapping[str, float], Mapping[str, Mapping[str, float]]]] = {
        "nominal (config)": (nominal, {})
    }
    for terrain in terrains:
        physics[f"physics ({terrain})"] = (fits[terrain]["physics"]["values"], {})
        tr = fits[terrain]["physics + turning resistance"]
        physics[f"physics + turning resistance ({terrain})"] = (tr["values"], tr["effects"])
    track = {"kinematic (χ = 1)": 1.0, **{f"effective track ({t})": chi[t] for t in terrains}}
    scores = [score_run(model, name, terrain_of[name], physics, track) for name, model in models.items()]
    attributions: dict[str, Any] = {}
    if args.attribute > 0:
        from terrain_analysis.sim2real.attribution import attribute

        for terrain in terrains:
            # The shortest held-out runs of at least 20 s (the engine's cost grows with the run's length).
            held = sorted(
                (
                    n
                    for n in models
                    if terrain_of[n] == terrain and _split(n) == "test" and models[n].data.t[-1] >= 20.0
                ),
                key=lambda n: models[n].data.t[-1],
            )[: args.attribute]
            for name in held:
                t0 = time.monotonic()
                cropped = _cropped(models[name], args.attribute_seconds)
                report = attribute(cropped, start_nuisance=fits[terrain]["physics"]["values"])
                engine_flags = flag_engine(name, cropped, terrain, report.best, report.ranking[:3])
                flags += engine_flags
                attributions[name] = {
                    "seconds_of_data": args.attribute_seconds,
                    "verdict": report.verdict,
                    "kind": report.kind,
                    "ranking": [
                        {"effect": m.name, "shrinkage": m.shrinkage.get("overall", 0.0), "parameters": m.parameters}
                        for m in report.ranking[:3]
                    ],
                    "nominal_gaps": report.nominal_gaps[:4],
                    "baseline": verdict_baseline(cropped, report, chi[terrain]),
                    "flags": len(engine_flags),
                    "seconds": time.monotonic() - t0,
                }
                print(f"{name}: {report.verdict}", file=sys.stderr)
    result = {
        "config": {k: v for k, v in cfg.items()},
        "effective_track": chi,
        "fits": fits,
        "runs": [vars(s) for s in scores],
        "attribution": attributions,
        "flags": flags,
        "physical_ranges": {
            "friction": {**TERRAIN_FRICTION, "default": DEFAULT_FRICTION},
            "stiffness_per_load": STIFFNESS_PER_LOAD,
        },
        "seconds": time.monotonic() - started,
    }
    (out / "husky.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    page = out / "husky.md"
    if page.exists() and "<!-- begin:" not in page.read_text():
        page.unlink()  # written whole by an earlier version of this command: replaced by its section
    from terrain_analysis.reporting import write_section

    write_section(page, "husky", _markdown(result, terrains))
    _figure(models, fits, chi, terrains, out / "husky.png")
    _baseline_figure(result, terrains, out / "husky_baseline.png")
    print(f"wrote {page}, husky.json, husky.png, husky_baseline.png in {time.monotonic() - started:.0f} s")
    return 0


# ---------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------


def _compare(physics: float, baseline: float) -> str:
    if not (math.isfinite(physics) and math.isfinite(baseline)) or baseline <= 0.0:
        return "n/a"
    if physics < BEAT_RATIO * baseline:
        return "beats"
    if physics > baseline / BEAT_RATIO:
        return "worse"
    return "equal"


def baseline_comparison(result: Mapping[str, Any], terrains: Sequence[str]) -> dict[str, Any]:
    """Per terrain, the held-out runs' yaw-rate RMS of the physics fitted there against its baselines."""
    out: dict[str, Any] = {}
    for terrain in terrains:
        held = [r for r in result["runs"] if r["terrain"] == terrain and _split(r["run"]) == "test"]
        rows = []
        for r in held:
            rms = {m: v["yaw_rate"] for m, v in r["rms"].items()}
            physics = rms[f"physics ({terrain})"]
            track = rms[f"effective track ({terrain})"]
            rows.append(
                {
                    "run": r["run"],
                    "zero": rms["zero yaw rate"],
                    "kinematic": rms["kinematic (χ = 1)"],
                    "track": track,
                    "nominal": rms["nominal (config)"],
                    "physics": physics,
                    "turning": rms[f"physics + turning resistance ({terrain})"],
                    "floor": r["rate_floor"],
                    "physics_vs_track": _compare(physics, track),
                    "turning_vs_track": _compare(rms[f"physics + turning resistance ({terrain})"], track),
                    "zero_vs_physics": _compare(rms["zero yaw rate"], physics),
                    "nominal_vs_physics": _compare(rms["nominal (config)"], physics),
                    "difference": physics - track,
                }
            )
        out[terrain] = rows
    return out


def _count(rows: Sequence[Mapping[str, Any]], key: str) -> dict[str, int]:
    return {k: sum(1 for r in rows if r[key] == k) for k in ("beats", "equal", "worse")}


def interpretation(result: Mapping[str, Any], terrains: Sequence[str]) -> list[str]:
    """The written reading of the Husky section, generated from the computed figures (no number typed in)."""
    comparison = baseline_comparison(result, terrains)
    lines: list[str] = []
    for terrain in terrains:
        rows = comparison[terrain]
        if not rows:
            continue
        fit = result["fits"][terrain]
        chi = result["effective_track"][terrain]
        phys = _count(rows, "physics_vs_track")
        turn = _count(rows, "turning_vs_track")
        med = {k: float(np.median([r[k] for r in rows])) for k in ("zero", "track", "physics", "turning", "nominal")}
        diffs = [abs(r["difference"]) for r in rows]
        track = float(result["config"]["vehicle.track"])
        c_b = fit["physics + turning resistance"]["effects"].get("turning_resistance", {}).get("turning_resistance")
        plural = "s" if len(rows) != 1 else ""
        lines.append(
            f"- **{terrain}** ({len(rows)} held-out run{plural}). The Husky turns at χ = {chi:.2f} of its encoder "
            f"yaw rate (effective track B/χ = {track / chi:.2f} m for a {track:.3g} m track, fitted on the "
            "training runs). "
            f"Median held-out yaw-rate RMS: effective track {med['track']:.3f} rad/s, fitted brush "
            f"physics {med['physics']:.3f}, with turning resistance {med['turning']:.3f}, unfitted nominal "
            f"{med['nominal']:.3f}, zero yaw rate {med['zero']:.3f}. The fitted physics beats the one-parameter "
            f"baseline (RMS below {BEAT_RATIO:g}×) on {phys['beats']} of {len(rows)} runs, equals it on "
            f"{phys['equal']}, is worse on {phys['worse']} (|physics − baseline| {min(diffs):.3f}–{max(diffs):.3f} "
            f"rad/s); with turning resistance (c_b = {c_b:.2f}) it beats it on {turn['beats']}, equals it on "
            f"{turn['equal']}, is worse on {turn['worse']}."
        )
        zero_wins = [r["run"] for r in rows if r["zero_vs_physics"] == "beats"]
        if zero_wins:
            lines.append(
                f"  Predicting zero yaw rate beats the fitted physics on {', '.join(zero_wins)}: the model has no "
                "mechanism that stops the vehicle turning there."
            )
        nominal_wins = [r["run"] for r in rows if r["nominal_vs_physics"] == "beats"]
        if nominal_wins:
            lines.append(
                f"  The unfitted nominal beats the fit on {', '.join(nominal_wins)}: the training fit does not "
                "transfer to these runs."
            )
        if phys["beats"] == 0:
            lines.append(
                "  Here the tire scales act as a yaw-rate gain: the physics adds nothing measurable to the "
                "effective-track factor, and its parameters cannot be read as tire properties."
            )
    flagged = result["flags"]
    if flagged:
        subjects = sorted({f["subject"] for f in flagged})
        lines.append(
            f"- **Flags.** {len(flagged)} fitted values are at a fit bound or outside their physical range "
            f"({len(subjects)} fits; table below). A fit that needs them says the model's structure differs from "
            "the Husky's on that ground, not that the tire has these properties."
        )
    else:
        lines.append("- **Flags.** No fitted value is at a fit bound or outside its physical range.")
    for name, a in result["attribution"].items():
        b = a["baseline"]["yaw_rate"]
        verdict = {"beats": "beats", "equal": "equals", "worse": "is worse than"}.get(
            _compare(b["physics"], b["effective track"]), "cannot be compared with"
        )
        lines.append(
            f"- **Engine on {name}** ({a['kind']}, model {a['baseline']['model']}): held-out yaw-rate RMS "
            f"{b['physics']:.3f} rad/s against {b['effective track']:.3f} for the effective track and "
            f"{b['zero']:.3f} for zero: the verdict's physics {verdict} the baseline"
            + (f"; {a['flags']} of its fitted values flagged." if a["flags"] else ".")
        )
    return lines


def _markdown(result: Mapping[str, Any], terrains: Sequence[str]) -> str:
    labels = _labels(terrains)
    lines = [
        "## Real data: Husky A200 (BorealTC)",
        "",
        "Computed by `python -m terrain_analysis.sim2real.husky --data ../shared/real_data/borealtc --out "
        "docs/results/sim2real/husky --bags out/husky_bags --overwrite` (`make sim2real-real-data`); figures "
        "`husky.png`, `husky_baseline.png` by the same command.",
        "Replay of the 4-wheel skid-steer model (brush tires, quasi-static loads) on the measured side wheel",
        "speeds (6.5 Hz, interpolated), predicting the gyro yaw rate and the lateral specific force at 100 Hz.",
        "Tire scales (C_x, C_α, μ) fitted on the even-numbered runs of one terrain, alone and with the",
        "catalogue's `turning_resistance` (lateral soil resistance c_b); odd runs held out. Baselines: zero yaw",
        "rate; the kinematic yaw rate (v_R − v_L)/B; the effective-track model χ (v_R − v_L)/B with χ fitted on",
        "the same training runs (least squares).",
        "",
        "### Reading",
        "",
        *interpretation(result, terrains),
        "",
        "### Fits on the training runs",
        "",
        "Standard errors: white (independent samples) and corrected for the residual's integrated",
        "autocorrelation τ (× √τ, effective sample size n/τ).",
        "",
        "| fitted on | model | runs | C_x scale | C_α scale | μ scale | c_b | reduced χ² | τ (samples) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for terrain in terrains:
        for kind, f in result["fits"][terrain].items():
            v, s, sc = f["values"], f["std"], f["std_corrected"]
            cb = f["effects"].get("turning_resistance", {}).get("turning_resistance")
            cells = [f"{v[n]:.3g} ± {s[n]:.2g} ({sc[n]:.2g})" for n in NUISANCE_NAMES]
            cb_cell = (
                f"{cb:.3g} ± {s['turning_resistance']:.2g} ({sc['turning_resistance']:.2g})" if cb is not None else "–"
            )
            lines.append(
                f"| {terrain} | {kind} | {f['runs']} | " + " | ".join(cells) + f" | {cb_cell} | "
                f"{f['reduced_chi2']:.2f} | {f['tau']:.0f} |"
            )
    lines += [
        "",
        "Effective track χ: " + ", ".join(f"{t} {result['effective_track'][t]:.3f}" for t in terrains) + ".",
        "",
        "### Flags: fitted values at a bound or outside their physical range",
        "",
    ]
    if result["flags"]:
        lines += ["| fit | parameter | value | why |", "|---|---|---|---|"]
        for f in result["flags"]:
            value = f"{f['value']:.3g} {f['unit']}"
            lines.append(f"| {f['subject']} | {f['parameter']} ({f['quantity']}) | {value} | {f['reason']} |")
    else:
        lines.append("None.")
    lines += [
        "",
        "Physical ranges: μ per terrain "
        + ", ".join(f"{k} {lo:g}–{hi:g}" for k, (lo, hi) in TERRAIN_FRICTION.items())
        + f" (other terrains {DEFAULT_FRICTION[0]:g}–{DEFAULT_FRICTION[1]:g}); slip stiffness per unit wheel load "
        f"C_x/F_z, C_α/F_z {STIFFNESS_PER_LOAD[0]:g}–{STIFFNESS_PER_LOAD[1]:g}; effect parameters: the catalogue's "
        "ranges (`vehicle_sim.effects`). At a bound: within "
        f"{100 * BOUND_TOLERANCE:g} % of the fit range's span (an effect's own off value excepted).",
        "",
        "### Held-out runs against the baselines (yaw-rate RMS, rad/s)",
        "",
        "| terrain | run | 6.5 Hz floor | zero | effective track | nominal | physics | + turning resistance | "
        "physics vs track |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for terrain, rows in baseline_comparison(result, terrains).items():
        for r in rows:
            lines.append(
                f"| {terrain} | {r['run']} | {r['floor']:.3f} | {r['zero']:.3f} | {r['track']:.3f} | "
                f"{r['nominal']:.3f} | {r['physics']:.3f} | {r['turning']:.3f} | {r['physics_vs_track']} |"
            )
    models = labels["baselines"] + labels["physics"]
    lines += [
        "",
        "![Held-out yaw-rate RMS per run and model](husky_baseline.png)",
        "",
        "![A held-out run: gyro, encoder yaw rate, effective track and replays](husky.png)",
        "",
        "### Appendix: every run, every model (yaw-rate RMS, rad/s)",
        "",
        "`split`: train/test for the terrain's own fit; gyro/enc: least-squares ratio of gyro to encoder yaw rate;",
        "σ: noise budget; 6.5 Hz floor: RMS of the gyro minus itself sampled at the wheel-speed times and",
        "interpolated back, noise removed: what no replay driven by these reports can predict.",
        "",
        "| run | split | s | speed m/s | gyro/enc | σ | 6.5 Hz floor | " + " | ".join(models) + " |",
        "|---|---|---|---|---|---|---|" + "---|" * len(models),
    ]
    for r in result["runs"]:
        lines.append(
            f"| {r['run']} | {_split(r['run'])} | {r['seconds']:.0f} | {r['mean_speed']:.2f} | "
            f"{r['gyro_over_encoder']:.2f} | {r['sigma']['yaw_rate']:.3f} | {r['rate_floor']:.3f} | "
            + " | ".join(f"{r['rms'][m]['yaw_rate']:.3f}" for m in models)
            + " |"
        )
    if result["attribution"]:
        lines += ["", "Attribution engine on the first seconds of held-out runs (verdicts as computed):", ""]
        for name, a in result["attribution"].items():
            top = ", ".join(f"{x['effect']} ({100 * x['shrinkage']:.0f} %)" for x in a["ranking"])
            lines.append(f"- {name} (first {a['seconds_of_data']:g} s): {a['verdict']}; top: {top}")
    lines.append("")
    return "\n".join(lines)


def _figure(
    models: Mapping[str, SkidSteerReplay],
    fits: Mapping[str, Any],
    chi: Mapping[str, float],
    terrains: Sequence[str],
    path: Path,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(terrains), 1, figsize=(10, 3.2 * len(terrains)), squeeze=False)
    for ax, terrain in zip(axes[:, 0], terrains, strict=True):
        # The held-out run that turns most (straight runs show nothing of the skid-steer physics).
        held = sorted(
            (n for n in models if n.startswith(terrain) and _split(n) == "test"),
            key=lambda n: -float(np.mean(np.abs(models[n].data.omega[:, 1] - models[n].data.omega[:, 0]))),
        )
        if not held:
            continue
        model = models[held[0]]
        data = model.data
        encoder = encoder_yaw_rate(model)
        fit = fits[terrain]
        ax.plot(data.t, data.yaw_rate, lw=0.6, color="0.6", label="gyro (measured)")
        ax.plot(data.t, encoder, lw=0.8, label="encoder yaw rate (no slip)")
        ax.plot(data.t, chi[terrain] * encoder, lw=1.0, label=f"effective track χ = {chi[terrain]:.2f}")
        ax.plot(data.t, model.predict({}, fit["physics"]["values"])["yaw_rate"], lw=1.0, label="replay, physics")
        tr = fit["physics + turning resistance"]
        ax.plot(
            data.t,
            model.predict(tr["effects"], tr["values"])["yaw_rate"],
            lw=1.0,
            ls="--",
            label="replay, physics + turning resistance",
        )
        ax.set_title(f"{held[0]} (held out; fits on {terrain} training runs)")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("yaw rate (rad/s)")
        ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _baseline_figure(result: Mapping[str, Any], terrains: Sequence[str], path: Path) -> None:
    """Grouped bars: held-out yaw-rate RMS per run of zero, effective track, physics, physics + turning resistance."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    comparison = baseline_comparison(result, terrains)
    keys = (
        ("zero", "zero yaw rate"),
        ("track", "effective track χ"),
        ("nominal", "nominal physics"),
        ("physics", "fitted physics"),
        ("turning", "physics + turning resistance"),
    )
    fig, axes = plt.subplots(len(terrains), 1, figsize=(10, 3.0 * len(terrains)), squeeze=False)
    for ax, terrain in zip(axes[:, 0], terrains, strict=True):
        rows = comparison[terrain]
        x = np.arange(len(rows))
        width = 0.8 / len(keys)
        for k, (key, label) in enumerate(keys):
            ax.bar(x + (k - 2) * width, [r[key] for r in rows], width, label=label)
        ax.plot(x, [r["floor"] for r in rows], "k_", ms=18, label="6.5 Hz floor")
        ax.set_xticks(x, [r["run"].split("/")[-1] for r in rows])
        ax.set_ylabel("yaw-rate RMS (rad/s)")
        ax.set_title(f"{terrain}: held-out runs (fits and χ on its training runs)")
        ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
