"""The quarter car's and LRV's "where" alone: open-loop replay of the nominal plant on a bag.

The nominal quarter car (2-DOF) or LRV (1-DOF) of
:mod:`vehicle_sim.plants.quarter_car` is driven by the bag's *measured*
profile (``terrain/profile``, elevation against time at its own rate) with the
vehicle parameters of the config file and the soil stiffness the estimator
converges to on the same bag (a real bag has no ground truth). The plant is
linear, so the replay is the exact first-order-hold solution
(:func:`scipy.signal.lsim`) of the paper's equations (eq. 2; MODELS.md A.7),
started at rest at the first road height, as the simulator starts.

The simulated specific forces are compared with ``imu/body`` and ``imu/wheel``
at the accelerometer stamps: residual bias and RMS against the noise budget
(the config's R plus what the profile sensor's noise does to the replay), the
ratio of residual to noise power and of measured to simulated power per octave
band, the coherence and the delay between measured and simulated signals, the
residual RMS per time window and per speed bin, and the estimator's NIS
(mean against its χ² band and autocorrelation at lags 1..10); the tests are
those of :mod:`~terrain_analysis.sim2real.where`. The full diagnosis (with the
attribution) is :func:`~terrain_analysis.sim2real.diagnose.diagnose`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from terrain_analysis.sim2real.model import StampOrigin
from terrain_analysis.sim2real.where import (
    ChannelReport,
    NisReport,
    RegimeStat,
    Sim2RealError,
    WhereSettings,
    _channel,
    _jsonable,
    _nis_report,
    _regimes,
    despike,
    regime_gaps,
    time_windows,
)
from terrain_estimation.bag import read_bag
from terrain_estimation.params import ParamValue
from terrain_estimation.tools.estimate import estimate_bag, topic_name
from terrain_estimation.vehicles import estimator_parameters, get_vehicle

__all__ = ["SUPPORTED_VEHICLES", "WhereReport", "diagnose_where", "replay_nominal"]

SUPPORTED_VEHICLES = ("quarter_car", "lrv")

FloatArray = NDArray[np.float64]


@dataclass
class WhereReport:
    """Result of :func:`diagnose_where` (``to_dict()`` is JSON-serialisable)."""

    bag: str
    vehicle: str
    namespace: str
    duration: float
    k_s: float
    k_s_source: str
    noise_variance: float
    mean_speed: float
    channels: list[ChannelReport]
    windows: list[RegimeStat]
    speed_bins: list[RegimeStat]
    nis: NisReport | None
    verdict: str
    gaps: list[str]
    settings: WhereSettings
    notes: list[str] = field(default_factory=list)
    # Time series for the figures (not in to_dict()).
    series: dict[str, FloatArray] = field(default_factory=dict, repr=False)

    @property
    def significant_gap(self) -> bool:
        return bool(self.gaps)

    def channel(self, name: str) -> ChannelReport:
        for ch in self.channels:
            if ch.name == name:
                return ch
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in asdict(self).items() if k != "series"}
        return _jsonable(out)


# ---------------------------------------------------------------------------
# Reading the bag
# ---------------------------------------------------------------------------


@dataclass
class _BagData:
    body_t: FloatArray
    body: FloatArray
    wheel_t: FloatArray | None
    wheel: FloatArray | None
    joint_t: FloatArray
    speed: FloatArray
    profile_t: FloatArray
    profile_x: FloatArray
    profile_z: FloatArray


def _open(
    bag: str | Path, vehicle: str, namespace: str | None, config: str | Path | None, say: Callable[[str], None]
) -> tuple[str, dict[str, ParamValue], _BagData]:
    """The bag's namespace, the vehicle's estimator parameters and the bag's streams (quarter car or LRV)."""
    entry = get_vehicle(vehicle)
    ns = namespace if namespace is not None else entry.namespace
    values = estimator_parameters(entry, config)
    say(f"reading {bag} ({vehicle}, namespace {ns})")
    return ns, values, _read(bag, ns, vehicle == "quarter_car", float(values["vehicle.wheel_radius"]))


