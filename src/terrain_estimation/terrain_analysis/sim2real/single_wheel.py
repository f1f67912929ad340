"""Sim-to-real gap of the Wong–Reece wheel model on a real single-wheel rig (CMU, smooth wheel, granular soil).

Data
    ``all_smooth_data.mat`` of the Carnegie Mellon single-wheel testbed
    (``robomechanics/3d-terramechanics``, C. Pavlov 2022, MIT licence; see
    ``real_data/README.md``): 189 steady-state trials of a smooth rigid wheel
    (r = 58 mm, b = 50 mm) at 10 mm/s carriage speed, 9 slip ratios from −1
    (locked) to 0.9, slip angles β = 0…90°, three repetitions each. Only the
    27 trials at β = 0 are used: the model is planar (no lateral force, no
    side-wall bulldozing), and a trial at β ≠ 0 has a lateral slip velocity it
    cannot represent. Per trial: slip i = (V_ry − V_x)/max(V_x, V_ry) (the
    project's eqs. 1–2), normal load W = −avg_Fz (N), drawbar pull
    DP = −avg_Fy (N, the rig's "tractive" axis), sinkage z = −avg_Z (mm).

Replay model (:class:`SingleWheelModel`, a :class:`~terrain_analysis.sim2real.model.ReplayModel`)
    "Samples" are trials, ordered by slip (then trial number); the "time" of
    trial k is k (no physical time: each trial is a steady state). Inputs are
    the measured i and W of each trial; the predicted channels are DP (N) and
    z (mm). The engine's least squares compares them with the measured means
    in units of the noise budget σ.

    Noise budget σ per channel: the pooled standard deviation of the repeated
    trials (three per commanded slip) about their slip group's mean,
    √(Σ (x − x̄_group)² / (N − groups)). It contains what the model would
    also see with perfect physics: soil preparation from run to run, the load
    varying from run to run, and the error of each trial's time average. The
    per-trial ``std_*`` fields are the fluctuation *within* a trial (the
    force ripple as the wheel rolls, 1–6 N), not the error of its mean, so
    they are reported but not used as σ.

Nominal physics
    The project's Wong–Reece rigid wheel (:mod:`vehicle_sim.terrain.wong_reece`,
    [RB] eqs. 3–11, same discretisation: Simpson's rule on the rear and front
    flow regions, ``DEFAULT_SIMPSON_POINTS`` nodes each, contact angle the
    smallest root of eq. 7 by a bracketing scan and Illinois iteration, skid
    by the anti-symmetry eqs. 10–11) with the rig authors' soil:

    * pressure–sinkage σ = k z^n with one modulus k = 8e3 kN/m^(n+2) and
      n = 1.46 (their ``set_soil_params.m``: σ[kPa] = k[kN/m^(n+2)] z[m]^n).
      In Bekker's form σ = (k_c/b + k_φ) z^n this is k_c = 0, k_φ = 8e6 N/m^(n+2)
      (the cohesive term is folded into the one modulus; nothing is lost for a
      single wheel width), i.e. the model's k1 = 0, k2 = k_φ b^(n−1);
    * cohesion c = 1 kPa, friction angle φ = 29°, shear modulus K = 21 mm
      (the values their README gives; their own smooth-wheel tuning used
      K = 10 mm and n0 = 1.4, with a slip-dependent n, reported here as a
      candidate effect, not as the nominal);
    * θ_m = θ0 (c1 + c2 i) with the project's c1 = 0.18, c2 = 0.32 (Wong's
      loose sand; the authors fitted theirs, which is the candidate
      ``max_stress_angle``); no rear contact (exit angle 0).

    Their soil specific weight 13.0 kN/m³ enters only their side-wall
    bulldozing term at β ≠ 0, which the planar model does not have.

    Sinkage: z = r (1 − cos θ0) below the undisturbed surface, with θ0 of the
    trial's own slip for i ≥ 0 and of slip −i in skid (the state the
    anti-symmetry mirrors, as :func:`~vehicle_sim.terrain.wong_reece.wheel_forces` returns it).

Candidate effects (fitted on some trials, scored on others)
    From the rover catalogue (:data:`vehicle_sim.effects.CATALOGUE` ``["rover"]``),
    the effects that act on a single smooth wheel, with the catalogue's fit ranges:

    * ``slip_sinkage``: k_eff = k/(1 + c|i|), implemented as the rover plant
      does (forces at W (1 + c|i|), divided by 1 + c|i|; θ0 of the scaled load).
    * ``soil_change``: the soil differs from the authors' values. Its four
      parameters (cohesion scale, friction-angle change, scale of the moduli
      k_c and k_φ, scale of the shear modulus K) are offered one at a time,
      ``soil_change_cohesion``, ``soil_change_friction_angle``,
      ``soil_change_modulus``, ``soil_change_shear_modulus`` (the engine pairs
      them when one does not suffice; all four at once are not identifiable
      from two channels: standard errors of tens). The catalogue's change
      *distance* has no meaning for separate steady-state trials on one
      prepared soil and is left out.
    * ``load_cell_bias``: constant offset of the drawbar-pull axis (N).
    * ``load_cell_crosstalk``: each force axis reads c times the other:
      DP_meas = DP + c W, W_meas = W + c DP (the measured W is the model's input,
      so W = W_meas − c DP is solved by fixed-point iteration).

    * ``grousers`` (a grousered wheel only, :class:`WheelGeometry`): the
      soil between the grousers moves with the wheel and is sheared on the
      cylinder through the tips, r + h_e, at the tip slip (the rover plant's
      mechanism, :func:`tip_slip`); the effective height h_e is fitted in
      [0, h_g] (h_g the wheel's grouser height; sparse grousers trap less
      soil). The sinkage is the tip circle's (the rig zeroes it with the
      tips on the surface).

    Not applicable: ``grousers`` on a smooth wheel, ``vertical_velocity``,
    ``imu_bias``, ``sensor_delay`` (no body, no IMU, trial means).

    Added for the rig, each a physical mechanism of a smooth wheel in sand:

    * ``sinkage_exponent``: n of the pressure–sinkage law (k's numerical value
      in N/m^(n+2) kept, as the authors do).
    * ``slip_exponent``: slip-dependent sinkage exponent n = n0 + n1 i (drive)
      or n0 + n2 |i| (skid), the authors' and Ding et al.'s slip-sinkage.
    * ``rear_contact``: the soil rebounds behind the wheel: exit angle
      θ_r = −λ θ0 (λ ≥ 0), rear region [θ_r, θ_m] mapped onto the front profile
      by θ* = θ0 − (θ − θ_r)/(θ_m − θ_r) (θ0 − θ_m) (the project's eq. 5 for θ_r = 0).
    * ``max_stress_angle``: c1, c2 of θ_m = θ0 (c1 + c2 i).
    * ``sinkage_offset``: the rig's sinkage zero (the wheel touching the
      prepared surface) is off by a constant (mm).
    * ``bulldozing`` (issue 22: what the braking data call for): the soil
      wedge a skidding wheel pushes ahead, κ × Wong's bulldozing resistance
      b (0.67 c z K_pc + 0.5 γ z² K_pγ) at the model's sinkage z, mobilised
      by the skid like the Janosi–Hanamoto shear, 1 − exp(−|i| r θ0/K), zero
      in drive (:func:`bulldozing_resistance`); κ fitted in [0, 3], physically
      0–1.5 (1: the full passive wedge).

    Physical ranges (:data:`PHYSICAL_RANGES`): a fit outside them, or at a
    bound of its fit range, is flagged in the report.
    * ``skid_stresses`` (a switch): in braking, the stresses of eqs. 3–9
      evaluated at the skid itself, with the Janosi–Hanamoto shear odd in the
      shear displacement (τ opposes the rim's motion relative to the soil) and
      θ_m = c1 θ0 (Wong's θ_m law is for driven slip), instead of the
      anti-symmetry of eqs. 10–11; the sinkage is then that of the skidding
      wheel (eq. 7 at the skid, where the reversed shear pushes the wheel down).

Driver (``python -m terrain_analysis.sim2real.single_wheel --data DIR --out DIR [--file F] [--radius R]
[--width B] [--grousers N --grouser-height H]``): any trial file of the rig's layout (``all_results``
with the fields above), the wheel's geometry as options (default: the smooth wheel).
    Writes ``single_wheel.md`` (a section for ``docs/results/sim2real.md``),
    ``single_wheel.json`` and ``single_wheel_fit.png``:

    * *where*: residual rig − model per slip regime (braking i < −0.1, low
      slip, high slip i > 0.3) for the nominal model and each analysis' best;
    * the model's stresses at the *measured* sinkage
      (:func:`consistency_at_measured_sinkage`), and the strongest braking
      resistance any re-parameterised Wong–Reece wheel can give at the locked
      wheel's measured sinkage and load (:func:`strongest_stress_field`);
    * *which effect*: the engine (:func:`~terrain_analysis.sim2real.attribution.attribute`)
      on the splits of :func:`analyses` (alternate slips; drive → braking;
      braking → drive; drive trials alone), the held-out trials given as its
      test mask;
    * the baseline (issue 22): every verdict against a slip-binned mean
      fitted on the same training trials and scored on the same held-out
      trials (:func:`slip_binned_baseline`, :func:`baseline_comparison`);
    * identifiability on the rig's own design (:func:`identifiability`):
      simulated trials with one effect each, diagnosed blind (``--validate N``
      seeds, default 2; 0 skips it).

    A run takes about 1 min of CPU with the identifiability check (30 s without).

Units: SI inside the physics (m, rad, Pa, N); sinkage channel in mm.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from terrain_analysis.sim2real.model import Candidate, Channel, FitParameter
from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.cli import cli_main
from terrain_estimation.jit import compiled

__all__ = [
    "Analysis",
    "DATA_FILE",
    "NOMINAL",
    "REGIMES",
    "BASELINE_BIN_WIDTH",
    "PHYSICAL_RANGES",
    "RIG_WHEEL",
    "RIG_WHEEL_RADIUS",
    "RIG_WHEEL_WIDTH",
    "RigTrials",
    "SingleWheelModel",
    "WheelGeometry",
    "WheelSoil",
    "analyses",
    "baseline_comparison",
    "bearing_capacity_factors",
    "bulldozing_resistance",
    "candidates",
    "consistency_at_measured_sinkage",
    "identifiability",
    "load_rig_trials",
    "main",
    "pooled_replicate_std",
    "run",
    "steady_state",
    "strongest_stress_field",
    "slip_binned_baseline",
    "synthetic_trials",
    "tip_slip",
]

FloatArray = NDArray[np.float64]

DATA_FILE = "all_smooth_data.mat"
RIG_WHEEL_RADIUS = 0.058
"""Rig wheel radius r (m)."""
RIG_WHEEL_WIDTH = 0.05
"""Rig wheel width b (m)."""
RIG_SOIL_UNIT_WEIGHT = 13.0e3
"""Specific weight γ of the rig's soil (N/m³; the authors' 13.0 kN/m³)."""

_SIMPSON_POINTS = 9  # = vehicle_sim.terrain.wong_reece.DEFAULT_SIMPSON_POINTS (tested equal)
_SCAN_POINTS = 48
_HALF_PI = 0.5 * math.pi


# ---------------------------------------------------------------------------
# Physics
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class WheelSoil:
    """Wheel, soil and effect parameters of one evaluation (all scalars; SI).

    Attributes:
        k_c, k_phi: Bekker moduli (N/m^(n+1), N/m^(n+2)); σ = (k_c/b + k_φ) z^n.
        n: Sinkage exponent at zero slip (–).
        n_slip, n_skid: Slip dependence of n: n + n_slip i (i ≥ 0), n + n_skid |i| (i < 0).
        cohesion: c (Pa).
        friction_angle: φ (rad).
        shear_modulus: K (m).
        c1, c2: θ_m = θ0 (c1 + c2 i).
        rear_ratio: λ of the exit angle θ_r = −λ θ0.
        slip_sinkage: c of k_eff = k/(1 + c|i|) (rover plant's implementation).
        skid_stresses: evaluate the stresses at the skid itself instead of eqs. 10–11.
        radius, width: r, b (m).
        grouser_height: h_e, the effective grouser height (m): the soil is sheared
            on the cylinder through the grouser tips, r + h_e, at the tip slip
            (0: a smooth rim; :func:`tip_slip`).
        bulldozing: κ, the fraction of Wong's passive bulldozing resistance
            mobilised ahead of a skidding wheel (0: none; :func:`bulldozing_resistance`).
        unit_weight: γ, the soil's specific weight (N/m³), for the bulldozing wedge.
    """

    k_c: float = 0.0
    k_phi: float = 8.0e6
    n: float = 1.46
    n_slip: float = 0.0
    n_skid: float = 0.0
    cohesion: float = 1.0e3
    friction_angle: float = math.radians(29.0)
    shear_modulus: float = 0.021
    c1: float = 0.18
    c2: float = 0.32
    rear_ratio: float = 0.0
    slip_sinkage: float = 0.0
    skid_stresses: bool = False
    radius: float = RIG_WHEEL_RADIUS
    width: float = RIG_WHEEL_WIDTH
    grouser_height: float = 0.0
    bulldozing: float = 0.0
    unit_weight: float = RIG_SOIL_UNIT_WEIGHT


NOMINAL = WheelSoil()
"""The rig authors' soil (README values) and the rig's wheel, every effect off."""


@dataclass(frozen=True)
class WheelGeometry:
    """The rig wheel's geometry (an option of the driver: the rig has been run with other wheels).

    Attributes:
        radius: Rim radius r (m), 0.005–2.
        width: Rim width b (m), 0.005–2.
        grouser_count: Number of grousers (lugs) on the rim, 0 (smooth) to 360.
        grouser_height: Their height above the rim (m), 0 for a smooth wheel,
            otherwise > 0 and below half the radius.

    Raises:
        Sim2RealError: a value out of its range, or grousers with no height (or
            a height with no grousers), naming the option and the value.
    """

    radius: float = RIG_WHEEL_RADIUS
    width: float = RIG_WHEEL_WIDTH
    grouser_count: int = 0
    grouser_height: float = 0.0

    def __post_init__(self) -> None:
        for name in ("radius", "width"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and 0.005 <= value <= 2.0):
                raise Sim2RealError(f"wheel {name} must be in [0.005, 2] m, got {value!r}")
        count, height = self.grouser_count, self.grouser_height
        if isinstance(count, bool) or not isinstance(count, int | np.integer) or not 0 <= count <= 360:
            raise Sim2RealError(f"grouser count must be a whole number in [0, 360], got {count!r}")
        if not (isinstance(height, int | float) and math.isfinite(height) and height >= 0.0):
            raise Sim2RealError(f"grouser height must be a finite length >= 0 m, got {height!r}")
        if (count > 0) != (height > 0.0):
            raise Sim2RealError(
                f"grousers need both a count and a height: got count {count} and height {height} m "
                "(a smooth wheel has 0 and 0)"
            )
        if height >= 0.5 * self.radius:
            raise Sim2RealError(
                f"grouser height {height} m must be below half the wheel radius ({0.5 * self.radius:g} m)"
            )

    @property
    def grousered(self) -> bool:
        """True if the wheel has grousers."""
        return self.grouser_count > 0

    @property
    def grouser_spacing(self) -> float:
        """Arc length between grouser tips (m); inf for a smooth wheel."""
        if not self.grousered:
            return math.inf
        return 2.0 * math.pi * (self.radius + self.grouser_height) / self.grouser_count

    def describe(self) -> str:
        """One line for the report."""
        text = f"r = {1e3 * self.radius:g} mm, b = {1e3 * self.width:g} mm"
        if self.grousered:
            return (
                f"{text}, {self.grouser_count} grousers {1e3 * self.grouser_height:g} mm high "
                f"({1e3 * self.grouser_spacing:.0f} mm apart at the tips)"
            )
        return f"{text}, smooth"


RIG_WHEEL = WheelGeometry()
"""The smooth wheel of ``all_smooth_data.mat`` (r = 58 mm, b = 50 mm)."""


def _simpson_weights(points: int) -> FloatArray:
    w = np.ones(points)
    w[1:-1:2] = 4.0
    w[2:-1:2] = 2.0
    return w / (3.0 * (points - 1))


_WEIGHTS = _simpson_weights(_SIMPSON_POINTS)


@compiled
def _rim_row(
    theta0: float, slip: float, n: float, soil: FloatArray, weights: FloatArray
) -> tuple[float, float, float]:  # pragma: no cover - compiled (tested through steady_state)
    """(W, DP, τ_R) of [RB] eqs. 7–9 at one (θ0, i, n); exit angle −λ θ0.

    For i ≥ 0 exactly the project's model. For i < 0 (only with ``skid_stresses``)
    the stresses are evaluated at the skid itself: θ_m = c1 θ0 (Wong's slip law
    θ_m = θ0 (c1 + c2 i) is not extrapolated into skid) and τ odd in j.

    ``soil`` = (stiffness k_c/b + k_φ, c, tan φ, K, c1, c2, λ, r, b). The same
    Simpson discretisation as :mod:`vehicle_sim.terrain.wong_reece`: nodes
    s ∈ [0, 1] at θ_r + s (θ_m − θ_r) behind and θ_m + s (θ0 − θ_m) in front
    of θ_m; the rear's eq.-5 angle θ* = θ0 − s (θ0 − θ_m).
    """
    stiffness, cohesion, tan_phi, shear_k, c1, c2, rear, r, b = (
        soil[0],
        soil[1],
        soil[2],
        soil[3],
        soil[4],
        soil[5],
        soil[6],
        soil[7],
        soil[8],
    )
    points = weights.size
    tm = theta0 * (c1 + c2 * max(slip, 0.0))
    tr = -rear * theta0
    cos0 = math.cos(theta0)
    sin0 = math.sin(theta0)
    load = 0.0
    dp = 0.0
    torque = 0.0
    for region in range(2):
        for k in range(points):
            s = k / (points - 1)
            if region == 0:
                angle = tr + s * (tm - tr)
                equivalent = theta0 - s * (theta0 - tm)
                dtheta = weights[k] * (tm - tr)
            else:
                angle = tm + s * (theta0 - tm)
                equivalent = angle
                dtheta = weights[k] * (theta0 - tm)
            base = r * (math.cos(equivalent) - cos0)
            sigma = stiffness * base**n if base > 0.0 else 0.0
            j = r * ((theta0 - angle) - (1.0 - slip) * (sin0 - math.sin(angle)))
            # Janosi–Hanamoto, odd in j (j < 0 only in skid: the shear opposes the motion).
            tau = math.copysign((cohesion + sigma * tan_phi) * -math.expm1(-abs(j) / shear_k), j)
            ca = math.cos(angle)
            sa = math.sin(angle)
            load += dtheta * (sigma * ca + tau * sa)
            dp += dtheta * (tau * ca - sigma * sa)
            torque += dtheta * tau
    br = b * r
    return br * load, br * dp, br * r * torque


@compiled
def _contact_angle_row(
    load: float, slip: float, n: float, soil: FloatArray, weights: FloatArray, scan_points: int
) -> float:  # pragma: no cover - compiled (tested through steady_state)
    """Smallest θ0 ∈ [0, π/2] with W(θ0) = load (eq. 7), saturated at π/2 (overload).

    A scan of ``scan_points`` intervals brackets the first crossing, an
    Illinois iteration refines it (as :func:`vehicle_sim.terrain.wong_reece.contact_angle`).
    """
    if load <= 0.0:
        return 0.0
    h = 0.5 * math.pi / scan_points
    lo = 0.0
    f_lo = -load
    hi = 0.0
    f_hi = -load
    found = False
    for k in range(1, scan_points + 1):
        hi = k * h
        f_hi = _rim_row(hi, slip, n, soil, weights)[0] - load
        if f_hi >= 0.0:
            found = True
            break
        lo = hi
        f_lo = f_hi
    if not found:
        return 0.5 * math.pi
    if f_hi == 0.0:
        return hi
    last = 0
    theta = hi
    for _ in range(100):
        denom = f_hi - f_lo
        if denom == 0.0:
            break
        theta = min(max(hi - f_hi * (hi - lo) / denom, lo), hi)
        res = _rim_row(theta, slip, n, soil, weights)[0] - load
        if abs(res) <= 1e-12 * load or hi - lo <= 1e-14:
            return theta
        if res < 0.0:
            if last == -1:
                f_hi *= 0.5
            lo = theta
            f_lo = res
            last = -1
        else:
            if last == 1:
                f_lo *= 0.5
            hi = theta
            f_hi = res
            last = 1
    return theta


@compiled
def _steady_rows(
    load: FloatArray,
    slip: FloatArray,
    n0: float,
    n_slip: float,
    n_skid: float,
    slip_sinkage: float,
    direct_skid: bool,
    soil: FloatArray,
    weights: FloatArray,
    scan_points: int,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled (tested through steady_state)
    rows = load.size
    dp = np.empty(rows)
    theta = np.empty(rows)
    for k in range(rows):
        i = min(max(slip[k], -1.0), 1.0)
        mag = abs(i)
        scale = 1.0 + slip_sinkage * mag
        w = max(load[k], 0.0) * scale
        n = n0 + (n_skid if i < 0.0 else n_slip) * mag
        evaluated = i if direct_skid else mag
        t0 = _contact_angle_row(w, evaluated, n, soil, weights, scan_points)
        d = _rim_row(t0, evaluated, n, soil, weights)[1]
        if i < 0.0 and not direct_skid:
            t00 = _contact_angle_row(w, 0.0, n0, soil, weights, scan_points)
            d = -d + 2.0 * _rim_row(t00, 0.0, n0, soil, weights)[1]
        dp[k] = d / scale
        theta[k] = t0
    return dp, theta


def _soil_vector(p: WheelSoil) -> FloatArray:
    return np.array(
        [
            p.k_c / p.width + p.k_phi,
            p.cohesion,
            math.tan(p.friction_angle),
            p.shear_modulus,
            p.c1,
            p.c2,
            p.rear_ratio,
            p.radius,
            p.width,
        ]
    )


def steady_state(load: ArrayLike, slip: ArrayLike, p: WheelSoil = NOMINAL) -> tuple[FloatArray, FloatArray]:
    """Drawbar pull DP (N) and sinkage z (m) of the wheel at loads W (N) and slips −1 ≤ i ≤ 1.

    Slip (i ≥ 0): θ0 from eq. 7, DP from eq. 8. Skid (i < 0): DP(i) = −DP(−i) + 2 DP(0)
    (eq. 10) under the same load, z from θ0 at −i; with a slip-dependent
    exponent the mirrored state has n(i) and DP(0) has n0. Slip-sinkage
    scales the load and the forces as the rover plant does (forces at
    W (1 + c|i|), divided by 1 + c|i|). Overload saturates at θ0 = π/2.
    Inputs broadcast; outputs have their shape.
    """
    load_, slip_ = np.broadcast_arrays(np.asarray(load, dtype=float), np.asarray(slip, dtype=float))
    rim_slip = np.ascontiguousarray(slip_.ravel())
    shear = p
    if p.grouser_height > 0.0:
        # The soil between the grousers moves with the wheel: shear on the tip cylinder at the tip slip.
        shear = dataclasses.replace(p, radius=p.radius + p.grouser_height)
        rim_slip = tip_slip(rim_slip, p.radius, p.grouser_height)
    dp, theta0 = _steady_rows(
        np.ascontiguousarray(load_.ravel()),
        rim_slip,
        float(p.n),
        float(p.n_slip),
        float(p.n_skid),
        float(p.slip_sinkage),
        bool(p.skid_stresses),
        _soil_vector(shear),
        _WEIGHTS,
        _SCAN_POINTS,
    )
    sinkage = shear.radius * (1.0 - np.cos(theta0))
    if p.bulldozing > 0.0:
        dp = dp - p.bulldozing * bulldozing_resistance(sinkage, np.ascontiguousarray(slip_.ravel()), theta0, shear)
    return dp.reshape(load_.shape), sinkage.reshape(load_.shape)


def tip_slip(slip: ArrayLike, radius: float, grouser_height: float) -> FloatArray:
    """Slip of the grouser tips (radius r + h) for the rim slip i (the rig's definition, −1 ≤ i ≤ 1).

    With ρ = V_rim/V_x (1/(1 − i) in drive, 1 + i in skid) the tips move at
    ρ_t = ρ (r + h)/r, and i_t = (ρ_t − 1)/max(1, ρ_t). In drive this is the
    rover plant's i_g = 1 − (1 − i) r/(r + h).
    """
    i = np.clip(np.asarray(slip, dtype=float), -1.0, 1.0)
    with np.errstate(divide="ignore"):
        rho = np.where(i >= 0.0, 1.0 / np.maximum(1.0 - i, 1e-9), 1.0 + i)
    rho_t = rho * (radius + grouser_height) / radius
    return np.asarray((rho_t - 1.0) / np.maximum(1.0, rho_t), dtype=float)


def bearing_capacity_factors(friction_angle: float) -> tuple[float, float, float]:
    """(N_c, N_q, N_γ) of a strip footing (Prandtl–Reissner N_q, N_c; Vesić's N_γ) at friction angle φ (rad)."""
    tan_phi = math.tan(max(friction_angle, 1e-6))
    n_q = math.exp(math.pi * tan_phi) * math.tan(0.25 * math.pi + 0.5 * friction_angle) ** 2
    n_c = (n_q - 1.0) / tan_phi
    n_gamma = 2.0 * (n_q + 1.0) * tan_phi
    return n_c, n_q, n_gamma


def bulldozing_resistance(sinkage: ArrayLike, slip: ArrayLike, theta0: ArrayLike, p: WheelSoil) -> FloatArray:
    """Resistance (N, ≥ 0) of the soil wedge a skidding wheel pushes ahead, mobilised by the skid.

    Wong's bulldozing resistance of a wheel with sinkage z (Bekker's passive
    earth pressure on a vertical blade of width b; Wong, *Theory of Ground
    Vehicles*, ch. 2)::

        R_b = b (0.67 c z K_pc + 0.5 γ z² K_pγ),
        K_pc = (N_c − tan φ) cos² φ,  K_pγ = (2 N_γ / tan φ + 1) cos² φ

    (:func:`bearing_capacity_factors`). The wedge builds only when the rim
    slides *forward* over the soil, i.e. in skid (i < 0): a driven wheel
    throws the soil back. It is mobilised like the Janosi–Hanamoto shear,
    by the soil's displacement ahead of the wheel over the contact,
    j = |i| r θ0: R = R_b (1 − exp(−j/K)) for i < 0, 0 otherwise. No
    parameter is new (c, φ, γ, K are the soil's); the effect's coefficient
    κ (:attr:`WheelSoil.bulldozing`) scales R (1: the full passive wedge).
    """
    z = np.asarray(sinkage, dtype=float)
    i = np.asarray(slip, dtype=float)
    theta = np.asarray(theta0, dtype=float)
    n_c, _, n_gamma = bearing_capacity_factors(p.friction_angle)
    tan_phi = math.tan(max(p.friction_angle, 1e-6))
    cos2 = math.cos(p.friction_angle) ** 2
    k_pc = (n_c - tan_phi) * cos2
    k_pg = (2.0 * n_gamma / tan_phi + 1.0) * cos2
    full = p.width * (0.67 * p.cohesion * z * k_pc + 0.5 * p.unit_weight * z**2 * k_pg)
    mobilised = np.where(i < 0.0, -np.expm1(-np.abs(i) * p.radius * theta / p.shear_modulus), 0.0)
    return np.asarray(full * mobilised, dtype=float)


# ---------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class RigTrials:
    """The β = 0 trials, ordered by slip then trial number.

    Attributes:
        slip: i (–).
        load: W = −avg_Fz (N).
        drawbar_pull: DP = −avg_Fy (N).
        drawbar_pull_ripple: std_Fy, within-trial fluctuation (N).
        sinkage: z = −avg_Z (mm, positive down).
        sinkage_ripple: std_Z (mm).
        trial: trial_num of the file.
        group: index of the commanded-slip group (repeated trials share it).
        total_trials: trials in the file (all β).
        betas: the distinct β of the file (deg).
        source: the file read.
    """

    slip: FloatArray
    load: FloatArray
    drawbar_pull: FloatArray
    drawbar_pull_ripple: FloatArray
    sinkage: FloatArray
    sinkage_ripple: FloatArray
    trial: FloatArray
    group: NDArray[np.int_]
    total_trials: int
    betas: tuple[float, ...]
    source: str

    @property
    def size(self) -> int:
        return int(self.slip.size)

    def subset(self, keep: NDArray[np.bool_]) -> RigTrials:
        """The trials where ``keep`` is True (groups renumbered)."""
        keep = np.asarray(keep, dtype=bool)
        if keep.shape != self.slip.shape or not keep.any():
            raise ValueError(f"subset mask must select some of the {self.size} trials")
        return dataclasses.replace(
            self,
            slip=self.slip[keep],
            load=self.load[keep],
            drawbar_pull=self.drawbar_pull[keep],
            drawbar_pull_ripple=self.drawbar_pull_ripple[keep],
            sinkage=self.sinkage[keep],
            sinkage_ripple=self.sinkage_ripple[keep],
            trial=self.trial[keep],
            group=np.unique(self.group[keep], return_inverse=True)[1].astype(int),
        )


_FIELDS = ("slip", "beta", "avg_Fy", "std_Fy", "avg_Fz", "avg_Z", "std_Z")


def _slip_groups(slip: FloatArray, tolerance: float = 0.02) -> NDArray[np.int_]:
    """Group index of each (sorted) slip: a new group where the gap exceeds ``tolerance``."""
    if slip.size == 0:
        return np.zeros(0, dtype=int)
    return np.concatenate([[0], np.cumsum(np.diff(slip) > tolerance)]).astype(int)


def load_rig_trials(folder: str | Path, file: str | None = None) -> RigTrials:
    """Read a trial file of the rig's layout and keep the β = 0 trials.

    Args:
        folder: A folder holding the file, or the file itself.
        file: The file's name in ``folder`` (default :data:`DATA_FILE`, the
            smooth wheel; any file with the same layout, e.g. another wheel's
            ``all_results``, is read the same way).

    Raises:
        Sim2RealError: missing file or field, or a value that is not finite or
            out of its physical range (names the file, trial, field and value).
    """
    import scipy.io

    given = Path(folder)
    path = given if given.is_file() and file is None else given / (file or DATA_FILE)
    if not path.is_file():
        raise Sim2RealError(f"{path}: no such file (a CMU single-wheel trial file, e.g. {DATA_FILE})")
    try:
        mat = scipy.io.loadmat(str(path), squeeze_me=True, struct_as_record=False)
    except Exception as exc:  # scipy raises several types for a damaged file
        raise Sim2RealError(f"{path}: not a readable MATLAB file ({exc})") from exc
    if "all_results" not in mat:
        raise Sim2RealError(
            f"{path}: no variable 'all_results' (has {sorted(k for k in mat if not k.startswith('_'))})"
        )
    trials = np.atleast_1d(mat["all_results"])
    rows = []
    for k, t in enumerate(trials):
        values = {}
        for name in _FIELDS:
            if not hasattr(t, name):
                raise Sim2RealError(f"{path}: trial {k} has no field {name!r}")
            try:
                v = float(getattr(t, name))
            except (TypeError, ValueError):
                raise Sim2RealError(f"{path}: trial {k} field {name!r} is not a number: {getattr(t, name)!r}") from None
            if not math.isfinite(v):
                raise Sim2RealError(f"{path}: trial {k} field {name!r} = {v} is not finite")
            values[name] = v
        if not -1.0 <= values["slip"] <= 1.0:
            raise Sim2RealError(f"{path}: trial {k} field 'slip' = {values['slip']} outside [-1, 1]")
        if values["avg_Fz"] >= 0.0:
            raise Sim2RealError(f"{path}: trial {k} field 'avg_Fz' = {values['avg_Fz']} N: the load must be < 0 (down)")
        values["trial"] = float(getattr(t, "trial_num", k))
        rows.append(values)
    betas = tuple(sorted({r["beta"] for r in rows}))
    planar = [r for r in rows if abs(r["beta"]) < 0.5]
    if len(planar) < 6:
        raise Sim2RealError(f"{path}: only {len(planar)} trials at beta = 0 (field 'beta'); need at least 6")
    planar.sort(key=lambda r: (r["slip"], r["trial"]))
    slip = np.array([r["slip"] for r in planar])
    return RigTrials(
        slip=slip,
        load=-np.array([r["avg_Fz"] for r in planar]),
        drawbar_pull=-np.array([r["avg_Fy"] for r in planar]),
        drawbar_pull_ripple=np.array([r["std_Fy"] for r in planar]),
        sinkage=-np.array([r["avg_Z"] for r in planar]),
        sinkage_ripple=np.array([r["std_Z"] for r in planar]),
        trial=np.array([r["trial"] for r in planar]),
        group=_slip_groups(slip),
        total_trials=len(rows),
        betas=betas,
        source=str(path),
    )


def pooled_replicate_std(values: FloatArray, group: NDArray[np.int_]) -> tuple[float, int]:
    """Pooled standard deviation of repeated trials about their group means, and its degrees of freedom."""
    resid = np.zeros_like(values)
    groups = np.unique(group)
    for g in groups:
        sel = group == g
        resid[sel] = values[sel] - values[sel].mean()
    dof = values.size - groups.size
    if dof < 1:
        raise Sim2RealError("no repeated trials: the noise budget needs at least two trials at one slip")
    return float(math.sqrt(float(np.sum(resid**2)) / dof)), int(dof)


# ---------------------------------------------------------------------------
# Candidates
# ---------------------------------------------------------------------------


def _catalogue_parameter(effect: str, name: str) -> FitParameter:
    from vehicle_sim.effects import CATALOGUE

    p = CATALOGUE["rover"][effect].parameter(name)
    scale = abs(p.typical - p.off) or 0.1 * (p.fit_range[1] - p.fit_range[0])
    return FitParameter(p.name, p.unit, float(p.off), p.fit_range, float(scale))


_SOIL_PARAMETERS = {
    "soil_change_cohesion": "soil_change_cohesion_scale",
    "soil_change_friction_angle": "soil_change_friction_angle_change",
    "soil_change_modulus": "soil_change_modulus_scale",
    "soil_change_shear_modulus": "soil_change_shear_modulus_scale",
}


#: Physically plausible range of each rig candidate parameter, where narrower than its fit range:
#: a fit outside it is flagged in the report (it is not a physical explanation).
PHYSICAL_RANGES: dict[str, tuple[float, float]] = {
    "load_cell_bias_dp": (-3.0, 3.0),  # zero drift of a 100 N-class load cell after taring
    "load_cell_crosstalk": (-0.05, 0.05),
    "soil_change_cohesion_scale": (0.0, 3.0),  # dry granular soil: c of 0–3 kPa
    "soil_change_friction_angle_change": (-0.1, 0.1),
    "sinkage_offset": (-5.0, 5.0),  # mm: zeroing on a prepared surface
    "bulldozing_coefficient": (0.0, 1.5),  # up to the full passive wedge, with some surcharge
    "max_stress_angle_c1": (0.2, 0.5),  # Wong & Reece's measurements: 0.18–0.43
}


def candidates(base: WheelSoil = NOMINAL, geometry: WheelGeometry = RIG_WHEEL) -> dict[str, Candidate]:
    """The candidate effects of the rig (module docstring), with their fit ranges.

    ``grousers`` only for a grousered wheel (``geometry``): its effective
    height h_e in [0, h_g] (0: the smooth-rim nominal; h_g: all soil between
    the grousers trapped).
    """
    from vehicle_sim.effects import CATALOGUE

    rover = CATALOGUE["rover"]
    soil = tuple(_catalogue_parameter("soil_change", name) for name in _SOIL_PARAMETERS.values())
    out = {
        "slip_sinkage": Candidate(
            "slip_sinkage",
            (_catalogue_parameter("slip_sinkage", "slip_sinkage_coefficient"),),
            rover["slip_sinkage"].description,
        ),
    }
    for cand, pname in _SOIL_PARAMETERS.items():
        p = next(q for q in soil if q.name == pname)
        out[cand] = Candidate(cand, (p,), f"{rover['soil_change'].description}: {p.name} only")
    out["load_cell_bias"] = Candidate(
        "load_cell_bias",
        (FitParameter("load_cell_bias_dp", "N", 0.0, (-10.0, 10.0), 1.0),),
        "constant offset of the drawbar-pull axis of the force sensor",
    )
    out["load_cell_crosstalk"] = Candidate(
        "load_cell_crosstalk",
        (_catalogue_parameter("load_cell_crosstalk", "load_cell_crosstalk"),),
        rover["load_cell_crosstalk"].description,
    )
    out["sinkage_exponent"] = Candidate(
        "sinkage_exponent",
        (FitParameter("sinkage_exponent", "–", base.n, (0.6, 2.2), 0.2),),
        "sinkage exponent n of σ = k z^n (k's value in N/m^(n+2) kept)",
    )
    out["slip_exponent"] = Candidate(
        "slip_exponent",
        (
            FitParameter("exponent_slip_rate", "–", 0.0, (-0.5, 1.5), 0.3),
            FitParameter("exponent_skid_rate", "–", 0.0, (-0.5, 1.5), 0.3),
        ),
        "slip-dependent sinkage exponent n = n0 + n1 i (drive), n0 + n2 |i| (skid) (Ding et al.; the rig authors)",
    )
    out["rear_contact"] = Candidate(
        "rear_contact",
        (FitParameter("rear_angle_ratio", "–", 0.0, (0.0, 1.0), 0.2),),
        "soil rebound behind the wheel: exit angle θ_r = −λ θ0",
    )
    out["max_stress_angle"] = Candidate(
        "max_stress_angle",
        (
            FitParameter("max_stress_angle_c1", "–", base.c1, (0.02, 0.6), 0.1),
            FitParameter("max_stress_angle_c2", "–", base.c2, (0.0, 0.4), 0.1),
        ),
        "position of the maximum normal stress θ_m = θ0 (c1 + c2 i)",
    )
    out["skid_stresses"] = Candidate(
        "skid_stresses",
        (),
        "braking: Wong–Reece stresses evaluated at the skid itself (shear reversed) instead of the anti-symmetry "
        "DP(i) = −DP(−i) + 2 DP(0)",
    )
    out["sinkage_offset"] = Candidate(
        "sinkage_offset",
        (FitParameter("sinkage_offset", "mm", 0.0, (-10.0, 10.0), 2.0),),
        "zero of the sinkage measurement (wheel touching the prepared surface) off by a constant",
    )
    out["bulldozing"] = Candidate(
        "bulldozing",
        (FitParameter("bulldozing_coefficient", "–", 0.0, (0.0, 3.0), 0.5),),
        "braking resistance of the soil wedge a skidding wheel pushes ahead: κ × Wong's bulldozing resistance "
        "b (0.67 c z K_pc + 0.5 γ z² K_pγ), mobilised by the skid as 1 − exp(−|i| r θ0 / K)",
    )
    if geometry.grousered:
        h = geometry.grouser_height
        out["grousers"] = Candidate(
            "grousers",
            (FitParameter("grouser_effective_height", "m", 0.0, (0.0, h), 0.5 * h),),
            f"{rover['grousers'].description}; effective height h_e in [0, {h:g} m] (the wheel's grousers)",
        )
    return out


def _apply(
    base: WheelSoil, effects: Mapping[str, Mapping[str, float]], geometry: WheelGeometry = RIG_WHEEL
) -> tuple[WheelSoil, dict[str, float]]:
    """Wheel–soil parameters with ``effects`` applied, and the sensor-level terms (bias, crosstalk, offset)."""
    sensor = {"bias": 0.0, "crosstalk": 0.0, "offset": 0.0}
    changes: dict[str, Any] = {}

    def value(effect: str, name: str, default: float) -> float:
        return float(effects[effect].get(name, default))

    for effect in effects:
        if effect == "slip_sinkage":
            changes["slip_sinkage"] = value(effect, "slip_sinkage_coefficient", 0.0)
        elif effect in _SOIL_PARAMETERS:
            cohesion = changes.get("cohesion", base.cohesion) * value(effect, "soil_change_cohesion_scale", 1.0)
            phi = changes.get("friction_angle", base.friction_angle) + value(
                effect, "soil_change_friction_angle_change", 0.0
            )
            modulus = value(effect, "soil_change_modulus_scale", 1.0)
            changes["cohesion"] = cohesion
            changes["friction_angle"] = phi
            changes["k_c"] = changes.get("k_c", base.k_c) * modulus
            changes["k_phi"] = changes.get("k_phi", base.k_phi) * modulus
            changes["shear_modulus"] = changes.get("shear_modulus", base.shear_modulus) * value(
                effect, "soil_change_shear_modulus_scale", 1.0
            )
        elif effect == "load_cell_bias":
            sensor["bias"] += value(effect, "load_cell_bias_dp", 0.0)
        elif effect == "load_cell_crosstalk":
            sensor["crosstalk"] += value(effect, "load_cell_crosstalk", 0.0)
        elif effect == "sinkage_exponent":
            changes["n"] = value(effect, "sinkage_exponent", base.n)
        elif effect == "slip_exponent":
            changes["n_slip"] = value(effect, "exponent_slip_rate", 0.0)
            changes["n_skid"] = value(effect, "exponent_skid_rate", 0.0)
        elif effect == "rear_contact":
            changes["rear_ratio"] = value(effect, "rear_angle_ratio", 0.0)
        elif effect == "max_stress_angle":
            changes["c1"] = value(effect, "max_stress_angle_c1", base.c1)
            changes["c2"] = value(effect, "max_stress_angle_c2", base.c2)
        elif effect == "sinkage_offset":
            sensor["offset"] += value(effect, "sinkage_offset", 0.0)
        elif effect == "skid_stresses":
            changes["skid_stresses"] = True
        elif effect == "bulldozing":
            changes["bulldozing"] = value(effect, "bulldozing_coefficient", 0.0)
        elif effect == "grousers":
            if not geometry.grousered:
                raise ValueError(
                    "single-wheel effect 'grousers' does not apply: the wheel is smooth "
                    "(give the wheel's grouser count and height)"
                )
            changes["grouser_height"] = min(
                max(value(effect, "grouser_effective_height", 0.0), 0.0), 0.49 * base.radius
            )
        else:
            raise ValueError(f"unknown single-wheel effect {effect!r}; known: {sorted(candidates(base))}")
    if changes.get("friction_angle", base.friction_angle) <= 0.0:
        changes["friction_angle"] = 1e-6
    return dataclasses.replace(base, **changes), sensor


# ---------------------------------------------------------------------------
# Replay model
# ---------------------------------------------------------------------------


def _regime(slip: float) -> str:
    if slip < -0.1:
        return "braking"
    if slip <= 0.3:
        return "low slip"
    return "high slip"


REGIMES = ("braking", "low slip", "high slip")
"""Slip regimes of the where-table: braking i < −0.1, low slip −0.1 ≤ i ≤ 0.3, high slip i > 0.3."""


@dataclass
class SingleWheelModel:
    """Replay model of the rig's β = 0 trials (module docstring)."""

    trials: RigTrials
    base: WheelSoil = NOMINAL
    noise: Mapping[str, tuple[float, int]] | None = None
    geometry: WheelGeometry = RIG_WHEEL
    vehicle: str = "cmu_single_wheel"
    channels: Sequence[Channel] = field(init=False)
    times: Mapping[str, FloatArray] = field(init=False)
    measured: Mapping[str, FloatArray] = field(init=False)
    nuisance: Sequence[FitParameter] = field(init=False)
    candidates: Mapping[str, Candidate] = field(init=False)
    regimes: Mapping[str, tuple[FloatArray, FloatArray]] = field(init=False)
    warmup: float = 0.0
    notes: list[str] = field(init=False)
    noise_dof: dict[str, int] = field(init=False)

    def __post_init__(self) -> None:
        t = self.trials
        g = self.geometry
        if (self.base.radius, self.base.width) != (g.radius, g.width):
            self.base = dataclasses.replace(self.base, radius=g.radius, width=g.width)
        if self.noise is None:
            sd_dp, dof_dp = pooled_replicate_std(t.drawbar_pull, t.group)
            sd_z, dof_z = pooled_replicate_std(t.sinkage, t.group)
        else:
            (sd_dp, dof_dp), (sd_z, dof_z) = self.noise["drawbar_pull"], self.noise["sinkage"]
        source = Path(t.source).name
        self.channels = [
            Channel("drawbar_pull", f"{source}: -avg_Fy", "N", sd_dp),
            Channel("sinkage", f"{source}: -avg_Z", "mm", sd_z),
        ]
        index = np.arange(t.size, dtype=float)
        self.times = {"drawbar_pull": index, "sinkage": index}
        self.measured = {"drawbar_pull": t.drawbar_pull, "sinkage": t.sinkage}
        self.nuisance = []
        self.candidates = candidates(self.base, g)
        self.regimes = {"slip (–)": (index, t.slip), "load (N)": (index, t.load)}
        self.noise_dof = {"drawbar_pull": dof_dp, "sinkage": dof_z}
        self.notes = [
            f"{t.size} trials at beta = 0 of {t.total_trials} (beta = {', '.join(f'{b:g}' for b in t.betas)} deg); "
            "the others are left out: the model is planar",
            f"samples are trials ordered by slip; noise budget = pooled spread of repeated trials: "
            f"DP {sd_dp:.3f} N, sinkage {sd_z:.3f} mm ({dof_dp} degrees of freedom)",
            f"wheel: {g.describe()}"
            + (
                "; the nominal model shears on the rim, the grousers effect on the tip cylinder"
                if g.grousered
                else "; the grousers effect does not apply (smooth wheel)"
            ),
        ]

    def predict(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, FloatArray]:
        """DP (N) and sinkage (mm) of every trial with ``effects`` added (nuisance: none)."""
        del nuisance
        p, sensor = _apply(self.base, effects, self.geometry)
        w_meas = self.trials.load
        c = sensor["crosstalk"]
        load = w_meas
        dp, z = steady_state(load, self.trials.slip, p)
        if c != 0.0:
            # W_meas = W + c DP: the true load from the measured one (contraction for |c| ≤ 0.1).
            for _ in range(4):
                load = np.maximum(w_meas - c * dp, 0.0)
                dp, z = steady_state(load, self.trials.slip, p)
        dp_meas = dp + c * load + sensor["bias"]
        z_mm = 1000.0 * z + sensor["offset"]
        return {
            "drawbar_pull": np.nan_to_num(dp_meas, nan=0.0, posinf=1e6, neginf=-1e6),
            "sinkage": np.nan_to_num(z_mm, nan=0.0, posinf=1e6, neginf=-1e6),
        }


# ---------------------------------------------------------------------------
# Driver
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Analysis:
    """One attribution run: which trials the model holds and which of them are held out.

    Attributes:
        name: Short key.
        description: The split in words.
        keep: Over all β = 0 trials: the trials of this run.
        held_out: Over the kept trials: True = scored, False = fitted.
    """

    name: str
    description: str
    keep: NDArray[np.bool_]
    held_out: NDArray[np.bool_]


def _slips_text(trials: RigTrials, groups: NDArray[np.int_]) -> str:
    return ", ".join(f"{trials.slip[trials.group == g].mean():+.2f}" for g in groups)


def analyses(trials: RigTrials) -> list[Analysis]:
    """The train/held-out splits of the driver.

    * ``alternate``: all trials; fit on every other commanded slip, score on the slips between.
    * ``drive_to_brake``: fit on i ≥ 0, score on braking (i < 0).
    * ``brake_to_drive``: fit on braking, score on i ≥ 0.
    * ``drive_only``: the i ≥ 0 trials alone (the regime the model is made for):
      fit on every other drive slip starting with the second, score on the rest
      (the engine's noise tests need ≥ 8 held-out trials per channel, so three of five slips are held out).
    """
    everything = np.ones(trials.size, dtype=bool)
    groups = np.unique(trials.group)
    brake = trials.slip < -0.01
    out = [
        Analysis(
            "alternate",
            f"all trials; fit on slips {_slips_text(trials, groups[0::2])}, "
            f"score on {_slips_text(trials, groups[1::2])}",
            everything,
            np.isin(trials.group, groups[1::2]),
        ),
        Analysis("drive_to_brake", "all trials; fit on drive (i ≥ 0), score on braking (i < 0)", everything, brake),
        Analysis("brake_to_drive", "all trials; fit on braking (i < 0), score on drive (i ≥ 0)", everything, ~brake),
    ]
    drive_groups = np.unique(trials.group[~brake])
    if drive_groups.size >= 4:
        held = drive_groups[0::2]
        out.append(
            Analysis(
                "drive_only",
                f"drive trials only; fit on slips {_slips_text(trials, drive_groups[1::2])}, "
                f"score on {_slips_text(trials, held)}",
                ~brake,
                np.isin(trials.group[~brake], held),
            )
        )
    return out


BASELINE_BIN_WIDTH = 0.25
"""Width of the slip bins of the empirical baseline (:func:`slip_binned_baseline`)."""


def slip_binned_baseline(
    slip: FloatArray, values: FloatArray, train: NDArray[np.bool_], width: float = BASELINE_BIN_WIDTH
) -> tuple[FloatArray, int]:
    """The field engineer's empirical model: per slip bin, the mean of the training trials in it.

    Bins of ``width`` over [−1, 1] (the last one closed). A trial whose bin
    has no training trial takes the mean of the nearest bins that have some
    (by bin index; both neighbours averaged on a tie): a flat extrapolation
    beyond the training slips, an average of the two sides between them.

    Returns:
        (prediction of every trial, number of bin means fitted).
    """
    if not np.any(train):
        raise ValueError("the baseline needs at least one training trial")
    edges = int(round(2.0 / width))
    index = np.clip(np.floor((np.asarray(slip, dtype=float) + 1.0) / width).astype(int), 0, edges - 1)
    means = {int(b): float(np.mean(values[train & (index == b)])) for b in np.unique(index[train])}
    filled = np.array(sorted(means))
    out = np.empty(slip.shape, dtype=float)
    for k, b in enumerate(index):
        if int(b) in means:
            out[k] = means[int(b)]
            continue
        distance = np.abs(filled - b)
        nearest = filled[distance == distance.min()]
        out[k] = float(np.mean([means[int(n)] for n in nearest]))
    return out, len(means)


def baseline_comparison(model: SingleWheelModel, held_out: NDArray[np.bool_], report: Any) -> dict[str, Any]:
    """Held-out χ² (Σ (r/σ)² over held-out trials and channels) of the nominal model, the verdict's model
    (the engine's best, fitted on the training trials) and the slip-binned mean baseline (fitted on the same
    training trials), with their parameter counts and penalised scores χ² + p ln n (the engine's score)."""
    train = ~held_out
    t = model.trials
    n = 2 * int(held_out.sum())
    rows: dict[str, Any] = {}
    best = report.best
    models = {"nominal": (model.predict({}, {}), 0)}
    if best is not None:
        models[best.name] = (model.predict(best.parameters, {}), int(best.added))
    baseline = {}
    bins = 0
    for ch in model.channels:
        baseline[ch.name], bins = slip_binned_baseline(t.slip, model.measured[ch.name], train)
    models["slip-binned mean"] = (baseline, 2 * bins)
    for name, (pred, params) in models.items():
        per_channel = {}
        chi2 = 0.0
        for ch in model.channels:
            r = (model.measured[ch.name] - pred[ch.name])[held_out] / ch.noise_std
            per_channel[ch.name] = float(np.sqrt(np.mean(r**2)))
            chi2 += float(np.sum(r**2))
        rows[name] = {
            "chi2": chi2,
            "parameters": params,
            "score": chi2 + params * math.log(max(n, 2)),
            "rms_sigma": per_channel,
        }
    physics = best.name if best is not None else "nominal"
    return {
        "models": rows,
        "physics": physics,
        "physics_beats_baseline": rows[physics]["score"] < rows["slip-binned mean"]["score"],
        "held_out_samples": n,
    }


def _regime_table(model: SingleWheelModel, predictions: Mapping[str, Mapping[str, FloatArray]]) -> list[dict[str, Any]]:
    """Bias and RMS (also in σ) of the residuals rig − model per slip regime, channel and model."""
    rows = []
    labels = np.array([_regime(s) for s in model.trials.slip])
    for regime in REGIMES:
        sel = labels == regime
        if not np.any(sel):
            continue
        for ch in model.channels:
            row: dict[str, Any] = {
                "regime": regime,
                "channel": ch.name,
                "unit": ch.unit,
                "trials": int(sel.sum()),
                "slips": sorted({round(float(s), 2) for s in model.trials.slip[sel]}),
                "models": {},
            }
            for name, pred in predictions.items():
                r = model.measured[ch.name][sel] - pred[ch.name][sel]
                row["models"][name] = {
                    "bias": float(np.mean(r)),
                    "rms": float(np.sqrt(np.mean(r**2))),
                    "rms_sigma": float(np.sqrt(np.mean(r**2)) / ch.noise_std),
                }
            rows.append(row)
    return rows


def consistency_at_measured_sinkage(trials: RigTrials, p: WheelSoil = NOMINAL) -> list[dict[str, float]]:
    """Per commanded slip: the load and drawbar pull the model's rim stresses give at the *measured* sinkage.

    θ0 = acos(1 − z/r) from the group's mean sinkage, then eqs. 7–8 at the
    group's mean slip (skid: the stresses at the skid itself, as with
    ``skid_stresses``; the nominal anti-symmetry has no stress field in skid).
    This separates the two halves of the model: W_model/W_measured ≠ 1 says
    the pressure–sinkage law is off (the soil carries the load at another
    depth), DP/W of the model against the rig's says the stress distribution
    (θ_m, shear, rear contact) is, whatever the sinkage law.
    """
    q = dataclasses.replace(p, skid_stresses=True)
    soil = _soil_vector(q)
    rows = []
    for g in np.unique(trials.group):
        sel = trials.group == g
        slip = float(trials.slip[sel].mean())
        z = float(trials.sinkage[sel].mean()) / 1000.0
        theta0 = math.acos(min(max(1.0 - z / q.radius, 0.0), 1.0))
        n = q.n + (q.n_skid if slip < 0.0 else q.n_slip) * abs(slip)
        load, dp, _ = _rim_row(theta0, slip, n, soil, _WEIGHTS)
        w_meas = float(trials.load[sel].mean())
        dp_meas = float(trials.drawbar_pull[sel].mean())
        rows.append(
            {
                "slip": slip,
                "sinkage_mm": 1000.0 * z,
                "load_measured": w_meas,
                "load_model": float(load),
                "drawbar_pull_measured": dp_meas,
                "drawbar_pull_model": float(dp),
                "dp_over_w_measured": dp_meas / w_meas,
                "dp_over_w_model": float(dp / load) if load > 0 else 0.0,
            }
        )
    return rows


def strongest_stress_field(
    slip: float, sinkage_mm: float, load: float, base: WheelSoil = NOMINAL, points: int = 5
) -> dict[str, Any]:
    """Most negative DP/W the rim stresses can give at a measured (slip, sinkage, load) within the fit ranges.

    A grid (``points`` values per parameter) over the candidates' fit ranges of
    φ, cohesion, K, n, c1 and the rear-contact ratio λ, stresses at the skid
    itself (``skid_stresses``); for each combination the modulus k is the one
    that carries the measured load at the measured sinkage (W and DP are
    linear in k at fixed θ0), combinations needing k ≤ 0 are skipped. Bounds
    what any re-parameterised Wong–Reece wheel can resist with there.
    """
    theta0 = math.acos(min(max(1.0 - sinkage_mm / 1000.0 / base.radius, 0.0), 1.0))
    best: dict[str, Any] = {"dp_over_w": 0.0, "parameters": {}}
    grid = np.linspace(0.0, 1.0, points)
    for phi, cohesion, shear, n, c1, rear in itertools.product(
        base.friction_angle - 0.15 + 0.30 * grid,
        5.0 * base.cohesion * grid,
        base.shear_modulus * (0.25 + 3.75 * grid),
        0.6 + 1.6 * grid,
        0.02 + 0.58 * grid,
        grid,
    ):
        p = dataclasses.replace(
            base, friction_angle=float(phi), cohesion=float(cohesion), shear_modulus=float(shear), n=float(n),
            c1=float(c1), rear_ratio=float(rear), skid_stresses=True,
        )  # fmt: skip
        w0, d0, _ = _rim_row(theta0, slip, p.n, _soil_vector(dataclasses.replace(p, k_c=0.0, k_phi=0.0)), _WEIGHTS)
        w1, d1, _ = _rim_row(theta0, slip, p.n, _soil_vector(p), _WEIGHTS)
        if w1 - w0 <= 0.0:
            continue
        scale = (load - w0) / (w1 - w0)
        if scale <= 0.0:
            continue
        ratio = (d0 + scale * (d1 - d0)) / load
        if ratio < best["dp_over_w"]:
            best = {
                "dp_over_w": float(ratio),
                "parameters": {
                    "friction_angle_deg": math.degrees(float(phi)),
                    "cohesion": float(cohesion),
                    "shear_modulus": float(shear),
                    "sinkage_exponent": float(n),
                    "max_stress_angle_c1": float(c1),
                    "rear_angle_ratio": float(rear),
                    "modulus_scale": float(scale),
                },
            }
    return best


def synthetic_trials(
    trials: RigTrials,
    effects: Mapping[str, Mapping[str, float]],
    noise: Mapping[str, float],
    seed: int,
    geometry: WheelGeometry = RIG_WHEEL,
) -> RigTrials:
    """The rig's slips and loads; channels from the model with ``effects`` plus Gaussian noise of std ``noise``."""
    rng = np.random.default_rng(seed)
    clean = SingleWheelModel(trials, geometry=geometry).predict(effects, {})
    return dataclasses.replace(
        trials,
        drawbar_pull=clean["drawbar_pull"] + rng.normal(0.0, noise["drawbar_pull"], trials.size),
        sinkage=clean["sinkage"] + rng.normal(0.0, noise["sinkage"], trials.size),
        source=f"synthetic (seed {seed})",
    )


def identifiability(
    trials: RigTrials,
    noise: Mapping[str, tuple[float, int]],
    seeds: Sequence[int] = (1, 2),
    *,
    settings: Any = None,
    progress: Any = None,
    geometry: WheelGeometry = RIG_WHEEL,
) -> list[dict[str, Any]]:
    """Can the rig's design tell the candidates apart? Simulated trials, one effect each, diagnosed blind.

    For every candidate (parameters at off + one typical change, inside the
    fit range) and a no-effect control: trials at the rig's slips and loads,
    channels from the model plus noise at the budget σ, then the ``alternate``
    split of :func:`analyses` through the engine. Returns one row per case and seed.
    """
    from terrain_analysis.sim2real.attribution import AttributionSettings, attribute

    settings = settings or AttributionSettings()
    sd = {name: value[0] for name, value in noise.items()}
    cases: list[tuple[str, dict[str, dict[str, float]]]] = [("nominal", {})]
    for name, cand in candidates(
        dataclasses.replace(NOMINAL, radius=geometry.radius, width=geometry.width), geometry
    ).items():
        values = {}
        for p in cand.parameters:
            up = p.off + p.scale
            values[p.name] = up if up <= p.bounds[1] else p.off - p.scale
        cases.append((name, {name: values}))
    split = analyses(trials)[0]
    rows = []
    for truth, effects in cases:
        for seed in seeds:
            model = SingleWheelModel(
                synthetic_trials(trials, effects, sd, seed, geometry), noise=noise, geometry=geometry
            )
            report = attribute(model, settings=settings, test_mask={ch.name: split.held_out for ch in model.channels})
            best = report.best.name if report.kind != "no_gap" and report.best is not None else ""
            row = {
                "truth": truth,
                "values": effects.get(truth, {}),
                "seed": seed,
                "kind": report.kind,
                "best": best,
                "correct": best == truth if truth != "nominal" else report.kind == "no_gap",
                "shrinkage": report.shrinkage if best else 0.0,
                "fitted": report.best.parameters.get(truth, {}) if report.best is not None and best == truth else {},
                "indistinguishable": report.indistinguishable,
                "verdict": report.verdict,
            }
            rows.append(row)
            if progress is not None:
                progress(f"identifiability: {truth} (seed {seed}) -> {report.verdict}")
    return rows


def run(
    folder: str | Path,
    out: str | Path,
    *,
    progress: Any = None,
    settings: Any = None,
    only: Sequence[str] | None = None,
    validate: Sequence[int] = (),
    geometry: WheelGeometry = RIG_WHEEL,
    file: str | None = None,
) -> dict[str, Any]:
    """Diagnose the rig data and write ``single_wheel.md``, ``single_wheel.json`` and PNG figures to ``out``.

    Args:
        folder: Folder holding the trial file (or the file itself).
        geometry: The wheel's geometry (default: the smooth wheel of ``all_smooth_data.mat``).
        file: The trial file's name in ``folder`` (default :data:`DATA_FILE`).
        out: Output folder (created).
        progress: Called with one line per step, or None.
        settings: :class:`~terrain_analysis.sim2real.attribution.AttributionSettings` (default: the engine's).
        only: Names of the analyses to run (default: all of :func:`analyses`).
        validate: Seeds of the simulated identifiability check (:func:`identifiability`); empty: none.

    Returns:
        The JSON summary.
    """
    from terrain_analysis.sim2real.attribution import AttributionSettings, attribute

    trials = load_rig_trials(folder, file)
    full = SingleWheelModel(trials, geometry=geometry)
    noise = {ch.name: (ch.noise_std, full.noise_dof[ch.name]) for ch in full.channels}
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    settings = settings or AttributionSettings()
    results: dict[str, Any] = {}
    reports: dict[str, Any] = {}
    predictions: dict[str, dict[str, FloatArray]] = {"nominal": full.predict({}, {})}
    for analysis in analyses(trials):
        if only is not None and analysis.name not in only:
            continue
        if progress is not None:
            progress(f"analysis {analysis.name}: {analysis.description}")
        model = SingleWheelModel(trials.subset(analysis.keep), noise=noise, geometry=geometry)
        test_mask = {ch.name: analysis.held_out for ch in model.channels}
        report = attribute(model, settings=settings, test_mask=test_mask, progress=progress)
        reports[analysis.name] = report
        results[analysis.name] = {
            "description": analysis.description,
            "trials": int(analysis.keep.sum()),
            "held_out_trials": int(analysis.held_out.sum()),
            "at_bounds": _at_bounds(model, report),
            "baseline": baseline_comparison(model, analysis.held_out, report),
            **report.to_dict(),
        }
        if report.best is not None:
            predictions[f"{report.best.name} [{analysis.name}]"] = full.predict(report.best.parameters, {})
        if analysis.name == "alternate":  # the baseline on the figure and in the where-table: the first analysis'
            predictions[f"slip-binned mean [{analysis.name}]"] = {
                ch.name: slip_binned_baseline(trials.slip, full.measured[ch.name], ~analysis.held_out)[0]
                for ch in full.channels
            }
    summary = {
        "data": {
            "source": trials.source,
            "trials_used": trials.size,
            "trials_total": trials.total_trials,
            "betas": list(trials.betas),
            "load_range": [float(trials.load.min()), float(trials.load.max())],
            "noise_std": {ch.name: ch.noise_std for ch in full.channels},
            "noise_dof": full.noise_dof,
            "median_within_trial_std": {
                "drawbar_pull": float(np.median(trials.drawbar_pull_ripple)),
                "sinkage": float(np.median(trials.sinkage_ripple)),
            },
        },
        "geometry": dataclasses.asdict(geometry),
        "identifiability": identifiability(
            trials, noise, validate, settings=settings, progress=progress, geometry=geometry
        )
        if validate
        else [],
        "nominal_soil": dataclasses.asdict(full.base),
        "at_measured_sinkage": consistency_at_measured_sinkage(trials, full.base),
        "strongest_locked_wheel": _strongest_locked(trials, full.base),
        "bulldozing_at_measured_sinkage": _bulldozing_at_measured_sinkage(trials, full.base),
        "regimes": _regime_table(full, predictions),
        "analyses": results,
        "notes": full.notes,
    }
    (out_dir / "single_wheel.json").write_text(json.dumps(_jsonable(summary), indent=1) + "\n")
    figures = _figures(full, predictions, out_dir)
    (out_dir / "single_wheel.md").write_text(_markdown(full, summary, reports, figures))
    return summary


def _bulldozing_at_measured_sinkage(trials: RigTrials, base: WheelSoil) -> float:
    """Wong's bulldozing resistance (κ = 1, N) at the most-braked slip's mean measured sinkage."""
    locked = trials.group == trials.group[int(np.argmin(trials.slip))]
    z = float(trials.sinkage[locked].mean()) / 1000.0
    slip = float(trials.slip[locked].mean())
    theta0 = math.acos(min(max(1.0 - z / base.radius, -1.0), 1.0))
    return float(bulldozing_resistance(np.array([z]), np.array([slip]), np.array([theta0]), base)[0])


def _strongest_locked(trials: RigTrials, base: WheelSoil) -> dict[str, Any]:
    locked = trials.group == trials.group[int(np.argmin(trials.slip))]
    slip = float(trials.slip[locked].mean())
    sinkage = float(trials.sinkage[locked].mean())
    load = float(trials.load[locked].mean())
    return {"slip": slip, "sinkage_mm": sinkage, "load": load, **strongest_stress_field(slip, sinkage, load, base)}


def _at_bounds(model: SingleWheelModel, report: Any) -> list[str]:
    """Fitted parameters of the ranked models that ended on a bound of their fit range or outside their
    physically plausible range (:data:`PHYSICAL_RANGES`): not a physical explanation, flagged."""
    out = []
    for fitted in list(report.ranking) + list(report.pairs):
        for effect, values in fitted.parameters.items():
            params = {p.name: p for p in model.candidates[effect].parameters}
            for name, v in values.items():
                lo, hi = params[name].bounds
                if v <= lo + 1e-6 * (hi - lo) and params[name].off != lo or v >= hi - 1e-6 * (hi - lo):
                    out.append(f"{fitted.name}: {name} = {v:.4g} at its bound [{lo:g}, {hi:g}]")
                elif name in PHYSICAL_RANGES and not PHYSICAL_RANGES[name][0] <= v <= PHYSICAL_RANGES[name][1]:
                    p_lo, p_hi = PHYSICAL_RANGES[name]
                    out.append(f"{fitted.name}: {name} = {v:.4g} outside its physical range [{p_lo:g}, {p_hi:g}]")
    return out


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _figures(model: SingleWheelModel, predictions: Mapping[str, Mapping[str, FloatArray]], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = model.trials
    # Models with identical predictions (the same fit from two analyses) share one curve.
    curves: dict[str, Mapping[str, FloatArray]] = {}
    for name, pred in predictions.items():
        same = next((k for k, v in curves.items() if all(np.array_equal(v[c], pred[c]) for c in pred)), None)
        if same is None:
            curves[name] = pred
        else:
            curves[f"{same}, {name.split(' [')[-1].rstrip(']')}]".replace("], ", ", ")] = curves.pop(same)
    groups = np.unique(t.group)
    slips = np.array([t.slip[t.group == g].mean() for g in groups])
    fig, axes = plt.subplots(2, 2, figsize=(12, 8), sharex=True)
    for col, ch in enumerate(model.channels):
        ax, rax = axes[0, col], axes[1, col]
        ax.errorbar(t.slip, model.measured[ch.name], yerr=ch.noise_std, fmt="ko", ms=4, label="rig (±σ)", zorder=5)
        for k, (name, pred) in enumerate(curves.items()):
            color = f"C{k}"
            mean = np.array([pred[ch.name][t.group == g].mean() for g in groups])
            ax.plot(slips, mean, "-" if k == 0 else "--", color=color, label=name)
            ax.plot(t.slip, pred[ch.name], "x", color=color, ms=5)
            resid = (model.measured[ch.name] - pred[ch.name]) / ch.noise_std
            rax.plot(t.slip + 0.01 * (k - 1), resid, "o", color=color, ms=3.5, label=name)
        ax.set_ylabel(f"{ch.name.replace('_', ' ')} ({ch.unit})")
        rax.set_ylabel(f"(rig − model) / σ, {ch.name.replace('_', ' ')}")
        rax.set_yscale("symlog", linthresh=3.0)
        rax.axhspan(-2, 2, color="0.85", zorder=0)
        rax.set_xlabel("slip i (–)")
        for a in (ax, rax):
            a.grid(alpha=0.3)
            a.axvspan(-1.05, -0.1, color="tab:red", alpha=0.05, zorder=0)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(
        "CMU single wheel, β = 0: rig against Wong–Reece\n"
        "(nominal; best model of each analysis, fitted on its training trials)"
    )
    fig.tight_layout()
    name = "single_wheel_fit.png"
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return [name]


def _fmt_params(fitted: Any) -> str:
    parts = []
    for effect, values in fitted.parameters.items():
        for p, v in values.items():
            sd = fitted.std.get(effect, {}).get(p, float("nan"))
            parts.append(f"{p} = {v:.3g} ± {sd:.2g}")
    return "; ".join(parts) or "(switch)"


def _markdown(
    model: SingleWheelModel, summary: Mapping[str, Any], reports: Mapping[str, Any], figures: list[str]
) -> str:
    t = model.trials
    d = summary["data"]
    lo, hi = d["load_range"]
    lines = [
        "## CMU single-wheel rig (real data): the Wong–Reece wheel against the rig",
        "",
        f"Data: `{Path(t.source).name}` (robomechanics/3d-terramechanics, C. Pavlov 2022, MIT licence): "
        f"{d['trials_used']} steady-state trials at β = 0 of {d['trials_total']} (β ≠ 0 is left out: the model is "
        f"planar). Wheel: {model.geometry.describe()}; 10 mm/s; the measured load of each trial "
        f"({lo:.1f}…{hi:.1f} N) and its slip are the inputs, drawbar pull DP = −avg_Fy and sinkage = −avg_Z the "
        "channels.",
        "",
        "Nominal model: the project's Wong–Reece wheel (`vehicle_sim.terrain.wong_reece`, skid by the "
        "anti-symmetry DP(i) = −DP(−i) + 2 DP(0)) with the rig authors' soil: σ = k z^n with one modulus "
        "k = 8e3 kN/m^(n+2) (k_c = 0, k_φ = 8e6 N/m^(n+2)), n = 1.46, c = 1 kPa, φ = 29°, K = 21 mm; "
        "θ_m = θ0 (0.18 + 0.32 i); no rear contact.",
        "",
        f"Noise budget σ (pooled spread of the three repeated trials at each slip, {d['noise_dof']['drawbar_pull']} "
        f"degrees of freedom): DP {d['noise_std']['drawbar_pull']:.3f} N, sinkage {d['noise_std']['sinkage']:.3f} mm. "
        f"(The median within-trial ripple, {d['median_within_trial_std']['drawbar_pull']:.2f} N, is the force "
        "fluctuation as the wheel rolls, not an error of the trial mean.)",
        "",
        "### Where: residual rig − model per slip regime",
        "",
        "Braking i < −0.1, low slip −0.1 ≤ i ≤ 0.3, high slip i > 0.3. Each cell: mean residual, RMS in units of σ. "
        "The best models are fitted on their analysis' training trials and evaluated on all trials.",
        "",
    ]
    names = list(summary["regimes"][0]["models"])
    lines.append("| regime (slips) | channel | " + " | ".join(names) + " |")
    lines.append("|---|---|" + "---|" * len(names))
    for row in summary["regimes"]:
        cells = " | ".join(
            f"{row['models'][n]['bias']:+.2f} {row['unit']}, {row['models'][n]['rms_sigma']:.1f} σ" for n in names
        )
        slips = ", ".join(f"{x:g}" for x in row["slips"])
        lines.append(f"| {row['regime']} ({slips}) | {row['channel']} | {cells} |")
    lines += _consistency_markdown(summary["at_measured_sinkage"])
    lines += _reading(summary)
    lines += [
        "",
        "### Which effect: fitted on some trials, scored on the others",
        "",
        "Engine: `terrain_analysis.sim2real.attribution.attribute` with the split given as its held-out mask; "
        "every held-out trial is its own bootstrap unit. Score = held-out χ² + p ln n; shrinkage = 1 − G/G_nominal "
        "with G = mean held-out (r/σ)² − 1.",
        "",
    ]
    for name, rep in reports.items():
        info = summary["analyses"][name]
        lines += [
            f"#### `{name}`: {info['description']}",
            "",
            f"{rep.train_samples} training and {rep.test_samples} held-out samples (trials × 2 channels). "
            f"Verdict: **{rep.verdict}**.",
            "",
            "| rank | model | held-out χ² | score | shrinkage (90 % CI) | DP | sinkage | parameters (± s.e.) |",
            "|---|---|---|---|---|---|---|---|",
            f"| – | nominal | {rep.nominal.test_chi2:.0f} | {rep.nominal.score:.0f} | – | – | – | – |",
        ]
        for k, m in enumerate(list(rep.ranking) + list(rep.pairs)):
            rank = str(k + 1) if k < len(rep.ranking) else "pair"
            clo, chi = m.shrinkage_ci
            lines.append(
                f"| {rank} | {m.name} | {m.test_chi2:.0f} | {m.score:.0f} | "
                f"{100 * m.shrinkage.get('overall', 0):.0f} % ({100 * clo:.0f}…{100 * chi:.0f}) | "
                f"{100 * m.shrinkage.get('drawbar_pull', 0):.0f} % | {100 * m.shrinkage.get('sinkage', 0):.0f} % | "
                f"{_fmt_params(m)} |"
            )
        if info["at_bounds"]:
            lines += [
                "",
                "Flagged (at a bound of the fit range or outside the physical range: not a physical explanation): "
                + "; ".join(info["at_bounds"])
                + ".",
            ]
        lines.append("")
    lines += _baseline_markdown(summary["analyses"])
    lines += _identifiability_markdown(summary["identifiability"])
    lines += [f"![{f}]({f})" for f in figures]
    return "\n".join(lines) + "\n"


def _baseline_markdown(results: Mapping[str, Any]) -> list[str]:
    """Every verdict against the field engineer's slip-binned mean, on the same held-out trials."""
    rows = {name: r["baseline"] for name, r in results.items() if "baseline" in r}
    if not rows:
        return []
    lines = [
        "### Against the simplest empirical model: a slip-binned mean",
        "",
        f"Baseline: per slip bin ({BASELINE_BIN_WIDTH:g} wide over [−1, 1]) the mean DP and sinkage of the "
        "analysis' training trials; a held-out trial in a bin without training trials takes the nearest bins' "
        "mean (flat beyond the training slips). Both are scored on the same held-out trials: χ² = Σ (r/σ)², "
        "score = χ² + p ln n (p: fitted parameters, the baseline's bin means count).",
        "",
        "| analysis | verdict's model | χ² nominal | χ² model (p) | χ² baseline (p) | RMS/σ model DP, z | "
        "RMS/σ baseline DP, z | physics beats baseline |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, b in rows.items():
        m = b["models"]
        phys, base = m[b["physics"]], m["slip-binned mean"]
        lines.append(
            f"| `{name}` | {b['physics']} | {m['nominal']['chi2']:.0f} | {phys['chi2']:.0f} ({phys['parameters']}) | "
            f"{base['chi2']:.0f} ({base['parameters']}) | {phys['rms_sigma']['drawbar_pull']:.1f}, "
            f"{phys['rms_sigma']['sinkage']:.1f} | {base['rms_sigma']['drawbar_pull']:.1f}, "
            f"{base['rms_sigma']['sinkage']:.1f} | {'**yes**' if b['physics_beats_baseline'] else 'no'}"
            + (
                " (χ² within 10 %: by the parameter count only)"
                if abs(phys["chi2"] - base["chi2"]) < 0.1 * base["chi2"]
                else ""
            )
            + " |"
        )
    wins = [n for n, b in rows.items() if b["physics_beats_baseline"]]
    losses = [n for n, b in rows.items() if not b["physics_beats_baseline"]]
    lines += [""]
    if wins:
        lines.append(
            f"The physics beats the baseline on {', '.join(f'`{n}`' for n in wins)}: held-out slips outside or "
            "between the training slips, where a table of means can only copy a neighbour and the model carries "
            "its structure (load, sinkage, the slip law) across."
        )
    if losses:
        lines.append(
            f"It does not on {', '.join(f'`{n}`' for n in losses)}: there the slip-binned mean, fitted on the "
            "same trials, predicts the held-out trials better than the best physical model; the model's "
            "structure misses what a table of means captures, and its verdict should be read with that."
        )
    lines.append("")
    return lines


def _consistency_markdown(rows: Sequence[Mapping[str, float]]) -> list[str]:
    lines = [
        "",
        "### The model's stresses at the measured sinkage",
        "",
        "θ0 from each slip's mean measured sinkage, then eqs. 7–8 (skid: stresses at the skid itself). "
        "W_model/W_rig ≠ 1: the pressure–sinkage law puts the load at another depth; DP/W ≠ the rig's: the "
        "stress distribution itself cannot give the measured force ratio, whatever the sinkage.",
        "",
        "| slip | sinkage (mm) | W rig (N) | W model (N) | DP rig (N) | DP model (N) | DP/W rig | DP/W model |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['slip']:+.2f} | {r['sinkage_mm']:.1f} | {r['load_measured']:.1f} | {r['load_model']:.1f} | "
            f"{r['drawbar_pull_measured']:+.2f} | {r['drawbar_pull_model']:+.2f} | {r['dp_over_w_measured']:+.2f} | "
            f"{r['dp_over_w_model']:+.2f} |"
        )
    return lines


def _reading(summary: Mapping[str, Any]) -> list[str]:
    """What the tables say, in numbers taken from them."""
    regimes = {(r["regime"], r["channel"]): r["models"]["nominal"] for r in summary["regimes"]}
    rows = summary["at_measured_sinkage"]
    lines = ["", "Reading:", ""]
    locked = min(rows, key=lambda r: r["slip"])
    free = min(rows, key=lambda r: abs(r["slip"]))
    high = max(rows, key=lambda r: r["slip"])
    nominal_locked = steady_state(locked["load_measured"], locked["slip"])[0].item()
    if ("braking", "drawbar_pull") in regimes:
        b = regimes[("braking", "drawbar_pull")]
        z = regimes[("braking", "sinkage")]
        lines.append(
            f"- The gap is largest in braking: DP residual {b['bias']:+.1f} N on average ({b['rms_sigma']:.0f} σ RMS), "
            f"sinkage {z['bias']:+.1f} mm. At i = {locked['slip']:+.2f} the rig resists with DP/W = "
            f"{locked['dp_over_w_measured']:+.2f} at {locked['sinkage_mm']:.0f} mm sinkage; the nominal model gives "
            f"{nominal_locked / locked['load_measured']:+.2f}. Even at the measured sinkage the Wong–Reece stresses "
            f"give only DP/W = {locked['dp_over_w_model']:+.2f} (and would carry {locked['load_model']:.0f} N, not "
            f"{locked['load_measured']:.0f} N). With φ, c, K, n, c1 and a rear contact anywhere in their fit ranges "
            "and the modulus set to carry the measured load at the measured sinkage, the rim stresses give at most "
            f"DP/W = {summary['strongest_locked_wheel']['dp_over_w']:+.2f}: no re-parameterised Wong–Reece wheel "
            "reaches the rig's braking force. The missing resistance comes from outside the rim's stress field: "
            "soil pushed ahead of the skidding wheel (bulldozing). Wong's fully mobilised wedge at the locked "
            f"wheel's measured {locked['sinkage_mm']:.0f} mm would resist with "
            f"{summary['bulldozing_at_measured_sinkage']:.0f} N (the rig's braking force is "
            f"{-locked['drawbar_pull_measured']:.0f} N); the `bulldozing` candidate evaluates it at the model's own "
            "sinkage, which is too shallow in braking, so it closes part of the braking gap only (tables below)."
        )
    drive = [regimes[(g, "drawbar_pull")] for g in ("low slip", "high slip") if (g, "drawbar_pull") in regimes]
    if drive:
        lines.append(
            f"- In drive the model under-predicts the pull by {min(d['bias'] for d in drive):+.1f}…"
            f"{max(d['bias'] for d in drive):+.1f} N (low, high slip). At the measured sinkage its stresses give "
            f"DP/W = {free['dp_over_w_model']:+.2f} at i = {free['slip']:+.2f} and {high['dp_over_w_model']:+.2f} at "
            f"i = {high['slip']:+.2f}, the rig {free['dp_over_w_measured']:+.2f} and {high['dp_over_w_measured']:+.2f}."
        )
        lines.append(
            f"- Sinkage: at the measured {free['sinkage_mm']:.1f} mm (i = {free['slip']:+.2f}) the authors' soil "
            f"carries {free['load_model']:.1f} N of the {free['load_measured']:.1f} N (stiffer soil than k = 8e3 "
            f"kN/m^(n+2) at rest); at {high['sinkage_mm']:.1f} mm (i = {high['slip']:+.2f}) it would carry "
            f"{high['load_model']:.1f} N of {high['load_measured']:.1f} N: the slipping wheel sinks deeper than "
            "the static law and the model's θ_m shift say (slip-sinkage)."
        )
    return lines


def _identifiability_markdown(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    if not rows:
        return []
    seeds = sorted({r["seed"] for r in rows})
    lines = [
        "### Identifiability on the rig's design (simulated trials)",
        "",
        f"The rig's 27 slips and loads, channels simulated with one effect (at its off value plus one typical "
        f"change) plus noise at σ, diagnosed blind with the `alternate` split; seeds {', '.join(map(str, seeds))}.",
        "",
        "| simulated effect (values) | attributed to (per seed) | held-out shrinkage | named indistinguishable |",
        "|---|---|---|---|",
    ]
    for truth in dict.fromkeys(r["truth"] for r in rows):
        sel = [r for r in rows if r["truth"] == truth]
        values = ", ".join(f"{k} = {v:.3g}" for k, v in sel[0]["values"].items()) or "–"
        got = ", ".join((r["best"] or "no significant gap") + ("" if r["correct"] else " ✗") for r in sel)
        shrink = ", ".join(f"{100 * r['shrinkage']:.0f} %" for r in sel)
        others = "; ".join(", ".join(r["indistinguishable"]) or "–" for r in sel)
        lines.append(f"| {truth} ({values}) | {got} | {shrink} | {others} |")
    right = sum(r["correct"] for r in rows)
    lines += ["", f"{right} of {len(rows)} cases right (✗: wrong or missed).", ""]
    return lines


@cli_main("sim2real-single-wheel")
def main(argv: Sequence[str] | None = None) -> int:
    """``python -m terrain_analysis.sim2real.single_wheel --data DIR --out DIR``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="folder holding the trial file, or the trial file itself")
    parser.add_argument("--file", help=f"trial file of the rig's layout (all_results) in --data (default {DATA_FILE})")
    parser.add_argument("--radius", type=float, default=RIG_WHEEL_RADIUS, help="wheel rim radius (m)")
    parser.add_argument("--width", type=float, default=RIG_WHEEL_WIDTH, help="wheel width (m)")
    parser.add_argument("--grousers", type=int, default=0, metavar="COUNT", help="grousers on the rim (0: smooth)")
    parser.add_argument(
        "--grouser-height", type=float, default=0.0, metavar="M", help="grouser height above the rim (m)"
    )
    parser.add_argument("--out", required=True, help="output folder (Markdown, JSON, PNG)")
    parser.add_argument("--only", nargs="*", help="analyses to run (default: all)")
    parser.add_argument(
        "--validate", type=int, default=2, metavar="N", help="seeds of the simulated identifiability check (0: none)"
    )
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    try:
        geometry = WheelGeometry(args.radius, args.width, args.grousers, args.grouser_height)
        summary = run(
            args.data,
            args.out,
            progress=None if args.quiet else lambda s: print(s, file=sys.stderr),
            only=args.only,
            validate=tuple(range(1, args.validate + 1)),
            geometry=geometry,
            file=args.file,
        )
    except Sim2RealError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for name, res in summary["analyses"].items():
        print(f"{name}: {res['verdict']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
