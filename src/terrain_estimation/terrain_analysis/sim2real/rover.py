"""Replay model of a rocker-bogie (Kapvik) bag for the sim-to-real attribution (issue 6).

This module holds the replay (:class:`RoverReplay`) and its building from a bag; its parts: the sensor
streams (:mod:`~terrain_analysis.sim2real.rover_bag`), the soil model and the per-wheel inversion
(:mod:`~terrain_analysis.sim2real.rover_soil`), the smoothing (:mod:`~terrain_analysis.sim2real.rover_signal`)
and the soil-change location search (:mod:`~terrain_analysis.sim2real.rover_location`).

The full multibody plant (:mod:`vehicle_sim.plants.rover`) runs about 2.5×
real time; the attribution engine calls :meth:`RoverReplay.predict` a few
hundred times per bag. This replay is therefore *quasi-static and driven by
the bag's own measurements*: at 2 cm/s the inertial terms of the body and
bogie rows of the equations of motion are below the sensor noise (measured on
the simulator: ≤ 4e-3 N·m against 1e-2 N·m of load-cell noise in the
moments), so each 50 Hz sample is an algebraic problem. No path and no soil
state are integrated, and the terrain under the wheels is never needed: the
contact angles follow from the load cells and the soil model.

What the replay assumes
    * The rover parameters (masses, geometry, r_w, b_w, I_wg, b_d) of the
      config (``vehicle.*``) and the config's soil (``soil.*`` of the
      simulator section, [RB] Table II by default) with the plant's
      4th-order Wong–Reece surrogate (:mod:`vehicle_sim.terrain.terramechanics_surrogate`).
    * Wheels that sink into that soil (``plant.wheel_sinkage`` of the
      simulator section, on by default; issue 21): each centre rides at the
      same soil's steady sinkage z*(W, i) = r_w (1 − cos θ0(W, i)) followed by
      a plastic lag (loading within ``plant.sinkage_loading_time``, unloading
      over a contact length of travel; :mod:`~terrain_analysis.sim2real.rover_sinkage`).
      Its factor on z* is a nuisance parameter (:data:`NUISANCE`
      ``sinkage_scale``) the diagnosis fits with the config's tolerance
      ``tolerance.sinkage``; each wheel's start below z* (a rut of a segment
      that starts mid-drive) is always fitted (``sinkage_start_*``).
    * Two-axis load cells (``estimator.load_cell_axes: 2``): F_L and F_⊥ per
      wheel (single-axis cells leave W, DP and γ underdetermined per wheel;
      a :class:`~terrain_analysis.sim2real.where.Sim2RealError` says so).
    * All sensors on one clock; the effort is the torque applied from its
      stamp on (zero-order hold, as the plant's controller).

Relations used (one set per sample; symbols as MODELS.md C.3–C.6)
    Load cells → soil forces. Cell j reads, in its carrier frame at
    ε_j = θ + q1 (bogie wheels) or θ (front), F_⊥ along the carrier x axis and
    F_L along its z axis (eqs. 81–82). In the body frame the force on wheel j
    is F_j = R(ε_j − θ) (F_⊥, F_L), R(a) b = (b_x cos a + b_z sin a, −b_x sin a + b_z cos a).

    1. Whole-rover force balance (rows x0, z0 of eq. 32, quasi-static):
       m f = Σ_j F_j, with f the body specific force at O (eqs. 72–73) and
       m = m0 + m1 + 3 m_w. Predicts the **accelerometer** ``accel_x``,
       ``accel_z`` from the load cells (measured on the simulator to 6e-5 m/s²
       against 1.2e-3 m/s² of noise). Independent of soil and terrain.
    2. Moment balances (rows θ and q1 of eq. 32): with P_j the body-frame
       vector O → wheel centre j and B_j bogie joint → wheel centre j,
       Σ_j P_j × F_j − Σ_j τ_R,j − ∂V/∂θ = 0 and Σ_bogie B_j × F_j − τ_R,1 − τ_R,2
       − ∂V/∂q1 = 0, where the soil's resistive torques follow from the wheel
       rows, τ_R,j = τ_W,j − b_d q̇_j − I_wg q̈_j (q̇, q̈ by central differences
       of the encoder angles; τ_W the effort held over the sample before and
       after, so both sides average the same interval). The channels
       ``moment_body`` and ``moment_bogie`` are the load-cell side (N·m); the
       prediction is the effort side. Independent of soil and terrain.
    3. Soil (eqs. 1–2, 7–9 via the surrogate): per wheel, the unknowns W_j,
       i_j and δ_j = γ_j − ε_j follow from τ_R,j = τ_R(W_j, i_j),
       F_L² + F_⊥² = W_j² + DP(W_j, i_j)² and
       δ_j = atan2(F_⊥, F_L) − atan2(DP_j, W_j) (safeguarded Newton on i,
       vectorised, iterated to convergence: :func:`_solve_wheels`).
       The wheel centre then moves at v_j = r_w ω_j (1 − i_j) (eq. 1; eq. 2
       for skid) along the terrain tangent, at γ_j − θ = δ_j + (ε_j − θ)
       below the body x axis, with ω_j the absolute spin θ̇ (+ q̇1) + q̇_j.
       Rigid-body kinematics give each wheel's estimate of the body velocity
       at O: ẋ0^R = v_j cos(γ_j − θ) − θ̇ P_j,z − q̇1 B_j,z and
       ż0^R = −v_j sin(γ_j − θ) + θ̇ P_j,x + q̇1 B_j,x. A sinking wheel
       (sinkage s_j, vertical) also moves at −ṡ_j cos γ_j along the terrain
       normal, (sin(γ_j − θ), cos(γ_j − θ)) in the body frame, which both
       estimates add (v_j, from the slip, is the speed along the tangent). The
       channel ``velocimeter`` is the mean of the three ẋ0^R; ``vz_front_middle``
       and ``vz_middle_rear`` are the differences of the wheels' ż0^R (0 for
       a rigid rover whose soil model is right: a wrong DP of ΔDP tilts a
       wheel's inferred velocity by ΔDP/W; a wheel whose load changes by 1 N/s
       sinks at ≈ 2e-4 m/s, ≈ 7 σ). These carry the soil effects and the
       sinkage (before the replay modelled it, issue 21's plant read "structure
       differs" on every control bag, gaps 0.4–15 in these two channels).
    4. Pitch and gyro: the pitch is gravity's direction in the body frame,
       θ = atan2(−(f_x − a_x), f_z − a_z), where the body acceleration
       (a_x, a_z) is the derivative (0.1 s Savitzky–Golay) of the wheels'
       mean estimate of (ẋ0^R, ż0^R) of relation 3 (it reaches 1e-2 m/s² when
       a wheel enters another soil: 1e-3 rad of false pitch otherwise).
       θ and θ̇ are quadratic Savitzky–Golay fits over 3 s (the accelerometer's
       noise, 1.3e-4 rad of pitch per sample, would otherwise dominate θ̇);
       the bogie rate q̇1 over 1 s of encoder angles. ``pitch_rate``
       predicts the gyro as θ̇ (its noise, 0.56 °/s, is far above the pitch
       rates at 2 cm/s: the channel carries the gyro bias).

    Samples within 3 s of the start (the smoothing windows) are left out
    (``warmup``).

Effects (:data:`vehicle_sim.effects.CATALOGUE` ``["rover"]``), as the plant implements them
    * ``load_cell_bias``, ``load_cell_crosstalk``: the plant reads
      F_L + c F_⊥ + b and F_⊥ + c F_L; the replay inverts this on the
      measured cells before every relation, and predicts the load-cell side
      of the moment channels as the cells would read it.
    * ``imu_bias``: accelerometer (x, z) and gyro biases added to the
      predictions; the pitch is taken from the bias-corrected accelerometer.
    * ``sensor_delay``: every channel but the effort lags by d; the replay
      shifts the effort by d (linear interpolation) so that it meets the
      delayed state.
    * ``slip_sinkage``: the surrogate at W (1 + c|i|), forces divided by 1 + c|i|
      (the plant's force-level form, exact); the steady sinkage at W (1 + c|i|).
    * ``grousers``: the plant evaluates a surrogate fitted for radius r_w + h_g
      at the tip slip 1 − (1 − i) r_w/(r_w + h_g); the replay uses the nominal
      surrogate at the tip slip plus the Wong–Reece difference
      WR(r_w + h_g) − WR(r_w) fitted as the plant fits its surrogate, on a
      30 × 30 instead of a 100 × 100 grid (the approximation); the sinkage of
      the cylinder r_w + h_g at the tip slip, h_g less (the nominal table times
      a 30 × 30 fit of the depth ratio).
    * ``soil_change``: the same difference for the changed soil, blended in
      over 2 mm of wheel-centre travel beyond ``soil_change_distance``
      (the plant switches at x_j ≥ d; the blend keeps the fit of d smooth). Wheel-centre x is O's x, integrated from
      the velocimeter from 0 at the bag's start (the plant's start_x = 0),
      plus the wheel's offset. The distance candidate starts where a
      linearised change-point scan of the nominal residual puts the change,
      refined with the replay's own cost near its best local minimum
      (:meth:`RoverReplay._change_location`; its "off" is immaterial while the
      soil scales are 1). With the 30 × 30 difference replaced by the plant's
      own 100 × 100 surrogate of the changed soil, the held-out residual of
      the withheld-effect suite's soil-change bags with their true parameters
      is the same within 1.5 %: the grid is not what limits this effect. The
      changed soil's sinkage is the nominal one times the 30 × 30 fit of their
      ratio (0.16 mm off the plant's in the test's run). Where a wheel enters a
      softer soil the plant sinks it 2–4 mm within ≈ 0.3 s: a vertical transient
      of the body that the 3 s pitch smoothing spreads over ±1.5 s, with inertial
      moments the quasi-static balance leaves out; the replay with the true
      change closes the gap from ≈ 2 s after the crossing.
    * ``vertical_velocity`` (path undulation): **not a candidate.** The replay
      takes the configuration from the sensors and infers the contact angles,
      so the terrain's shape, undulation included, is part of its input: an
      undulation of the wheel-centre path is not distinguishable from terrain
      (the Fig. 10 rolling terrain itself has a 0.9 m, 12 mm component). A
      note says so in every model.

Noise budgets
    Each channel's σ is what the config's sensor noise (``noise.*``) does to
    its residual through the replay: four Monte Carlo realisations of that
    noise are added to the measured inputs and replayed with the nominal
    model; the spread of the change of the residual is the propagated noise.
    The smoothing colours it (the ż0^R differences most), so σ is the level
    of the white noise that bounds its PSD in every octave band from 0.5 Hz
    (:func:`_white_bound`), not only its variance, as the attribution's noise
    tests assume white residuals. A model-error floor (:data:`MODEL_FLOORS`,
    below the noise) is added in quadrature.

Measured (simulator, Table IV noise; ``test/test_sim2real_rover.py``)
    Nominal runs on terrains rolling, uphill and step_sharp: every channel's
    residual RMS 0.5–1.0 σ. With an effect on, the replay with that effect at
    the plant's value brings every channel back to ≤ 1.3 σ for load-cell
    bias and cross-talk, IMU biases, slip-sinkage and grousers. Soil change:
    the same away from the change; for ≈ 1 s after a wheel crosses it the
    plant's transient (body acceleration spike, bogie rate step) is faster
    than the smoothing above and leaves a residual of a few σ in the ż0^R
    differences (still far below the nominal replay's there). At the one
    sample where a wheel enters the changed soil, the central differences of
    the encoder angles straddle the switch of τ_R: a few σ in the moment and
    accelerometer channels, ≈ 13 σ in ``vz_front_middle`` (test's run, front
    wheel, true parameters). Until session 7 the plant's load cells reported
    the normal load held from the previous step (computed with the old soil's
    forces) instead of the reaction that acts, 0.5–3 N apart at that sample:
    44 σ in ``moment_body`` there, a simulator artefact the plant no longer
    has.

Outside the domain: a rover sliding backward
    A rover that cannot climb stalls and slides back under turning wheels
    (slip beyond 1, body accelerations of 0.5 m/s²): outside the soil model's
    slip range and the quasi-static balance. Such stretches, widened by 1.5 s
    either side, are left out of every fit, score and test (``valid``,
    :meth:`RoverReplay._inside_domain`), with a note. Measured on the three
    withheld bags that slide (≈ 1.7 s each, velocimeter down to −0.06 to
    −0.34 m/s): 9a51da3d1271 (soil change; it kept 92 % of its gap with the
    true parameters before) and 62b94e4b601a (slip-sinkage c = 1.47) are now
    attributed right; b5507c8f9e04 (c = 1.30) still is not: with the true c
    the ż0^R differences leave 35–8600 σ² per second over the 3 s before the
    slide, while the inferred slips rise from 0.45 to 0.55 (the approach to
    the stall is already outside what the replay reproduces; not understood).

What the bag shows only to a likelihood ratio, and what it cannot show
    * ``sensor_delay``: only the effort is undelayed, and at 2 cm/s it changes
      by ≈ 2e-4 N·m per sample; a 60 ms delay moves τ_R by ≈ 1e-3 N·m, the
      slip by ≈ 3e-4: the replay with and without the delay differ by less
      than 0.05 in mean r² on every channel, far below what the noise tests
      flag, and its held-out χ² drop (≈ 0.3 %) is below the engine's
      relative-improvement guard. It is coherent, though: on a 30 s bag the
      χ² over all samples falls by ≈ 40 (noise-budget units) from 0 to the
      best delay. The engine's cross-fitted held-out likelihood-ratio test
      (:func:`terrain_analysis.sim2real.attribution._cross_fitted`, issue 22
      item 4) finds it. Measured on 30 s rolling-terrain bags (before the
      replay modelled the sinkage, plant with ``wheel_sinkage=False``): 60 ms
      fitted as 39, 44 and 62 ms (the χ² minimum over all samples of the first is at
      ≈ 40 ms: the moment channels favour it, ``vz_front_middle`` no delay —
      not understood), 100 ms as 99 ms.
    * ``vertical_velocity``: see above (not a candidate). Listed as "not
      identifiable from this bag" (attribute ``unidentifiable``) with the
      measurement that would identify it.

Units: SI (m, s, kg, rad, N, N·m).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import Channel, FitParameter, candidates_from_catalogue
from terrain_analysis.sim2real.rover_bag import WHEELS, RoverSeries, read_rover_bag, series_from_run
from terrain_analysis.sim2real.rover_kinematics import RoverKinematics
from terrain_analysis.sim2real.rover_location import ChangeLocation
from terrain_analysis.sim2real.rover_signal import _savgol, _white_bound
from terrain_analysis.sim2real.rover_sinkage import START_OFFSET, sinkage_motion, start_offsets
from terrain_analysis.sim2real.rover_soil import _SoilModel, _SoilVariant, _solve_wheels
from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.models.rover import RoverParams

__all__ = [
    "MODEL_FLOORS",
    "NUISANCE",
    "RoverReplay",
    "RoverSeries",
    "build_model",
    "build_model_from_series",
    "read_rover_bag",
    "series_from_run",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[str], None] | None

_BLEND_WIDTH = 2.0e-3  # m, soil-change blend
#: Effects that change the inputs or the soil model of the per-wheel inversion (the others reuse the nominal one).
_SOIL_INPUT_EFFECTS = frozenset(
    {"load_cell_bias", "load_cell_crosstalk", "sensor_delay", "slip_sinkage", "grousers", "soil_change"}
)
_SMOOTH_WINDOW = 3.0  # s, Savitzky-Golay window of the accelerometer pitch
_BOGIE_WINDOW = 1.0  # s, Savitzky-Golay window of the bogie rate
_ACCEL_WINDOW = 0.1  # s, Savitzky-Golay window of the body acceleration from the wheels' velocities
#: s, quadratic Savitzky–Golay window of the steady sinkage z* before the sinkage lag (:meth:`RoverReplay._sinkage`).
_SINKAGE_WINDOW = 0.4

#: Model-error floors σ_model per channel (added in quadrature to the propagated noise): the nominal replay's
#: largest residual RMS on noiseless 15 s simulator runs (terrains rolling and step_sharp), rounded up.
MODEL_FLOORS: Mapping[str, float] = {
    "accel_x": 1.5e-5,
    "accel_z": 1.5e-5,
    "pitch_rate": 3.0e-5,
    "moment_body": 5.0e-4,
    "moment_bogie": 3.0e-4,
    "velocimeter": 8.0e-6,
    "vz_front_middle": 8.0e-6,
    "vz_middle_rear": 8.0e-6,
}


#: Nuisance parameters the replay can fit in every model (``nuisance=`` of :class:`RoverReplay`), besides the
#: sinkage's start offsets it always fits (:data:`~terrain_analysis.sim2real.rover_sinkage.START_OFFSET`):
#: ``sinkage_scale``, the factor on the nominal soil's steady sinkage z* (relation 3; a soil's k_c, k_φ and n are
#: uncertain by tens of per cent, and z* goes as (k_c/b + k_φ)^(−2/(2n+1))). Its prior, if any, is the nominal
#: tolerance's (:mod:`terrain_analysis.sim2real.tolerance`).
NUISANCE: Mapping[str, FitParameter] = {
    "sinkage_scale": FitParameter("sinkage_scale", "–", 1.0, (0.0, 3.0), 0.1),
}


class RoverReplay(ChangeLocation, RoverKinematics):
    """:class:`~terrain_analysis.sim2real.model.ReplayModel` of one rover bag (module docstring)."""

    vehicle = "rover"

    def __init__(
        self,
        series: RoverSeries,
        params: RoverParams,
        soil: Any,
        *,
        warmup: float = 3.0,
        noise: Mapping[str, float] | None = None,
        source: str = "",
        monte_carlo: int = 4,
        seed: int = 0,
        sinkage: bool = True,
        sinkage_loading_time: float = 0.1,
        nuisance: Sequence[str] = (),
    ) -> None:
        n = series.t.size
        unknown = [name for name in nuisance if name not in NUISANCE]
        if unknown:
            raise ValueError(f"RoverReplay: unknown nuisance parameter(s) {unknown}; known: {sorted(NUISANCE)}")
        if n < 50:
            raise Sim2RealError(f"{source or 'bag'}: {n} samples; the rover replay needs at least 50 (1 s at 50 Hz)")
        self.series = series
        self.params = params
        self.warmup = float(warmup)
        self.notes: list[str] = []
        dt = float(np.median(np.diff(series.t)))
        if not dt > 0.0:
            raise Sim2RealError(f"{source or 'bag'}: joint_states stamps do not increase (median step {dt} s)")
        self.dt = dt
        self.noise = dict(noise or {})
        #: Model the wheels' sinkage (module docstring, relation 3) and its loading time constant (s).
        self.sinkage = bool(sinkage)
        self.sinkage_loading_time = float(sinkage_loading_time)
        self._sinkage_scale = 1.0
        self._sinkage_start: FloatArray | None = None
        self._t = series.t
        self._prepare()
        self._inside = self._inside_domain(self.noise.get("forward_speed", 0.0), source)
        self._warm_series: RoverSeries | None = None
        self._warm_start: tuple[FloatArray, FloatArray] | None = None
        self._nominal_state: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray] | None = None
        self.soil_model = _SoilModel(soil, params)
        self.soil = soil
        self._soil_weights: FloatArray | None = None
        self._build_channels(monte_carlo, seed)
        catalogue = candidates_from_catalogue("rover", exclude=("vertical_velocity",))
        self.candidates = self._adapt_candidates(catalogue)
        #: Fitted in every model: the sinkage's unknown start (with it) and the asked-for :data:`NUISANCE`.
        start = list(START_OFFSET.values()) if self.sinkage else []
        self.nuisance: list[FitParameter] = start + [NUISANCE[name] for name in nuisance]
        #: Effects this replay cannot identify from any bag, with the measurement that would (issue 22, item 4).
        self.unidentifiable: dict[str, str] = {
            "vertical_velocity": "a measurement of the terrain under the wheels (a surveyed or lidar profile of the "
            "path): the replay infers the contact geometry from the load cells and the joint angles, so a path "
            "undulation is terrain to it"
        }
        self.notes.append(
            "vertical_velocity (path undulation) is not a candidate: the replay is driven by the measured "
            "configuration and infers the contact angles from the load cells, so the terrain's shape (an "
            "undulation included) is part of its input and cannot be told apart from terrain"
        )

    # --- preparation --------------------------------------------------------

    def _prepare(self) -> None:
        s, dt = self.series, self.dt
        q = s.wheel_angle
        rate = np.empty_like(q)
        rate[1:-1] = (q[2:] - q[:-2]) / (2.0 * dt)
        rate[0], rate[-1] = (q[1] - q[0]) / dt, (q[-1] - q[-2]) / dt
        accel = np.zeros_like(q)
        accel[1:-1] = (q[2:] - 2.0 * q[1:-1] + q[:-2]) / dt**2
        self._wheel_rate = rate
        self._wheel_accel = accel
        window = int(round(_SMOOTH_WINDOW / dt))
        self._window = window
        self._accel_window = int(round(_ACCEL_WINDOW / dt))
        self._sinkage_window = int(round(_SINKAGE_WINDOW / dt))
        self._accel_smooth = _savgol(s.accel, window, 0, dt)
        self._bogie_rate = _savgol(s.bogie, int(round(_BOGIE_WINDOW / dt)), 1, dt)
        self._speed_smooth = _savgol(s.speed, window, 0, dt)
        # Effort held over the sample before and after t_k (central differences average that interval).
        e = s.effort
        self._effort_mid = np.vstack([e[:1], 0.5 * (e[1:] + e[:-1])])
        p = self.params
        self._front = np.array(p.front_wheel_offset)
        self._joint = np.array(p.bogie_joint_offset)
        self._bogie_wheels = np.array(p.bogie_wheel_offsets)

    def _inside_domain(self, speed_noise: float, source: str) -> NDArray[np.bool_]:
        """Samples inside the quasi-static replay's domain: not while the rover slides backward.

        A rover that cannot climb (its wheels dig in, the drawbar pull falls below the grade
        resistance) stalls and slides back under turning wheels: slip beyond 1, body
        accelerations of 0.5 m/s² and more, outside the soil model's slip range and the
        quasi-static force balance (withheld bags 62b94e4b601a, b5507c8f9e04: slip-sinkage
        c ≈ 1.4 on a rolling-terrain climb; 9a51da3d1271: a softer soil after a change; the
        velocimeter reads −0.06 to −0.34 m/s for ≈ 1.7 s). Such a stretch (velocimeter below
        −3σ of its noise, and below −1 mm/s, with the wheels turning forward), widened by half
        the longest smoothing window (:data:`_SMOOTH_WINDOW`) on each side, is left out of
        every fit, score and test (the engine's ``valid`` masks), with a note.
        """
        s = self.series
        threshold = -max(3.0 * float(speed_noise), 1e-3)
        sliding = (s.speed < threshold) & np.all(self._wheel_rate > 0.0, axis=1)
        inside = np.ones(self._t.size, dtype=bool)
        if not np.any(sliding):
            return inside
        margin = 0.5 * _SMOOTH_WINDOW
        starts = np.flatnonzero(sliding & ~np.r_[False, sliding[:-1]])
        ends = np.flatnonzero(sliding & ~np.r_[sliding[1:], False])
        spans = []
        for a, b in zip(starts, ends, strict=True):
            inside &= ~((self._t >= self._t[a] - margin) & (self._t <= self._t[b] + margin))
            spans.append(f"{self._t[a]:.1f}–{self._t[b]:.1f} s")
        self.notes.append(
            f"the rover slid backward (velocimeter down to {float(np.min(s.speed)):.3f} m/s with the wheels "
            f"driving forward: slip beyond 1) over {', '.join(spans)}: outside the quasi-static replay; "
            f"{100.0 * float(np.mean(~inside)):.1f} % of the samples ({margin:g} s either side included) are "
            "left out of every fit, score and test"
        )
        if not np.any(inside[self._t >= self._t[0] + self.warmup]):
            raise Sim2RealError(f"{source or 'bag'}: the rover slides backward throughout; nothing to replay")
        return inside

    def _base_inputs(self, effects: Mapping[str, Mapping[str, float]]) -> dict[str, Any]:
        """Sensor-level effects undone on the measured inputs."""
        s = self.series
        bias = effects.get("load_cell_bias", {})
        b = np.array([bias.get(f"load_cell_bias_{w}", 0.0) for w in WHEELS])
        c = float(effects.get("load_cell_crosstalk", {}).get("load_cell_crosstalk", 0.0))
        axial = s.load_axial - b
        perp = s.load_perpendicular
        if c != 0.0:
            det = 1.0 - c * c
            axial, perp = (axial - c * perp) / det, (perp - c * axial) / det
        imu = effects.get("imu_bias", {})
        accel_bias = np.array([imu.get("imu_accel_bias_x", 0.0), imu.get("imu_accel_bias_z", 0.0)])
        f = self._accel_smooth - accel_bias
        pitch = np.arctan2(-f[:, 0], f[:, 1])
        delay = float(effects.get("sensor_delay", {}).get("sensor_delay", 0.0))
        effort = self._effort_mid
        if delay != 0.0:
            t = self._t
            effort = np.column_stack([np.interp(t - delay, t, effort[:, j]) for j in range(3)])
        return {"axial": axial, "perp": perp, "pitch": pitch, "effort": effort, "accel_bias": accel_bias}

    def _wheel_state(
        self, base: Mapping[str, Any], effects: Mapping[str, Mapping[str, float]]
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """Per wheel (N, 3): W, i, DP, δ = γ − ε from (F_L, F_⊥, τ_R) and the soil model (module docstring, 3),
        and the steady sinkage z*(W, i) of the same soil (zero without :attr:`sinkage`).

        Newton on i for τ_R(W, i) = τ_R,measured, alternating with W = √(F_L² + F_⊥² − DP²);
        started from the nominal solution of the same data (cached).
        """
        soil_inputs = {k: v for k, v in effects.items() if k in _SOIL_INPUT_EFFECTS}
        cached = self._nominal_state if self._warm_series is self.series else None
        if not soil_inputs and cached is not None:
            return cached
        axial, perp = base["axial"], base["perp"]
        tau = self._resistive_torque(base["effort"]).ravel()
        force2 = (axial**2 + perp**2).ravel()
        shape = axial.shape
        sinkage = float(effects.get("slip_sinkage", {}).get("slip_sinkage_coefficient", 0.0))
        grouser = float(effects.get("grousers", {}).get("grouser_height", 0.0))
        variants = self._variants(effects, grouser)
        all_variants = variants
        warm = self._warm_start if self._warm_series is self.series else None
        rows: NDArray[np.intp] | None = None
        if cached is not None and set(soil_inputs) == {"soil_change"} and len(variants) == 2:
            # Only the samples at or beyond the change differ from the nominal solution.
            weight = np.asarray(variants[1][1])
            rows = np.flatnonzero(weight > 1e-12)
            variants = [(v, np.asarray(w)[rows]) for v, w in variants]
            tau, force2 = tau[rows], force2[rows]
        sweeps: tuple[tuple[int, int], ...]
        if warm is not None:
            slip, load = (warm[0].copy(), warm[1].copy()) if rows is None else (warm[0][rows], warm[1][rows])
            sweeps = ((2, 1), (1, 1))
        else:
            slip, load = np.full(tau.size, 0.2), np.sqrt(force2)
            sweeps = ((8, 2), (3, 1), (3, 1), (3, 1))

        def forces(sel: NDArray[np.intp] | None, w: FloatArray, i: FloatArray) -> tuple[FloatArray, FloatArray]:
            use = variants if sel is None else [(v, x if np.ndim(x) == 0 else np.asarray(x)[sel]) for v, x in variants]
            return self.soil_model.forces(w, i, sinkage=sinkage, grouser_height=grouser, variants=use)

        slip, load, dp = _solve_wheels(forces, tau, force2, slip, load, sweeps)
        if rows is not None and cached is not None:
            full = [np.array(a, dtype=float).ravel() for a in cached[:3]]
            for array, value in zip(full, (load, slip, dp), strict=True):
                array[rows] = value
            load, slip, dp = full
        if warm is None and not effects and self._warm_series is None:
            self._warm_series, self._warm_start = self.series, (slip.copy(), load.copy())
        delta = np.arctan2(perp.ravel(), axial.ravel()) - np.arctan2(dp, load)
        if self.sinkage:
            depth = self.soil_model.depth(load, slip, sinkage=sinkage, grouser_height=grouser, variants=all_variants)
        else:
            depth = np.zeros_like(load)
        state = (
            load.reshape(shape),
            slip.reshape(shape),
            dp.reshape(shape),
            delta.reshape(shape),
            depth.reshape(shape),
        )
        if not soil_inputs and self._warm_series is self.series:
            self._nominal_state = state
        return state

    def _variants(
        self, effects: Mapping[str, Mapping[str, float]], grouser: float
    ) -> list[tuple[_SoilVariant | None, FloatArray | float]]:
        base = _SoilVariant(self.soil, grouser) if grouser > 0.0 else None
        change = effects.get("soil_change")
        if change:
            from vehicle_sim.effects import effects_for

            plant = effects_for("rover", {"soil_change": {k: float(v) for k, v in change.items()}}, soil=self.soil)
            if plant.soil_change_soil is not None:
                if self._soil_weights is not None:  # the change-location scan: the soil of given wheels
                    after = self._soil_weights
                else:
                    x = self._wheel_x()
                    after = (0.5 * (1.0 + np.tanh((x - float(plant.soil_change_distance)) / _BLEND_WIDTH))).ravel()
                return [(base, 1.0 - after), (_SoilVariant(plant.soil_change_soil, grouser), after)]
        return [(base, 1.0)]

    def _wheel_x(self) -> FloatArray:
        """World x of each wheel centre (N, 3): O from 0 at the start (velocimeter integrated) plus the offset."""
        if not hasattr(self, "_wheel_x_cache"):
            base = self._base_inputs({})
            pitch = base["pitch"]
            vx = self._speed_smooth * np.cos(pitch)
            x0 = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * np.diff(self._t))])
            P, _ = self._geometry(self.series.bogie)
            offset = P[:, :, 0] * np.cos(pitch)[:, None] + P[:, :, 1] * np.sin(pitch)[:, None]
            self._wheel_x_cache = x0[:, None] + offset
        out: FloatArray = self._wheel_x_cache
        return out

    # --- prediction -----------------------------------------------------------

    def _channels_for(
        self, effects: Mapping[str, Mapping[str, float]], series: RoverSeries | None = None
    ) -> tuple[dict[str, FloatArray], dict[str, FloatArray]]:
        """(measured, predicted) of every channel with ``effects``."""
        if series is not None:
            saved = self.series, self._t
            self.series = series
            self._prepare()
        try:
            return self._compute(effects)
        finally:
            if series is not None:
                self.series, self._t = saved
                self._prepare()

    def _sinkage(
        self,
        depth: FloatArray,
        slip: FloatArray,
        pitch_rate: FloatArray,
        effects: Mapping[str, Mapping[str, float]],
    ) -> tuple[FloatArray, FloatArray | None]:
        """(s, ṡ) of each wheel (N, 3) following its steady depth (:mod:`~terrain_analysis.sim2real.rover_sinkage`);
        ṡ is None without :attr:`sinkage`.

        z* is smoothed first (quadratic, :data:`_SINKAGE_WINDOW`): it follows the inferred W and i, whose
        per-sample noise the lag rectifies (a rising z* is followed within 0.1 s, a falling one over a contact
        length), which biased ṡ by up to 9e-6 m/s over 5 s (0.3 σ of the ż0^R channels) on a step_sharp control
        bag against its plant's truth; smoothed over 0.4 s, 1.7e-6 m/s. z* itself changes over the wheels'
        travel across the terrain (≥ 1 s at 2 cm/s).
        """
        if not self.sinkage:
            return np.zeros_like(depth), None
        grouser = float(effects.get("grousers", {}).get("grouser_height", 0.0))
        return sinkage_motion(
            self._t,
            _savgol(depth, self._sinkage_window, 0, self.dt) * self._sinkage_scale,
            self._centre_speed(slip, pitch_rate),
            loading_time=self.sinkage_loading_time,
            radius=self.params.wheel_radius,
            grouser_height=grouser,
            start_offset=self._sinkage_start,
        )

    def _compute(
        self, effects: Mapping[str, Mapping[str, float]]
    ) -> tuple[dict[str, FloatArray], dict[str, FloatArray]]:
        s, p = self.series, self.params
        base = self._base_inputs(effects)
        pitch = base["pitch"]
        P, B = self._geometry(s.bogie)
        fx, fz = self._body_forces(base["axial"], base["perp"])
        fx_raw, fz_raw = self._body_forces(s.load_axial, s.load_perpendicular)
        m = p.total_mass
        bias = base["accel_bias"]
        gyro_bias = float(effects.get("imu_bias", {}).get("imu_gyro_bias", 0.0))
        pred: dict[str, FloatArray] = {}
        meas: dict[str, FloatArray] = {}
        meas["accel_x"], meas["accel_z"] = s.accel[:, 0], s.accel[:, 1]
        pred["accel_x"] = fx.sum(axis=1) / m + bias[0]
        pred["accel_z"] = fz.sum(axis=1) / m + bias[1]
        # Soil: per-wheel slip and contact angle (independent of the pitch rate), and the steady sinkage.
        load, slip, dp, delta, depth = self._wheel_state(base, effects)
        # Pitch from gravity: the accelerometer minus the body acceleration, which the wheels' velocities give
        # (a first pass with the quasi-static pitch; the dynamic part reaches 1e-2 m/s² at a soil change).
        pitch_rate = _savgol(np.unwrap(pitch), self._window, 1, self.dt)
        sinkage, sink = self._sinkage(depth, slip, pitch_rate, effects)
        vx, vz = self._body_velocity(slip, delta, pitch_rate, P, B, None if sink is None else (sink, pitch))
        ax = _savgol(vx.mean(axis=1), self._accel_window, 1, self.dt)
        az = _savgol(vz.mean(axis=1), self._accel_window, 1, self.dt)
        f = s.accel - bias
        pitch = _savgol(np.unwrap(np.arctan2(-(f[:, 0] - ax), f[:, 1] - az)), self._window, 0, self.dt)
        pitch_rate = _savgol(pitch, self._window, 1, self.dt)
        vx, vz = self._body_velocity(slip, delta, pitch_rate, P, B, None if sink is None else (sink, pitch))
        meas["pitch_rate"] = s.gyro
        pred["pitch_rate"] = pitch_rate + gyro_bias

        # Moments: load-cell side as the raw cells read it; effort side from the wheel rows.
        def cross(vec: FloatArray, fxj: FloatArray, fzj: FloatArray) -> FloatArray:
            result: FloatArray = vec[..., 1] * fxj - vec[..., 0] * fzj
            return result

        tau_r = self._resistive_torque(base["effort"])
        d_theta, d_bogie = self._gravity_moments(pitch, P, B)
        body_raw = cross(P, fx_raw, fz_raw).sum(axis=1)
        body_true = cross(P, fx, fz).sum(axis=1)
        bogie_raw = cross(B[:, :2], fx_raw[:, :2], fz_raw[:, :2]).sum(axis=1)
        bogie_true = cross(B[:, :2], fx[:, :2], fz[:, :2]).sum(axis=1)
        meas["moment_body"] = body_raw
        pred["moment_body"] = tau_r.sum(axis=1) + d_theta + (body_raw - body_true)
        meas["moment_bogie"] = bogie_raw
        pred["moment_bogie"] = tau_r[:, :2].sum(axis=1) + d_bogie + (bogie_raw - bogie_true)

        meas["velocimeter"] = s.speed
        pred["velocimeter"] = vx.mean(axis=1)
        zeros = np.zeros_like(s.speed)
        meas["vz_front_middle"] = zeros
        pred["vz_front_middle"] = vz[:, 2] - vz[:, 1]
        meas["vz_middle_rear"] = zeros
        pred["vz_middle_rear"] = vz[:, 1] - vz[:, 0]
        self._last_state = {"load": load, "slip": slip, "drawbar_pull": dp, "delta": delta, "sinkage": sinkage}
        for name, value in pred.items():
            if not np.all(np.isfinite(value)):
                pred[name] = np.where(np.isfinite(value), value, 0.0)
        return meas, pred

    def _build_channels(self, replicates: int, seed: int) -> None:
        meas, pred = self._channels_for({})
        rng = np.random.default_rng(seed)
        s = self.series
        nz = self.noise
        spread: dict[str, list[FloatArray]] = {k: [] for k in meas}
        for _ in range(max(0, replicates)):
            noisy = dataclasses.replace(
                s,
                accel=s.accel + nz.get("acceleration", 0.0) * rng.standard_normal(s.accel.shape),
                gyro=s.gyro + nz.get("pitch_rate", 0.0) * rng.standard_normal(s.gyro.shape),
                bogie=s.bogie + nz.get("bogie_angle", 0.0) * rng.standard_normal(s.bogie.shape),
                wheel_angle=s.wheel_angle + nz.get("wheel_angle", 0.0) * rng.standard_normal(s.wheel_angle.shape),
                speed=s.speed + nz.get("forward_speed", 0.0) * rng.standard_normal(s.speed.shape),
                load_axial=s.load_axial + nz.get("load_cell", 0.0) * rng.standard_normal(s.load_axial.shape),
                load_perpendicular=s.load_perpendicular
                + nz.get("load_cell", 0.0) * rng.standard_normal(s.load_perpendicular.shape),
            )
            m2, p2 = self._channels_for({}, noisy)
            for k in meas:
                spread[k].append((m2[k] - p2[k]) - (meas[k] - pred[k]))
        use = self._t >= self._t[0] + self.warmup
        units = {
            "accel_x": ("imu linear_acceleration.x", "m/s²"),
            "accel_z": ("imu linear_acceleration.z", "m/s²"),
            "pitch_rate": ("imu angular_velocity.y", "rad/s"),
            "moment_body": ("wheel/*/load force.z, force.x: moment about O (vs joint_states effort)", "N·m"),
            "moment_bogie": ("wheel/{rear,middle}/load: moment about the bogie joint (vs effort)", "N·m"),
            "velocimeter": ("velocimeter twist.linear.x", "m/s"),
            "vz_front_middle": ("wheel/{front,middle}/load + joint_states: body z velocity front − middle", "m/s"),
            "vz_middle_rear": ("wheel/{middle,rear}/load + joint_states: body z velocity middle − rear", "m/s"),
        }
        channels = []
        for name in meas:
            # One more noise realisation through the replay changes the residual by what one realisation
            # does: its spread is the propagated noise. The replay's smoothing colours it, so σ is the white
            # level that bounds it in every octave band of the noise tests, not only its variance.
            propagated = (
                _white_bound([d[use & self._inside] for d in spread[name]], 1.0 / self.dt) if spread[name] else 0.0
            )
            sigma = math.hypot(propagated, MODEL_FLOORS.get(name, 0.0))
            if not (sigma > 0.0 and math.isfinite(sigma)):
                sigma = MODEL_FLOORS.get(name, 1e-6) or 1e-6
            topic, unit = units[name]
            channels.append(Channel(name, topic, unit, sigma))
        self.channels: list[Channel] = channels
        self.times: dict[str, FloatArray] = {c.name: self._t for c in channels}
        self.valid: dict[str, NDArray[np.bool_]] = {c.name: self._inside for c in channels}
        self.measured: dict[str, FloatArray] = {k: np.asarray(v, dtype=float) for k, v in meas.items()}
        state = self._last_state if hasattr(self, "_last_state") else {}
        self.regimes: dict[str, tuple[FloatArray, FloatArray]] = {
            "forward speed (m/s)": (self._t, self._speed_smooth),
            "bogie angle (rad)": (self._t, s.bogie),
        }
        if state:
            self.regimes["mean slip (–)"] = (self._t, np.mean(state["slip"], axis=1))

    def predict(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, FloatArray]:
        """Predicted channels with ``effects`` added (``{}``: nominal) and the :data:`NUISANCE` values ``nuisance``."""
        self._sinkage_scale = float(nuisance.get("sinkage_scale", 1.0))
        self._sinkage_start = start_offsets(nuisance)
        try:
            _, pred = self._compute(effects)
        finally:
            self._sinkage_scale, self._sinkage_start = 1.0, None
        return pred


# ---------------------------------------------------------------------------
# Building
# ---------------------------------------------------------------------------


#: The sensor noise σ of the config (``noise.*``) the replay propagates into its noise budgets.
_NOISE = ("acceleration", "pitch_rate", "bogie_angle", "wheel_angle", "forward_speed", "load_cell")


def _config_values(config: str | Path | None) -> tuple[dict[str, Any], dict[str, Any]]:
    from terrain_estimation.vehicles import estimator_parameters, get_vehicle
    from vehicle_sim.ros.registry import get_simulator, simulator_parameters

    est = estimator_parameters(get_vehicle("rover"), config)
    sim = simulator_parameters(get_simulator("rover"), config)
    return est, sim


def _soil_from(values: Mapping[str, Any]) -> Any:
    from vehicle_sim.terrain.wong_reece import WongReeceSoil

    fields = [f.name for f in dataclasses.fields(WongReeceSoil)]
    return WongReeceSoil(**{name: float(values[f"soil.{name}"]) for name in fields})


def build_model_from_series(
    series: RoverSeries,
    *,
    config: str | Path | None = None,
    params: RoverParams | None = None,
    soil: Any = None,
    warmup: float = 3.0,
    source: str = "",
    progress: Progress = None,
    nuisance: Sequence[str] = (),
) -> RoverReplay:
    """The replay model of already-read sensor streams (vehicle, soil, sinkage and noise from the config).

    ``nuisance``: names of :data:`NUISANCE` to fit in every model (their priors: the nominal tolerances).
    """
    from terrain_estimation.ros.rover import vehicle_params

    est, sim = _config_values(config)
    if int(est["estimator.load_cell_axes"]) != 2:
        raise Sim2RealError(
            "estimator.load_cell_axes = 1: the rover replay needs two-axis load cells (force.x and force.z); "
            "with one axis W, DP and the contact angle of a wheel are not separable"
        )
    noise = {name: float(est[f"noise.{name}"]) for name in _NOISE}
    if progress is not None:
        progress(f"building the rover replay ({series.t.size} samples)")
    return RoverReplay(
        series,
        params or vehicle_params(est),
        soil if soil is not None else _soil_from(sim),
        warmup=warmup,
        noise=noise,
        source=source,
        sinkage=bool(sim["plant.wheel_sinkage"]),
        sinkage_loading_time=float(sim["plant.sinkage_loading_time"]),
        nuisance=nuisance,
    )


def build_model(
    bag: str | Path,
    *,
    config: str | Path | None = None,
    namespace: str | None = None,
    progress: Progress = None,
    warmup: float = 3.0,
    nuisance: Sequence[str] = (),
) -> RoverReplay:
    """The replay model of a rover bag (CONTRACT.md rover topics) for the attribution engine.

    Args:
        bag: rosbag2 directory.
        config: the rover config (default ``config/rover.yaml``): vehicle, noise, soil, joint names.
        namespace: the bag's namespace (default ``/rover``).
        progress: called with progress lines.
        warmup: seconds left out at the start.
        nuisance: names of :data:`NUISANCE` to fit in every model.

    Raises:
        Sim2RealError: missing topic or joint, non-finite values, single-axis load cells, too short.
    """
    est, _ = _config_values(config)
    joints = {"bogie": str(est["joints.bogie"]), **{w: str(est[f"joints.{w}_wheel"]) for w in WHEELS}}
    if progress is not None:
        progress(f"reading {bag}")
    series = read_rover_bag(bag, namespace=namespace or "/rover", joints=joints)
    return build_model_from_series(
        series, config=config, warmup=warmup, source=str(bag), progress=progress, nuisance=nuisance
    )