def _read(bag: str | Path, namespace: str, two_dof: bool, wheel_radius: float) -> _BagData:
    names = {
        "body": topic_name(namespace, "imu/body"),
        "joint": topic_name(namespace, "joint_states"),
        "profile": topic_name(namespace, "terrain/profile"),
    }
    if two_dof:
        names["wheel"] = topic_name(namespace, "imu/wheel")
    by_topic = {v: k for k, v in names.items()}
    data: dict[str, list[tuple[float, ...]]] = {k: [] for k in names}
    clock = StampOrigin()  # seconds from the first stamp: epoch stamps lose precision as floats
    for item in read_bag(bag, list(by_topic)):
        key = by_topic[item.topic]
        msg = item.msg
        if key in ("body", "wheel"):
            data[key].append((clock(msg), float(msg.linear_acceleration.z)))
        elif key == "profile":
            data[key].append((clock(msg), float(msg.point.x), float(msg.point.z)))
        else:
            names_ = list(msg.name)
            if "wheel" not in names_ or len(msg.velocity) <= names_.index("wheel"):
                continue
            data[key].append((clock(msg), float(msg.velocity[names_.index("wheel")]) * wheel_radius))
    for key, topic in names.items():
        if len(data[key]) < 2:
            what = "has no messages on" if not data[key] else "has a single message on"
            extra = " (joint 'wheel' with a velocity)" if key == "joint" else ""
            raise Sim2RealError(
                f"bag {str(bag)!r} {what} {topic}{extra}, which the sim-to-real diagnosis needs "
                f"(namespace {namespace!r}; pass --namespace if the bag was recorded under another one)"
            )

    def arr(key: str) -> FloatArray:
        a = np.array(data[key], dtype=float)
        return a[np.argsort(a[:, 0], kind="stable")]

    body, joint, prof = arr("body"), arr("joint"), arr("profile")
    wheel = arr("wheel") if two_dof else None
    return _BagData(
        body_t=body[:, 0],
        body=body[:, 1],
        wheel_t=None if wheel is None else wheel[:, 0],
        wheel=None if wheel is None else wheel[:, 1],
        joint_t=joint[:, 0],
        speed=joint[:, 1],
        profile_t=prof[:, 0],
        profile_x=prof[:, 1],
        profile_z=prof[:, 2],
    )


# ---------------------------------------------------------------------------
# Open-loop replay of the nominal plant
# ---------------------------------------------------------------------------


def _savgol(n: int, order: int, deriv: int, dt: float) -> FloatArray:
    return np.asarray(signal.savgol_coeffs(n, order, deriv=deriv, delta=dt, use="dot"), dtype=float)


def _odd(n: int, minimum: int) -> int:
    n = max(int(n), minimum)
    return n if n % 2 else n + 1


def replay_nominal(
    values: Mapping[str, Any],
    k_s: float,
    t: FloatArray,
    h: FloatArray,
    h_rate: FloatArray,
) -> tuple[FloatArray, FloatArray | None]:
    """Nominal plant's accelerations (ÿ1, ÿ2 or None) on the road h(t), ḣ(t).

    ``values`` are the estimator parameters (``vehicle.*`` of the config);
    ``t`` a uniform, increasing grid. Exact linear (first-order hold) solution
    from rest at h(t[0]), as :class:`~vehicle_sim.plants.quarter_car.QuarterCarSimulator`.
    """
    kind = str(values["vehicle.kind"])
    m1 = float(values["vehicle.sprung_mass"])
    k = float(values["vehicle.suspension_stiffness"])
    c = float(values["vehicle.suspension_damping"])
    if kind == "quarter_car":
        m2 = float(values["vehicle.unsprung_mass"])
        k_t = float(values["vehicle.tire_stiffness"])
        kt = k_t * k_s / (k_t + k_s)
        a = np.array(
            [
                [0.0, 1.0, 0.0, 0.0],
                [-k / m1, -c / m1, k / m1, c / m1],
                [0.0, 0.0, 0.0, 1.0],
                [k / m2, c / m2, -(k + kt) / m2, -c / m2],
            ]
        )
        b = np.array([[0.0], [0.0], [0.0], [kt / m2]])
        cm = a[[1, 3], :]
        d = b[[1, 3], :]
        x0 = np.array([h[0], 0.0, h[0], 0.0])
        u: FloatArray = h[:, None]
    else:
        kt = k * k_s / (k + k_s)
        ground = str(values.get("vehicle.damper_reference", "ground")) == "ground"
        a = np.array([[0.0, 1.0], [-kt / m1, -c / m1]])
        b = np.array([[0.0, 0.0], [kt / m1, c / m1 if ground else 0.0]])
        cm = a[[1], :]
        d = b[[1], :]
        x0 = np.array([h[0], 0.0])
        u = np.column_stack([h, h_rate])
    system = signal.StateSpace(a, b, cm, d)
    _, y, _ = signal.lsim(system, u, t - t[0], X0=x0, interp=True)
    y = np.asarray(y, dtype=float).reshape(len(t), -1)
    return y[:, 0], (y[:, 1] if y.shape[1] > 1 else None)


# ---------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------


