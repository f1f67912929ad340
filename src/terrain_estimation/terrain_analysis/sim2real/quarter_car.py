"""Replay model of a quarter-car (2-DOF) or LRV (1-DOF) bag, with every catalogue effect.

The nominal plant of :mod:`vehicle_sim.plants.quarter_car` (MODELS.md A.1, A.7)
is driven by the bag's measured road (``terrain/profile``) on the profile's own
time grid, integrated by RK4 at that step (JIT-compiled), from rest at the
first road height. Its body (and wheel) specific forces are compared with
``imu/body`` (and ``imu/wheel``) at the accelerometer stamps.

Road input
    * Quarter car: Savitzky–Golay smoothed as in :mod:`~terrain_analysis.sim2real.where`.
    * LRV: the conditional mean of the road given the profile, E[h | profile]
      and E[ḣ | profile] (non-causal Wiener smoother, :func:`_wiener_road`).
      Its ground damper puts c/m = 20 s⁻¹ on the road *rate*, so the replay's
      error is that of the estimated ḣ (errors in variables). A fixed smoothing
      window leaves an error that is correlated with the profile, which an
      input filter (``tire_enveloping``) or a gain (``sprung_mass_change``)
      then partly removes on a bag without any effect. With the conditional
      mean the replay of the linear plant is E[ÿ | profile]: its error is
      orthogonal to every function of the profile, so no effect acting on
      the road can reduce it; what remains is a known noise (the budget).
      The road spectrum S is the profile's own (Welch, median-smoothed over a
      relative bandwidth) less the sensor's white floor N = 2 σ_h² Δt; the
      gain is S / (S + N), the rate its spectral derivative. The accelerometer
      is never used to estimate the road.

Nuisance parameter
    ``ln_k_s``: the soil stiffness k_s (N/m) is what the vehicle's estimator is
    for and no real bag gives it, so it is fitted in every model, the nominal
    one included, starting from the estimator's final estimate. An effect that
    biases the estimator's k_s is then not mistaken for a gap everywhere.

Effects (:data:`vehicle_sim.effects.CATALOGUE`, same physics as the plant)
    * ``accel_bias``, ``accel_scale``: reading = (1 + s)(ÿ + g) + b per channel;
    * ``sensor_delay``: one latency per stream; each accelerometer's
      prediction is shifted by its latency less the profile's (linear
      interpolation of the replay's fine grid); see :func:`_candidates`.
      The fit starts from a least-squares scan of the shift per
      accelerometer (:meth:`QuarterCarReplay._scan_delays`, 2.5 ms steps):
      against a broadband ride signal the cost minimum of a delay is a few ms
      wide, which no coarse grid finds. Accelerometer samples in the last
      :data:`RELATIVE_DELAY_BOUND` s are left out of every fit (``valid``):
      with a late profile they have no road input;
    * ``nonlinear_soil``: the soil's curvature about the static point, an
      exponential-stiffness law with stiffness k_s there (the nuisance)
      (:func:`~terrain_analysis.sim2real.quarter_car_kernel._chain_force`, :func:`_candidates`), in series with the tire
      (LRV: combined) spring, solved per stage by safeguarded Newton in the
      soil's own compression (the plant's Bekker-type law, solved for the
      force, is a separate implementation);
    * ``wheel_liftoff``: total ground force W + F_d ≥ 0;
    * ``suspension_friction``: F_c tanh(Δv / v_f), v_f = 0.02 m/s (2-DOF);
    * ``tire_damping``: c_t (ḣ − ẏ2) in parallel with the tire–soil chain (2-DOF);
    * ``tire_enveloping``: the road seen through a contact patch of length L,
      the tandem (two-cam) form of Schmeitz and Pacejka (Pacejka, *Tire and
      Vehicle Dynamics*, 3rd ed., § 10.2): two cams a base ρL apart, each the
      mean over (1 − ρ)L, averaged (over distance, from the profile's own x).
      ``tire_tandem_ratio`` ρ runs from the mean over the patch (0, the
      catalogue's form) to the two-point follower (1); both ends are laws
      of the family (:attr:`FitParameter.physical_bounds`), and the fit
      starts from the two-point follower too (:attr:`Candidate.starts`);
    * ``sprung_mass_change``: m_s (1 + x), the static load W with it.

Noise budget per channel: the config's accelerometer variance R plus what
the profile sensor's noise (``estimator.profile_noise_std``) does through the
replay (quarter-car wheel channel: k_tot/m_2 times the smoothed noise; LRV
body: the road's posterior error N·S/(S + N) through the body's transfer
function ÿ/h, with the effect's mass, soil stiffness, contact length and scale).

Not identifiable from a bag (reported, not fitted): a latency common to all
streams (only differences show), and a profile-sensor gain, which scales both
accelerometers like equal ``accel_scale`` errors (the suite's out-of-catalogue
``channel_scale`` case).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal, stats

from terrain_analysis.sim2real.model import Candidate, Channel, FitParameter, candidates_from_catalogue
from terrain_analysis.sim2real.open_loop import _odd, _open, _savgol
from terrain_analysis.sim2real.quarter_car_kernel import _simulate
from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.tools.estimate import topic_name

__all__ = ["QuarterCarReplay", "build_model"]

FloatArray = NDArray[np.float64]

RELATIVE_DELAY_BOUND = 0.35  # s: fit bound of the latency of an accelerometer relative to the profile (either sign)
SOIL_STIFFENING_BOUNDS = (-4.0, 4.0)  # a of the soil law (Bekker n 0.3–3, ζ ≥ 0.2: |a| ≤ 4 mostly)
SOIL_SHAPE_BOUNDS = (-20.0, 20.0)  # λ = 1/(n − 1) of the soil law (Bekker n outside 0.95–1.05)
DELAY_SCAN_STEP = 0.0025  # s: step of the latency scan that starts the sensor_delay fit
ROAD_PSD_SEGMENT = 1024  # samples per Welch segment of the road spectrum (1 Hz bins at 1 kHz)
ROAD_PSD_BANDWIDTH = 0.05  # relative half-width of the running median over frequency (road spectra are smooth in log f)


def _candidates(vehicle: str) -> dict[str, Candidate]:
    """The catalogue's candidates, with the latencies and the soil in the replay's own parameters.

    * ``sensor_delay``: a bag shows only differences between streams: an
      accelerometer's prediction is shifted by its latency less the
      profile's. LRV: one parameter, ``delay_body``, the body accelerometer's
      latency relative to the profile, in ±:data:`RELATIVE_DELAY_BOUND`
      (negative: the profile is the late stream). Quarter car: one latency
      per stream, ``delay_body``, ``delay_wheel``, ``delay_profile``, each in
      ±:data:`RELATIVE_DELAY_BOUND`, so that a latency on any one stream, or
      one common to both accelerometers (= −``delay_profile``), is a move of
      one parameter from the nominal model (the fit's starts move one
      parameter at a time). A latency common to all three streams is
      invisible: the fitted values are one of a family (add the same x to
      all three); only the differences are reported as found. The
      catalogue's per-stream latencies map to d_c + d_common − d_profile.
    * ``nonlinear_soil``: the power-law family about the static point in
      regular coordinates, stiffness k_s (1 + λ a u)^(1/λ), u = δ/z₀ (k_s the
      ln k_s nuisance, the stiffness at the static point; :func:`_soil_force`):
      ``soil_stiffening`` a, the curvature (stiffening a > 0 / softening
      a < 0 under extra load), and ``soil_shape`` λ, the higher orders
      (0: exponential). The catalogue's Bekker-type law (n, ζ) is
      a = (n − 1)/(n ζ), λ = 1/(n − 1). Fitted as (n, ζ), the pair slides
      along a valley to n's bound (a true n = 1.5, ζ = 0.7 came back as
      n = 3 with the right curvature: the higher orders are weakly
      identified at ride amplitudes); in (a, λ) that valley ends inside the
      range (n → ∞ is λ = 0) and a is well determined. Solved in the soil's
      compression, not the force as the plant does: a separate implementation.
    """

    out = candidates_from_catalogue(vehicle)
    if "tire_enveloping" in out:
        length = out["tire_enveloping"].parameters[0]
        out["tire_enveloping"] = Candidate(
            "tire_enveloping",
            (
                length,
                FitParameter("tire_tandem_ratio", "–", 0.0, (0.0, 1.0), 0.5, physical_bounds=True),
            ),
            "the road seen through the contact patch: two cams a base ρL apart, each the mean over (1 − ρ)L, "
            "averaged (L the contact length; ρ = 0 the mean over the patch, ρ = 1 the two-point follower)",
            starts=(((length.name, length.scale), ("tire_tandem_ratio", 1.0)),),
        )
    streams = ("body", "wheel", "profile") if vehicle == "quarter_car" else ("body",)
    bound = RELATIVE_DELAY_BOUND
    out["sensor_delay"] = Candidate(
        "sensor_delay",
        tuple(FitParameter(f"delay_{s}", "s", 0.0, (-bound, bound), 0.02) for s in streams),
        "latency of each sensor stream; an accelerometer's prediction is shifted by its latency less the "
        "profile's (only differences between streams are observable)",
    )
    out["nonlinear_soil"] = Candidate(
        "nonlinear_soil",
        (
            FitParameter("soil_stiffening", "–", 0.0, SOIL_STIFFENING_BOUNDS, 0.5),
            FitParameter("soil_shape", "–", 0.0, SOIL_SHAPE_BOUNDS, 1.0),
        ),
        "soil stiffness k_s (1 + λ a u)^(1/λ), u = δ/z0, about the static point (a > 0 stiffening, a < 0 "
        "softening under extra load; λ the law's higher orders, 0 exponential; Bekker's law with exponent n and "
        "origin ratio ζ: a = (n − 1)/(n ζ), λ = 1/(n − 1))",
    )
    return out


#: Soil stiffness (N/m) the ln k_s nuisance may always reach, whatever its start: 10 MN/m, 4x a compacted sand's
#: (LETE, 2.3 MN/m) and far beyond a tire's stiffness.
SOIL_STIFFNESS_MAX = 1.0e7


def _soil_nuisance(k_s: float) -> FitParameter:
    """The ln k_s nuisance started at ``k_s`` (N/m): a factor 30 either side, and up to at least
    :data:`SOIL_STIFFNESS_MAX`.

    Its start is the onboard estimator's final k_s, which a sensor effect throws far off, and low: a lag
    between the profile and the accelerometers decorrelates the road from the wheel's motion, which the
    estimator can only explain by a softer soil filtering the road (a profile 38 ms late gave 2.5 kN/m for
    a 651 kN/m soil, outside a range of 30x about it). The range is not widened below the start: the
    nominal fit of such a bag runs the soil soft to absorb the lag, and a deeper floor only lets it run
    further (the per-stream delay fits then start from a worse nominal model).
    """
    ln = math.log(k_s)
    return FitParameter(
        "ln_k_s", "ln(N/m)", ln, (ln - math.log(30.0), max(ln + math.log(30.0), math.log(SOIL_STIFFNESS_MAX))), 0.2
    )


def _periodic(x: FloatArray) -> tuple[FloatArray, float, FloatArray]:
    """(ramp, slope per sample, odd periodic extension of x − ramp): no jump in value or slope at the ends."""
    n = x.size
    slope = float(x[-1] - x[0]) / (n - 1)
    ramp = x[0] + slope * np.arange(n)
    d = x - ramp
    return ramp, slope, np.concatenate([d, -d[-2:0:-1]])


def _spectral(
    x: FloatArray, dt: float, gain: Callable[[FloatArray], FloatArray] | None
) -> tuple[FloatArray, FloatArray]:
    """(G x, d/dt (G x)) of a signal on a uniform grid, G a zero-phase gain of frequency (None: 1)."""
    n = x.size
    ramp, slope, ext = _periodic(x)
    spec = np.fft.rfft(ext)
    f = np.asarray(np.fft.rfftfreq(ext.size, dt), dtype=float)
    if gain is not None:
        spec = spec * gain(f)
    rate_spec = 2j * np.pi * f * spec
    if ext.size % 2 == 0:
        rate_spec[-1] = 0.0  # the Nyquist bin has no defined derivative
    value = ramp + np.fft.irfft(spec, ext.size)[:n]
    rate = slope / dt + np.fft.irfft(rate_spec, ext.size)[:n]
    return np.asarray(value, dtype=float), np.asarray(rate, dtype=float)


def _wiener_road(raw: FloatArray, dt: float, sigma_h: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(frequencies, Wiener gain S/(S+N), bin widths) of the road seen through white profile noise σ_h.

    S: the profile's Welch spectrum P (linear detrend, Hann, 50 % overlap)
    with a running median over ±:data:`ROAD_PSD_BANDWIDTH` of each frequency
    (at least ±2 bins; a median keeps the road's band edge sharp), less the
    white floor N = 2 σ_h² Δt (one-sided). A bin counts as road only where
    P exceeds N significantly (one-sided 1 % χ² bound for the smoothed
    estimate's degrees of freedom): above the road's band edge P scatters
    about N, and a gain fitted to that scatter would pass noise (weighted by
    ω² through the damper) while the budget charged it as road.
    """
    _, _, ext = _periodic(raw)
    d = ext[: raw.size]
    nper = int(min(ROAD_PSD_SEGMENT, d.size))
    f, p = signal.welch(d, fs=1.0 / dt, nperseg=nper, detrend="linear")
    n_seg = max(1, (d.size - nper) // (nper // 2) + 1)
    smooth = np.empty_like(p)
    bins = np.empty_like(p)
    for i, fi in enumerate(f):
        half = max(ROAD_PSD_BANDWIDTH * fi, 2.0 * (f[1] - f[0]))
        lo, hi = np.searchsorted(f, fi - half), np.searchsorted(f, fi + half, side="right")
        smooth[i] = np.median(p[lo:hi])
        bins[i] = hi - lo
    floor = 2.0 * sigma_h**2 * dt
    if floor <= 0.0:
        return np.asarray(f, dtype=float), np.ones_like(p, dtype=float), np.full(f.size, float(f[1] - f[0]))
    # Degrees of freedom as in where._band_stats (Hann, 50 % overlap: ~0.9 of 2 per bin and
    # segment, neighbouring bins worth 1/1.5), a median worth 2/π of a mean.
    dof = np.maximum(2.0, 2.0 * 0.9 * n_seg * bins / 1.5 * (2.0 / np.pi))
    bound = stats.chi2.ppf(0.99, dof) / dof
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(smooth > bound * floor, 1.0 - floor / smooth, 0.0)
    gain = np.nan_to_num(gain, nan=0.0)
    return np.asarray(f, dtype=float), np.asarray(gain, dtype=float), np.full(f.size, float(f[1] - f[0]))


class QuarterCarReplay:
    """:class:`~terrain_analysis.sim2real.model.ReplayModel` of one quarter-car / LRV bag."""

    def __init__(
        self,
        vehicle: str,
        values: Mapping[str, Any],
        grid: FloatArray,
        h: FloatArray,
        h_rate: FloatArray,
        distance: FloatArray,
        channels: list[tuple[Channel, FloatArray, FloatArray]],
        speed: tuple[FloatArray, FloatArray],
        k_s: float,
        smooth: Callable[[FloatArray], tuple[FloatArray, FloatArray]],
        warmup: float,
        notes: list[str],
        noise: tuple[float, float, float, float],
        road_error: tuple[FloatArray, FloatArray, FloatArray] | None = None,
        speed_mean: float = 1.0,
    ) -> None:
        self.vehicle = vehicle
        self.two_dof = vehicle == "quarter_car"
        self._values = dict(values)
        self._t0 = float(grid[0])
        self._grid = grid - self._t0
        self._dt = float(self._grid[1] - self._grid[0])
        self._h, self._hd = h, h_rate
        self._distance = distance
        self._smooth = smooth
        self.channels = [c for c, _, _ in channels]
        self.times = {c.name: t - self._t0 for c, t, _ in channels}
        self.measured = {c.name: y for c, _, y in channels}
        self.regimes = {"speed (m/s)": (speed[0] - self._t0, speed[1])}
        self.warmup = warmup
        self.notes = notes
        self.gravity = float(values["estimator.gravity"])
        self.k_s_start = k_s
        self.nuisance = [_soil_nuisance(k_s)]
        self.candidates: dict[str, Candidate] = _candidates(vehicle)
        # Samples a profile delayed by up to the fit bound would leave without road input are left out.
        self.max_relative_delay = RELATIVE_DELAY_BOUND
        self.valid = {c.name: self.times[c.name] <= float(self._grid[-1]) - RELATIVE_DELAY_BOUND for c in self.channels}
        self._envelope_cache: dict[tuple[float, float], tuple[FloatArray, FloatArray]] = {}
        # (R, σ_h² of the profile, Σ smoothing², Σ derivative²): the noise budget's pieces.
        self._noise = noise
        # LRV: (frequencies, posterior error density of the road N·S/(S+N), bin widths).
        self._road_error = road_error
        self._speed_mean = speed_mean
        self.channels = [Channel(c.name, c.topic, c.unit, self.noise_std_for({}, {})[c.name]) for c in self.channels]
        self._last_grid_accelerations: tuple[FloatArray, FloatArray] | None = None
        self.delay_scan = self._scan_delays()
        # Each latency's start offset: its own scan; the profile's: minus the best common shift of both.
        starts = dict(self.delay_scan)
        if self.two_dof:
            starts["profile"] = -starts.pop("common")
        self.candidates["sensor_delay"] = Candidate(
            "sensor_delay",
            tuple(
                FitParameter(p.name, p.unit, p.off, p.bounds, max(abs(starts[p.name[len("delay_") :]]), 0.01))
                for p in self.candidates["sensor_delay"].parameters
            ),
            self.candidates["sensor_delay"].description,
        )
        self.notes.append(
            "latency scan of the nominal replay against each accelerometer (least squares over the shift, "
            f"{DELAY_SCAN_STEP * 1e3:g} ms steps in ±{RELATIVE_DELAY_BOUND:g} s): "
            + ", ".join(f"{name} {1e3 * d:+.1f} ms" for name, d in self.delay_scan.items())
            + " relative to the profile; its magnitude is the sensor_delay fit's start offset (scale)"
        )

    def _scan_delays(self) -> dict[str, float]:
        """Per accelerometer, and common to all (``common``, 2-DOF): the shift of the nominal replay that fits
        best (s, > 0: the accelerometer is late; the common shift's cost sums the channels in units of σ²).

        A delay against a broadband ride signal has a cost minimum a few ms
        wide between side lobes of the signal's autocorrelation: no coarse
        grid of the fit finds it. This scan (every :data:`DELAY_SCAN_STEP`
        over ±:data:`RELATIVE_DELAY_BOUND`, least squares with the usable
        samples of each channel, the replay's fine grid interpolated) is the
        likelihood scan of a pure shift, the other parameters at their start.
        """
        self.predict({}, {})
        assert self._last_grid_accelerations is not None
        a1, a2 = self._last_grid_accelerations
        shifts = np.arange(-RELATIVE_DELAY_BOUND, RELATIVE_DELAY_BOUND + 0.5 * DELAY_SCAN_STEP, DELAY_SCAN_STEP)
        out = {}
        total = np.zeros(shifts.size)
        for ch in self.channels:
            acc = a1 if ch.name == "body" else a2
            t = self.times[ch.name]
            use = (t >= self.warmup) & self.valid[ch.name]
            y = self.measured[ch.name][use] - self.gravity
            costs = np.array([float(np.sum((y - np.interp(t[use] - d, self._grid, acc)) ** 2)) for d in shifts])
            out[ch.name] = float(shifts[int(np.argmin(costs))])
            total += costs / ch.noise_std**2
        if self.two_dof:
            out["common"] = float(shifts[int(np.argmin(total))])
        return out

    def with_k_s(self, k_s: float) -> QuarterCarReplay:
        """Restart the ln k_s nuisance (and the noise budget) from ``k_s`` (N/m); returns self."""
        if not (k_s > 0.0 and math.isfinite(k_s)):
            raise Sim2RealError(f"starting soil stiffness must be positive and finite, got {k_s}")
        self.k_s_start = float(k_s)
        self.nuisance = [_soil_nuisance(k_s)]
        self.channels = [Channel(c.name, c.topic, c.unit, self.noise_std_for({}, {})[c.name]) for c in self.channels]
        return self

    def _effect_values(self, effects: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
        e: dict[str, float] = {}
        for name, params in effects.items():
            if name not in self.candidates:
                raise KeyError(f"{self.vehicle} has no effect {name!r}")
            e.update({k: float(x) for k, x in params.items()})
            if name == "wheel_liftoff":
                e["wheel_liftoff"] = 1.0
        return e

    def noise_std_for(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, float]:
        """Noise budget σ per channel: R plus the profile noise fed straight through the replay.

        2-DOF wheel: (k_tot/m₂)² σ_h² Σc² + (c_t/m₂)² σ_h² Σd² (c: the
        smoothing filter, d: the road-rate filter); the 2-DOF body has no
        direct feed-through. LRV body, replayed on E[road | profile]: the road's
        posterior error density N·S/(S+N) through |ÿ/h|² (ground or inertial
        damper, the contact-length average, the accelerometer scale). k_tot
        uses the stiffness at the static point (n·k_s for the nonlinear soil).
        """
        v = self._values
        e = self._effect_values(effects)
        r_var, s2, c2, d2 = self._noise
        k_s = math.exp(
            float(nuisance.get("ln_k_s", math.log(self.k_s_start)))
        )  # the soil's stiffness at the static point
        if self.two_dof:
            series = float(v["vehicle.tire_stiffness"])
            kt = series * k_s / (series + k_s)
            m2 = float(v["vehicle.unsprung_mass"])
            ct = e.get("tire_damping", 0.0)
            return {
                "body": math.sqrt(r_var),
                "wheel": math.sqrt(r_var + s2 * ((kt / m2) ** 2 * c2 + (ct / m2) ** 2 * d2)),
            }
        series = float(v["vehicle.suspension_stiffness"])
        kt = series * k_s / (series + k_s)
        m = float(v["vehicle.sprung_mass"]) * (1.0 + e.get("sprung_mass_change", 0.0))
        c = (
            float(v["vehicle.suspension_damping"])
            if str(v.get("vehicle.damper_reference", "ground")) == "ground"
            else 0.0
        )
        if self._road_error is None:
            return {"body": math.sqrt(r_var + s2 * ((kt / m) ** 2 * c2 + (c / m) ** 2 * d2))}
        f, density, width = self._road_error
        w = 2.0 * np.pi * f
        ground = (kt + 1j * w * c) if c > 0.0 else kt
        transfer = -(w**2) * ground / (kt + 1j * w * float(v["vehicle.suspension_damping"]) - m * w**2)
        length = e.get("tire_contact_length", 0.0)
        if length > 1e-4:
            # The enveloping window at the mean speed: two cams ρL apart, each the mean over (1 − ρ)L.
            ratio = e.get("tire_tandem_ratio", 0.0)
            wavenumber = f / self._speed_mean
            cams = np.sinc(wavenumber * (1.0 - ratio) * length)
            transfer = transfer * cams * np.cos(np.pi * wavenumber * ratio * length)
        scale = (1.0 + e.get("accel_scale_body", 0.0)) ** 2
        return {"body": math.sqrt(r_var + scale * float(np.sum(np.abs(transfer) ** 2 * density * width)))}

    # -- effects ----------------------------------------------------------

    def _road(self, length: float, ratio: float = 0.0) -> tuple[FloatArray, FloatArray]:
        """(h, ḣ) of the enveloped road: two cams ``ratio``·L apart, each the mean over (1 − ratio)·L."""
        if length <= 1e-4:
            return self._h, self._hd
        key = (round(length, 5), round(ratio, 5))
        if key not in self._envelope_cache:
            s = self._distance
            h = self._h
            cam = (1.0 - ratio) * length
            if cam > 1e-4:
                # ∫h ds of the profile's linear interpolation, exact (piecewise quadratic: a linear
                # interpolation of the integral would make a window shorter than the profile's spacing a
                # step function of its position), then the centred window mean.
                ds = np.diff(s)
                integral = np.concatenate([[0.0], np.cumsum(0.5 * (h[1:] + h[:-1]) * ds)])
                slope = np.diff(h) / np.maximum(ds, 1e-12)

                def integral_at(x: FloatArray) -> FloatArray:
                    i = np.clip(np.searchsorted(s, x, side="right") - 1, 0, s.size - 2)
                    u = x - s[i]
                    return np.asarray(integral[i] + u * (h[i] + 0.5 * slope[i] * u))

                def cam_height(c: FloatArray) -> FloatArray:
                    lo = np.clip(c - 0.5 * cam, s[0], s[-1])
                    hi = np.clip(c + 0.5 * cam, s[0], s[-1])
                    width = np.maximum(hi - lo, 1e-9)
                    return np.asarray((integral_at(hi) - integral_at(lo)) / width)

            else:

                def cam_height(c: FloatArray) -> FloatArray:
                    return np.asarray(np.interp(c, s, h))

            base = ratio * length
            env = cam_height(s) if base <= 1e-6 else 0.5 * (cam_height(s - 0.5 * base) + cam_height(s + 0.5 * base))
            if len(self._envelope_cache) > 64:
                self._envelope_cache.clear()
            self._envelope_cache[key] = (env, self._smooth(env)[1])
        return self._envelope_cache[key]

    def predict(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, FloatArray]:
        v = self._values
        k_s = math.exp(float(nuisance.get("ln_k_s", math.log(self.k_s_start))))
        e = self._effect_values(effects)
        m1 = float(v["vehicle.sprung_mass"]) * (1.0 + e.get("sprung_mass_change", 0.0))
        c = float(v["vehicle.suspension_damping"])
        if self.two_dof:
            m2 = float(v["vehicle.unsprung_mass"])
            k = float(v["vehicle.suspension_stiffness"])
            series = float(v["vehicle.tire_stiffness"])
            load = (m1 + m2) * self.gravity
            ground_damper = 0.0
        else:
            m2 = 0.0
            k = 0.0
            series = float(v["vehicle.suspension_stiffness"])
            load = m1 * self.gravity
            ground_damper = 1.0 if str(v.get("vehicle.damper_reference", "ground")) == "ground" else 0.0
        params = np.array(
            [
                m1,
                m2,
                k,
                c,
                series,
                k_s,
                load,
                e.get("soil_stiffening", 0.0),
                e.get("wheel_liftoff", 0.0),
                e.get("suspension_friction", 0.0),
                e.get("tire_damping", 0.0),
                ground_damper,
                1.0 if self.two_dof else 0.0,
                e.get("soil_shape", 0.0),
            ]
        )
        h, hd = self._road(e.get("tire_contact_length", 0.0), e.get("tire_tandem_ratio", 0.0))
        a1, a2 = _simulate(h, hd, self._dt, params)
        self._last_grid_accelerations = (a1, a2)
        out = {}
        for ch in self.channels:
            acc = a1 if ch.name == "body" else a2
            # Latency of this accelerometer stream relative to the profile's (shift of the prediction).
            t = self.times[ch.name] - (e.get(f"delay_{ch.name}", 0.0) - e.get("delay_profile", 0.0))
            y = np.interp(t, self._grid, acc) + self.gravity
            y = (1.0 + e.get(f"accel_scale_{ch.name}", 0.0)) * y + e.get(f"accel_bias_{ch.name}", 0.0)
            out[ch.name] = y
        return out


def build_model(
    bag: str | Path,
    vehicle: str = "quarter_car",
    *,
    config: str | Path | None = None,
    namespace: str | None = None,
    k_s: float | None = None,
    warmup: float = 1.5,
    progress: Callable[[str], None] | None = None,
) -> QuarterCarReplay:
    """Read ``bag`` and build its replay model.

    Args:
        bag: rosbag2 directory (CONTRACT.md, quarter car or LRV topics).
        vehicle: ``quarter_car`` or ``lrv``.
        config: Parameter file (default ``config/<vehicle>.yaml``).
        namespace: Namespace of the bag (default: the vehicle's).
        k_s: Starting soil stiffness (N/m); default: the estimator's final
            estimate over the bag (it needs the estimator run).
        warmup: Seconds left out at the start (the replay starts at rest).
        progress: Called with progress lines.
    """
    from terrain_estimation.tools.estimate import estimate_bag

    if vehicle not in ("quarter_car", "lrv"):
        raise Sim2RealError(f"quarter-car replay is for quarter_car or lrv, not {vehicle!r}")

    def say(text: str) -> None:
        if progress is not None:
            progress(text)

    ns, values, data = _open(bag, vehicle, namespace, config, say)
    two_dof = vehicle == "quarter_car"
    r_var = float(values["filter.accel_noise_variance"])
    sigma_h = float(values["estimator.profile_noise_std"])
    notes: list[str] = []
    if k_s is None:
        say("running the estimator over the bag (a starting soil stiffness for the replay)")
        run = estimate_bag(bag, vehicle, namespace=ns, config=config)
        estimates = run.messages(topic_name(ns, "soil_stiffness"))
        good = [m for m in estimates if m.converged and math.isfinite(float(m.k_s)) and float(m.k_s) > 0]
        if good:
            k_s = float(good[-1].k_s)
        elif estimates and float(estimates[-1].k_s) > 0:
            k_s = float(estimates[-1].k_s)
            notes.append("the estimator never converged on this bag: the replay's starting k_s is uncertain")
        else:
            raise Sim2RealError(f"the estimator produced no usable {topic_name(ns, 'soil_stiffness')} estimate")
    # Road on the profile's own (assumed uniform) time grid.
    keep = np.concatenate([[True], np.diff(data.profile_t) > 0.0])
    tp, zp, xp = data.profile_t[keep], data.profile_z[keep], data.profile_x[keep]
    if tp.size < 16:
        raise Sim2RealError(f"{topic_name(ns, 'terrain/profile')}: only {tp.size} distinct stamps")
    dt_p = float(np.median(np.diff(tp)))
    grid = np.arange(tp[0], tp[-1] + 0.5 * dt_p, dt_p)
    h_raw = np.interp(grid, tp, zp)
    x_grid = np.maximum.accumulate(np.interp(grid, tp, xp))
    speed_mean = float(np.mean(np.abs(data.speed))) or 1.0
    n_h = 5
    hdot_window = float(values.get("estimator.hdot_window", 0.06)) or 0.06
    n_d = _odd(round(0.5 * hdot_window / speed_mean / dt_p), 7)

    def smooth(raw: FloatArray) -> tuple[FloatArray, FloatArray]:
        hs = np.asarray(signal.savgol_filter(raw, n_h, 2, mode="interp"), dtype=float)
        rate = np.asarray(signal.savgol_filter(raw, n_d, 3, deriv=1, delta=dt_p, mode="interp"), dtype=float)
        return hs, rate

    coeffs = _savgol(n_h, 2, 0, dt_p)
    d_coeffs = _savgol(n_d, 3, 1, dt_p)
    noise = (r_var, sigma_h**2, float(np.sum(coeffs**2)), float(np.sum(d_coeffs**2)))
    road_error = None
    if two_dof:
        h, h_rate = smooth(h_raw)
    else:
        f_w, gain_w, width_w = _wiener_road(h_raw, dt_p, sigma_h)
        h, h_rate = _spectral(h_raw, dt_p, lambda f: np.interp(f, f_w, gain_w))
        road_error = (f_w, 2.0 * sigma_h**2 * dt_p * gain_w, width_w)

        def smooth(raw: FloatArray) -> tuple[FloatArray, FloatArray]:
            # A linear map (the contact-length average) of E[h | profile] is already its own
            # conditional mean: only differentiated, not smoothed again.
            return _spectral(raw, dt_p, None)

    raw = [("body", topic_name(ns, "imu/body"), data.body_t, data.body)]
    if two_dof and data.wheel_t is not None and data.wheel is not None:
        raw.append(("wheel", topic_name(ns, "imu/wheel"), data.wheel_t, data.wheel))
    channels = []
    for name, topic, t, y in raw:
        sel = (t >= grid[0]) & (t <= grid[-1])
        if int(np.sum(sel)) < 64:
            raise Sim2RealError(f"{topic}: only {int(np.sum(sel))} samples overlap the profile; need at least 64")
        channels.append((Channel(name, f"{topic} linear_acceleration.z", "m/s²", 1.0), t[sel], y[sel]))
    say(f"replay model: {len(grid)} road samples at {1 / dt_p:.0f} Hz, k_s start {k_s:.4g} N/m")
    return QuarterCarReplay(
        vehicle,
        values,
        grid,
        h,
        h_rate,
        x_grid,
        channels,
        (data.joint_t, np.abs(data.speed)),
        float(k_s),
        smooth,
        warmup,
        notes,
        noise,
        road_error,
        speed_mean,
    )