def diagnose_where(
    bag: str | Path,
    vehicle: str,
    namespace: str | None = None,
    config: str | Path | None = None,
    *,
    settings: WhereSettings | None = None,
    k_s: float | None = None,
    progress: bool = False,
) -> WhereReport:
    """Open-loop replay of the nominal plant on ``bag`` and where it disagrees.

    Args:
        bag: rosbag2 directory following CONTRACT.md.
        vehicle: ``quarter_car`` or ``lrv``.
        namespace: Namespace the bag was recorded under (default: the vehicle's).
        config: Parameter file (default: ``config/<vehicle>.yaml``).
        settings: Analysis settings (default :class:`WhereSettings`).
        k_s: Soil stiffness for the replay (N/m); default: the estimator's
            final estimate over the same bag.
        progress: Progress lines on stderr.

    Raises:
        Sim2RealError: unsupported vehicle, missing topic, too little data.
        BagError: unreadable bag.
    """
    settings = settings or WhereSettings()
    if vehicle not in SUPPORTED_VEHICLES:
        raise Sim2RealError(f"sim-to-real 'where' supports {', '.join(SUPPORTED_VEHICLES)}, not {vehicle!r}")

    def say(text: str) -> None:
        if progress:
            print(f"sim2real: {text}", file=sys.stderr)

    ns, values, data = _open(bag, vehicle, namespace, config, say)
    two_dof = vehicle == "quarter_car"
    gravity = float(values["estimator.gravity"])
    r_var = float(values["filter.accel_noise_variance"])
    sigma_h = float(values["estimator.profile_noise_std"])
    notes: list[str] = []

    say("running the estimator over the bag (soil stiffness for the replay, NIS)")
    run = estimate_bag(bag, vehicle, namespace=ns, config=config)
    estimates = run.messages(topic_name(ns, "soil_stiffness"))
    nis = _nis_report(estimates, 2 if two_dof else 1, float(values["diagnostics.nis_probability"]))
    if k_s is not None:
        k_s_used, source = float(k_s), "given"
    elif estimates:
        converged = [m for m in estimates if m.converged]
        pick = converged[-1] if converged else estimates[-1]
        k_s_used = float(pick.k_s)
        source = "estimator (final converged estimate)" if converged else "estimator (final estimate, NOT converged)"
        if not converged:
            notes.append("the estimator never converged on this bag: the replay's k_s is uncertain")
    else:
        raise Sim2RealError(f"the estimator produced no {topic_name(ns, 'soil_stiffness')} estimate on {bag}")

    # Road on the profile's own (assumed uniform) time grid.
    tp, zp = data.profile_t, data.profile_z
    keep = np.concatenate([[True], np.diff(tp) > 0.0])
    tp, zp = tp[keep], zp[keep]
    dt_p = float(np.median(np.diff(tp)))
    grid = np.arange(tp[0], tp[-1] + 0.5 * dt_p, dt_p)
    h_raw = np.interp(grid, tp, zp)
    n_h = _odd(settings.profile_smoothing, 1)
    if n_h >= 3:
        coeffs = _savgol(n_h, 2, 0, dt_p)
        h = np.asarray(signal.savgol_filter(h_raw, n_h, 2, mode="interp"), dtype=float)
    else:
        coeffs = np.array([1.0])
        h = h_raw
    speed_mean = float(np.mean(np.abs(data.speed))) or 1.0
    hdot_window = float(values.get("estimator.hdot_window", 0.06)) or 0.06
    # ḣ (LRV ground damper): cubic Savitzky-Golay slope over half the estimator's hdot_window of road.
    n_d = _odd(round(0.5 * hdot_window / speed_mean / dt_p), 7)
    po = 3
    h_rate = np.asarray(signal.savgol_filter(h_raw, n_d, po, deriv=1, delta=dt_p, mode="interp"), dtype=float)
    d_coeffs = _savgol(n_d, po, 1, dt_p)

    # Noise budget: R plus the profile sensor's noise through the replay's direct feed-through.
    m1 = float(values["vehicle.sprung_mass"])
    k = float(values["vehicle.suspension_stiffness"])
    c = float(values["vehicle.suspension_damping"])
    if two_dof:
        kt_ser = float(values["vehicle.tire_stiffness"])
        kt = kt_ser * k_s_used / (kt_ser + k_s_used)
        feed = {
            "body": 0.0,
            "wheel": (kt / float(values["vehicle.unsprung_mass"])) ** 2 * sigma_h**2 * float(np.sum(coeffs**2)),
        }
    else:
        kt = k * k_s_used / (k + k_s_used)
        ground = str(values.get("vehicle.damper_reference", "ground")) == "ground"
        feed = {
            "body": (kt / m1) ** 2 * sigma_h**2 * float(np.sum(coeffs**2))
            + ((c / m1) ** 2 * sigma_h**2 * float(np.sum(d_coeffs**2)) if ground else 0.0)
        }

    say(f"replaying the nominal plant open loop (k_s = {k_s_used:.4g} N/m, {len(grid)} road samples)")
    a1, a2 = replay_nominal(values, k_s_used, grid, h, h_rate)

    channels_raw: list[tuple[str, str, FloatArray, FloatArray, FloatArray]] = [
        ("body", topic_name(ns, "imu/body"), data.body_t, data.body, a1)
    ]
    if two_dof and data.wheel_t is not None and data.wheel is not None and a2 is not None:
        channels_raw.append(("wheel", topic_name(ns, "imu/wheel"), data.wheel_t, data.wheel, a2))

    t_start = grid[0] + settings.warmup
    channels: list[ChannelReport] = []
    residuals: dict[str, FloatArray] = {}
    noise_vars: dict[str, float] = {}
    series: dict[str, FloatArray] = {}
    t_ref: FloatArray | None = None
    for name, topic, t_m, y_m, acc in channels_raw:
        sel = (t_m >= t_start) & (t_m <= grid[-1])
        if np.sum(sel) < 64:
            raise Sim2RealError(
                f"{topic}: only {int(np.sum(sel))} samples overlap the profile after the {settings.warmup} s "
                "warm-up; the diagnosis needs at least 64 (about a second)"
            )
        t_s = t_m[sel]
        meas = y_m[sel]
        sim = np.interp(t_s, grid, acc) + gravity
        fs = 1.0 / float(np.median(np.diff(t_s)))
        noise_var = r_var + feed[name]
        noise_vars[name] = noise_var
        say(f"analysing {topic} ({len(t_s)} samples at {fs:.0f} Hz)")
        channels.append(_channel(name, topic, meas, sim, fs, noise_var, settings, len(channels_raw)))
        residuals[name] = despike(meas, sim, settings)[0] - sim
        series[f"{name}_t"] = t_s
        series[f"{name}_measured"] = meas
        series[f"{name}_simulated"] = sim
        if t_ref is None:
            t_ref = t_s
    assert t_ref is not None
    # Regimes on the body stamps (the wheel channel, if any, interpolated onto them).
    res_on_ref = {
        name: (residuals[name] if name == "body" else np.interp(t_ref, series[f"{name}_t"], residuals[name]))
        for name in residuals
    }
    speed_ref = np.interp(t_ref, data.joint_t, data.speed)
    win_labels = time_windows(t_ref, float(t_ref[0]), grid[0], settings.window)
    n_tests = len(res_on_ref) * len(win_labels)
    windows = _regimes(win_labels, res_on_ref, noise_vars, settings, n_tests)
    bins = np.floor(np.abs(speed_ref) / settings.speed_bin)
    speed_labels = []
    for b in np.unique(bins):
        lo, hi = float(b * settings.speed_bin), float((b + 1) * settings.speed_bin)
        speed_labels.append((f"{lo:g}–{hi:g} m/s", lo, hi, bins == b))
    speed_bins = _regimes(speed_labels, res_on_ref, noise_vars, settings, len(res_on_ref) * len(speed_labels))

    gaps = [g for ch in channels for g in ch.gaps]
    gaps += regime_gaps("window ", windows) + regime_gaps("speed ", speed_bins)
    if nis is not None and nis.updates:
        nis_probability = float(values["diagnostics.nis_probability"])
        if not nis.in_band:
            gaps.append(
                f"estimator NIS: mean {nis.mean:.2f} outside its {100 * nis_probability:.0f} % "
                f"χ² band [{nis.band[0]:.2f}, {nis.band[1]:.2f}] (dim {nis.dim})"
            )
        if not nis.white:
            notes.append("the estimator's NIS sequence is autocorrelated (more than one lag of 1..10 beyond ±2/√N)")
    for ch in channels:
        if abs(ch.delay) >= 0.5 / 100.0 and any(b.gap for b in ch.bands):
            notes.append(f"{ch.name}: measured lags the replay by {1000 * ch.delay:.1f} ms (cross-correlation peak)")
    verdict = "no significant gap" if not gaps else "gap: " + "; ".join(gaps)
    duration = float(grid[-1] - grid[0])
    return WhereReport(
        bag=str(bag),
        vehicle=vehicle,
        namespace=ns,
        duration=duration,
        k_s=k_s_used,
        k_s_source=source,
        noise_variance=r_var,
        mean_speed=speed_mean,
        channels=channels,
        windows=windows,
        speed_bins=speed_bins,
        nis=nis,
        verdict=verdict,
        gaps=gaps,
        settings=settings,
        notes=notes,
        series=series,
    )
