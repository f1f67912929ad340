"""Withheld-effect validation suite: blind "real" bags for the sim-to-real diagnosis (issue 6).

``python -m vehicle_sim.tools.withheld --out DIR --per-effect N --seed S [--vehicle V ...] [--duration D]``

Writes, for each vehicle (``quarter_car``, ``lrv``, ``skid_steer``, ``rover``):

* ``N`` bags per effect of the catalogue (:data:`vehicle_sim.effects.CATALOGUE`),
  the effect on at random magnitudes (below);
* ``--controls`` bags (default ``N``) with no effect at all: the nominal
  plant of the catalogue (every effect off; for the skid steer also
  load-transfer dynamics and tire relaxation, which the simulator node
  switches on by default, and the plant runs the brush tire on level,
  uniform ground, where the node's truth has its own magic-formula tire);
* ``--out-of-catalogue`` bags (default ``N`` × the number of kinds, cycling
  through them) with an effect that is *not* in the catalogue
  (:data:`OUT_OF_CATALOGUE`), applied to the messages after the adapter;
* quarter car and LRV: ``--rough-controls`` more controls (default half of
  ``--controls``) on the rough roads of the wheel-liftoff bags (ISO 8608 E, F),
  so that a diagnosis that takes a rough road for lift-off is caught. They are
  drawn last, so the bags above do not depend on their number.

Every bag is an ordinary contract bag, as a real robot records it
(CONTRACT.md): the sensor topics of the vehicle's simulator adapter
(:mod:`vehicle_sim.ros`), the same path as ``terrain-simulate``, but **no
``ground_truth/*`` topics and no ``/clock``**, and every stamp shifted by a
random start time (a real bag's stamps start at any value; here uniformly in
[1.6e9, 1.8e9] s, whole nanoseconds; log time = header stamp). The vehicle's
scenario varies too, so that the diagnosis cannot learn one scenario: quarter
car and LRV: ISO 8608 road class (B, C, D or the meadow stand-in; E or F for
the wheel-liftoff bags, the only roads on which the wheel leaves the ground,
and for the rough-road controls),
road realisation and soil from a small set; skid steer: manoeuvre; rover: terrain.
The noise seed is drawn per bag. Durations are drawn per bag (quarter car /
LRV 10–20 s, skid steer 15–20 s, rover 30–60 s) unless ``--duration`` fixes
them.

Output layout::

    DIR/manifest.json      what the diagnosis is given: id → vehicle, bag path
    DIR/labels.json        the answers (and each bag's effect signature): NEVER to be read by the diagnosis
    DIR/bags/<id>/         one rosbag2 (MCAP) bag per id

Bag ids are 12 random hex digits (drawn from the seeded generator), so they
carry nothing about the effect; the manifest is sorted by id. ``labels.json``
holds per id the vehicle, the kind (``effect``, ``control`` or
``out_of_catalogue``), the effect and its parameter values, the scenario, the
noise seed, duration and start time: it is for the scorer only, which joins
the diagnosis's output to it on the id. The generator and the diagnosis are
separate code paths: the diagnosis gets only the manifest and the bags.

How magnitudes are drawn (:func:`draw_parameter`)
    For a continuous parameter with off value ``off``, typical value ``t``
    and fit range [lo, hi], the typical deviation is d = |t − off|. The
    deviation from ``off`` is drawn log-uniformly in
    [d, min(3 d, room)] ("clearly visible" lower magnitude 1× typical,
    upper 3× typical), where ``room`` is the distance from ``off`` to the
    fit-range bound on the chosen side (a side is possible when its room is
    at least d; if both are, the side is random — a random sign for the
    symmetric ranges). The value is therefore inside the fit range and at
    least d away from the off value. Switches are on. Two kinds of parameter
    have no "magnitude" and are drawn otherwise (``rule`` in the labels):
    a *shape* parameter whose typical equals its off value (the rover's
    undulation wavelength) log-uniformly within a factor 2 of the typical,
    clipped to the fit range; the rover's ``soil_change_distance`` (a
    location) so that the front wheel (0.35 m ahead of the body at the
    start) reaches the change after 15–60 % of the run's travel. Skid steer
    (issue 22, :func:`_skid_steer_draw`): of a per-axis effect (accelerometer
    bias and scale, gyro bias, grade/bank) each component is kept with
    probability ½ (at least one), the others off; a stream delay (IMU or
    wheel encoders) is drawn log-uniformly over 0.05–0.3 s. Quarter car and
    LRV (issue 22, :func:`_quarter_car_draw`): one late stream, 0.01–0.3 s;
    a bias or scale on one or both accelerometers; a stiffening or softening
    soil (n in 1.2–1.8 or 0.4–0.8, origin ratio ζ in 0.3–3).

Out-of-catalogue effects (:data:`OUT_OF_CATALOGUE`; applied to the adapter's
messages, no plant change; sample time t from the start of the run)
    ``imu_vibration``: an engine/drive-train vibration line
    a sin(2π f t + φ) added to every measured accelerometer axis of the
    vehicle's IMU(s) (quarter car/LRV z; skid steer x, y, z; rover x, z),
    f uniform in [0.1, 0.4] × the IMU rate (below Nyquist), amplitude per
    vehicle (quarter car/LRV 1–3 m/s², skid steer 0.3–1 m/s², rover
    0.05–0.2 m/s²), random phase per axis.
    ``accel_spikes``: outliers in one channel, the (body) IMU's z
    accelerometer: each sample is hit with probability p ∈ [1 %, 3 %] by a
    spike of random sign and magnitude uniform in the vehicle's range
    (quarter car/LRV 5–15, skid steer 3–10, rover 0.3–1 m/s²).
    ``channel_scale``: a scale error (reading × (1 + s), |s| ∈ [0.1, 0.3],
    random sign) on a channel the catalogue has no scale effect for:
    quarter car/LRV the profile sampler's elevation (``terrain/profile``
    point.z), skid steer the left side's encoder stream (``joint_states``
    ``left_motor`` position and velocity; the yaw gyro has the catalogue's
    ``gyro_scale``), rover the velocimeter (twist.linear.x).

Effect signature (``labels.json`` only: never in the manifest or the bags)
    How much the withheld effect changed what the bag records, so that the
    scorer can tell "the diagnosis failed" from "there was nothing to see".
    Every bag of kind ``effect`` or ``out_of_catalogue`` has a *twin*
    (:func:`twin`): the identical plan (scenario, noise seed, duration) with
    every effect off. The plants draw their sensor noise from per-channel
    streams spawned from the seed, a fixed number of draws per sample
    whatever the effects, and the drive controllers read the true state, so
    bag and twin share the noise realisation and Δ = y_effect − y_twin
    isolates the effect (a control and its separately simulated twin give
    Δ ≡ 0 bit for bit: test_withheld_signature.py). A catalogue effect's twin
    is simulated again (nothing written); an out-of-catalogue effect only
    changes messages after the adapter, so its twin is the same run recorded
    before the transform. Channels (generic over the message types, not
    listed per vehicle): every numeric field of the recorded sensor
    messages, scalar or array element (JointState elements named by joint),
    without header, strings and ``*covariance`` metadata; a quaternion field
    gives the three components of the rotation vector of q_twin⁻¹ ⊗ q_effect
    (no ±π wrap). Samples are aligned on their stamps. The noise σ of each
    channel is estimated once per vehicle (:func:`noise_sigma`, cached) from
    two nominal runs of the vehicle's default scenario, :data:`SIGMA_DURATION`
    s long, that differ only in the noise seed (:data:`SIGMA_SEEDS`):
    σ = RMS(y₁ − y₂)/√2. Channels with σ = 0 are noise-free or not measured
    (unmeasured IMU axes, the quarter car's wheel speed and profile
    position, the rover's wheel torque). The signature (:func:`signature`):

    * ``snr`` = sqrt(Σ_channels Σ_samples (Δ/σ)²) over the noisy channels of
      the vehicle's *response* topics (:data:`RESPONSE_TOPICS`: IMUs, load
      cells, velocimeter): the SNR of the ideal matched-filter detector,
      which knows the effect's shape and magnitude, in white sensor noise
      (below about 3 there was nothing to see). The inputs a replay is
      driven by (road profile, drive commands and encoders) and the GNSS
      fix are left out: an ideal detector would need the twin's exact
      trajectory to use them (the rover's wheel encoders, σ ≈ 4e-7 rad, gave
      SNRs of 10⁵–10⁷ to every rover effect; the skid steer's quantised
      motor encoders, whose quantisation is the same in both σ runs, turn a
      tiny change of the true motor angle into Δ ≈ step/period). It is an
      upper bound for a blind diagnosis, which knows neither the effect nor
      the scenario's nuisances (soil, road, initial state): an effect that a
      nuisance absorbs (a nonlinear soil about its static point against a
      fitted k_s) keeps its SNR here. ``snr_all`` is the same over every
      noisy channel;
    * ``channels``: per noisy channel ``rms_over_sigma`` = RMS(Δ)/σ, its
      own ``snr`` (its share) and ``in_snr``; ``most_affected``: the response
      channel with the largest share (None when none changed); ``samples``:
      the samples compared;
    * ``noise_free_changed``: max |Δ| of the noise-free channels that
      changed (not in the SNR: no noise to measure them against).

    ``labels.json`` also holds the definition and the σ per channel and
    vehicle (key ``signature``). It costs one more simulation (no bag
    writing) per catalogue-effect bag and two σ runs per vehicle;
    ``--no-signature`` skips it.

Reproducible from ``--seed``: each vehicle has its own generator seeded from
(seed, vehicle), so a subset of vehicles gives the same bags for those
vehicles. Progress goes to stderr (with each bag's signature SNR and most
affected channel); ``--jobs`` simulates bags in parallel processes (same
output).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import math
import operator
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from terrain_estimation.bag import AtomicBagWriter, BagError
from terrain_estimation.cli import cli_main
from terrain_estimation.outputs import MARKER, OutputExistsError, prepare_output_dir
from terrain_estimation.params import ParameterError
from terrain_estimation.ros.time import ns_to_stamp, stamp_to_ns
from terrain_estimation.tools.estimate import topic_name
from vehicle_sim.effects import CATALOGUE, EffectParameter, effects_for
from vehicle_sim.ros.registry import get_simulator, simulator_parameters

__all__ = [
    "RESPONSE_TOPICS",
    "DURATIONS",
    "OUT_OF_CATALOGUE",
    "ROUGH_ROADS",
    "SIGMA_DURATION",
    "SIGMA_SEEDS",
    "VEHICLES",
    "BagPlan",
    "channel_differences",
    "draw_parameter",
    "effect_deltas",
    "generate",
    "main",
    "noise_sigma",
    "plan_suite",
    "record",
    "signature",
    "twin",
    "write_bag",
]

VEHICLES: tuple[str, ...] = ("quarter_car", "lrv", "skid_steer", "rover")

#: Default (min, max) duration (s) per vehicle.
DURATIONS: Mapping[str, tuple[float, float]] = {
    "quarter_car": (10.0, 20.0),
    "lrv": (10.0, 20.0),
    "skid_steer": (15.0, 20.0),
    "rover": (30.0, 60.0),
}

#: Out-of-catalogue effects: name → description (module docstring).
OUT_OF_CATALOGUE: Mapping[str, str] = {
    "imu_vibration": "sinusoidal vibration line added to every measured accelerometer axis",
    "accel_spikes": "random outliers (spikes) in the IMU's z accelerometer",
    "channel_scale": "scale error on a channel without a catalogue scale effect",
}

#: Per-vehicle magnitudes of the out-of-catalogue effects (m/s²).
_VIBRATION_AMPLITUDE = {"quarter_car": (1.0, 3.0), "lrv": (1.0, 3.0), "skid_steer": (0.3, 1.0), "rover": (0.05, 0.2)}
_SPIKE_MAGNITUDE = {"quarter_car": (5.0, 15.0), "lrv": (5.0, 15.0), "skid_steer": (3.0, 10.0), "rover": (0.3, 1.0)}
#: Channel of channel_scale: vehicle → (topic key of the adapter, description).
_SCALE_CHANNEL = {
    "quarter_car": ("profile", "terrain/profile point.z (profile sampler elevation)"),
    "lrv": ("profile", "terrain/profile point.z (profile sampler elevation)"),
    # The yaw gyro has a catalogue scale effect (gyro_scale, issue 22): one side's encoder stream instead (a
    # per-side rolling-radius / encoder-resolution error, which the catalogue's common radius error is not).
    "skid_steer": ("joint_states", "joint_states left_motor position and velocity (one side's encoder)"),
    "rover": ("velocimeter", "velocimeter twist.linear.x"),
}

_ROADS = ("B", "C", "D", "meadow_c")
#: Roads of the wheel-liftoff bags and of the rough-road controls (quarter car, LRV): ISO 8608
#: E and F. A unilateral contact changes the response only where the dynamic tyre load exceeds
#: the static one; on the roads above at the simulators' speeds it never does for the quarter
#: car (session 6: six of six wheel_liftoff bags identical to their twins, signature SNR 0), so
#: those bags tested whether the diagnosis could find an effect that was not there. Drawn with
#: the same random number as the others' road, so the rest of the suite is unchanged.
ROUGH_ROADS = ("E", "F")
_SOILS = {
    "quarter_car": ("graneville_loam", "upland_sandy_loam", "north_gower_clayey_loam", "rubicon_sandy_loam"),
    "lrv": ("graneville_loam", "upland_sandy_loam", "lete_sand", "lunar_regolith"),
}
_START_TIME_RANGE_S = (1.6e9, 1.8e9)
#: Rover: wheel-centre x of the front wheel at the start (body at x = 0) (m).
_ROVER_FRONT_WHEEL_X = 0.35
_NOTE_LABELS = (
    "Ground-truth labels of the withheld-effect suite: for the scorer only. "
    "The sim-to-real diagnosis must NEVER read this file; it is given manifest.json and the bags."
)
_NOTE_SIGNATURE = (
    "signature (per effect / out-of-catalogue label): the bag minus its twin (same plan, effects off, same noise), "
    "per noisy sensor channel Delta = y_effect - y_twin; snr = sqrt(sum over channels and samples of "
    "(Delta/sigma)^2), the matched-filter SNR of an ideal detector in white sensor noise; sigma per channel "
    "= RMS(y1 - y2)/sqrt(2) of two nominal runs differing only in the noise seed (noise_sigma below); "
    "over the vehicle's response topics (response_topics below; snr_all: every noisy channel). "
    "Noise-free channels (sigma = 0) are left out of the SNR and listed in noise_free_changed when they change."
)
_NOTE_MANIFEST = "What the diagnosis is given: bag id -> vehicle and bag path. Labels are withheld."


# ---------------------------------------------------------------------------
# Drawing
# ---------------------------------------------------------------------------


def draw_parameter(parameter: EffectParameter, rng: np.random.Generator) -> tuple[float, dict[str, Any]]:
    """A random value of one catalogue parameter and how it was drawn.

    Returns:
        (value, rule): ``rule["rule"]`` is ``"switch"``, ``"magnitude"`` (with
        ``lower``: the smallest deviation from off, and ``upper``) or
        ``"shape"``. See the module docstring.
    """
    if parameter.switch:
        return 1.0, {"rule": "switch"}
    lo, hi = parameter.fit_range
    off, typical = parameter.off, parameter.typical
    d = abs(typical - off)
    if d == 0.0:
        low = max(lo, typical / 2.0) if typical > 0 else lo
        high = min(hi, typical * 2.0) if typical > 0 else hi
        if low > 0:
            value = float(math.exp(rng.uniform(math.log(low), math.log(high))))
        else:
            value = float(rng.uniform(low, high))
        return value, {"rule": "shape", "range": [low, high]}
    rooms = {+1: hi - off, -1: off - lo}
    sides = [s for s in (+1, -1) if rooms[s] >= d * (1.0 - 1e-12)]
    if not sides:
        raise ValueError(
            f"parameter {parameter.name!r}: typical deviation {d:g} leaves no room in {parameter.fit_range}"
        )
    side = sides[int(rng.integers(len(sides)))] if len(sides) > 1 else sides[0]
    upper = min(3.0 * d, rooms[side])
    deviation = float(math.exp(rng.uniform(math.log(d), math.log(upper)))) if upper > d else d
    value = float(np.clip(off + side * deviation, lo, hi))
    return value, {"rule": "magnitude", "lower": d, "upper": upper}


@dataclass(frozen=True)
class BagPlan:
    """Everything needed to write one bag (picklable: sent to worker processes)."""

    id: str
    vehicle: str
    kind: str  # "effect" | "control" | "out_of_catalogue"
    effect: str | None
    parameters: dict[str, float]
    draw: dict[str, dict[str, Any]]
    out_of_catalogue: str | None
    ooc_parameters: dict[str, Any]
    scenario: dict[str, Any]
    seed: int
    duration: float
    start_time_ns: int
    path: str = field(default="")

    def label(self) -> dict[str, Any]:
        return {
            "vehicle": self.vehicle,
            "kind": self.kind,
            "effect": self.effect,
            "parameters": self.parameters,
            "draw": self.draw,
            "out_of_catalogue": self.out_of_catalogue,
            "out_of_catalogue_parameters": self.ooc_parameters,
            "scenario": self.scenario,
            "seed": self.seed,
            "duration": self.duration,
            "start_time_ns": self.start_time_ns,
            "bag": self.path,
        }


def _vehicle_rng(seed: int, vehicle: str) -> np.random.Generator:
    tag = int.from_bytes(hashlib.sha256(vehicle.encode()).digest()[:4], "little")
    return np.random.default_rng([int(seed), tag])


def _scenario(vehicle: str, rng: np.random.Generator, rough: bool = False) -> dict[str, Any]:
    if vehicle in ("quarter_car", "lrv"):
        soils = _SOILS[vehicle]
        pick = int(rng.integers(len(_ROADS)))
        roads = ROUGH_ROADS if rough else _ROADS
        return {
            "scenario.road": roads[pick % len(roads)],
            "scenario.road_seed": int(rng.integers(2**31 - 1)),
            "scenario.soils": [soils[int(rng.integers(len(soils)))]],
            "scenario.soil_starts": [0.0],
        }
    if vehicle == "skid_steer":
        from vehicle_sim.plants.skid_steer import MANOEUVRES

        names = sorted(MANOEUVRES)
        return {"scenario.manoeuvre": names[int(rng.integers(len(names)))]}
    if vehicle == "rover":
        from vehicle_sim.plants.rover import TERRAINS

        names = sorted(TERRAINS)
        return {"scenario.terrain": names[int(rng.integers(len(names)))]}
    raise ValueError(f"unknown vehicle {vehicle!r}; known: {', '.join(VEHICLES)}")


def _draw_effect(
    vehicle: str, effect: str, duration: float, desired_speed: float, rng: np.random.Generator
) -> tuple[dict[str, float], dict[str, dict[str, Any]]]:
    values: dict[str, float] = {}
    rules: dict[str, dict[str, Any]] = {}
    for p in CATALOGUE[vehicle][effect].parameters:
        if vehicle == "rover" and p.name == "soil_change_distance":
            travel = desired_speed * duration
            value = _ROVER_FRONT_WHEEL_X + float(rng.uniform(0.15, 0.6)) * travel
            value = float(np.clip(value, *p.fit_range))
            values[p.name], rules[p.name] = value, {"rule": "location", "travel": travel}
            continue
        values[p.name], rules[p.name] = draw_parameter(p, rng)
    if vehicle == "skid_steer":
        _skid_steer_draw(effect, values, rules, rng)
    if vehicle in ("quarter_car", "lrv"):
        _quarter_car_draw(vehicle, effect, values, rules, rng)
    return values, rules


#: Quarter car / LRV: stream latencies drawn log-uniformly over this range (s; issue 22: up to 0.3 s).
_QUARTER_CAR_DELAY_RANGE = (0.01, 0.3)
#: Quarter car / LRV nonlinear soil: |n − 1| drawn log-uniformly in these ranges, stiffening (n > 1) or softening.
_QUARTER_CAR_SOIL_STIFFENING = (0.2, 0.8)
_QUARTER_CAR_SOIL_SOFTENING = (0.2, 0.6)
#: Quarter car / LRV nonlinear soil: origin ratio ζ drawn log-uniformly in this range.
_QUARTER_CAR_SOIL_ORIGIN = (0.3, 3.0)


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def _quarter_car_draw(
    vehicle: str, effect: str, values: dict[str, float], rules: dict[str, dict[str, Any]], rng: np.random.Generator
) -> None:
    """Quarter-car / LRV rules on top of :func:`draw_parameter` (in place; issue 22).

    * ``sensor_delay``: one stream is late (a real latency sits on one
      driver or bus): one of the catalogue's latencies (quarter car: common
      accelerometer, body, wheel, profile; LRV: body, profile) drawn
      log-uniformly over :data:`_QUARTER_CAR_DELAY_RANGE`, the others 0.
    * ``accel_bias``, ``accel_scale`` (quarter car): each sensor's component
      stays with probability ½ (at least one), the others off.
    * ``nonlinear_soil``: stiffening (n − 1 log-uniform in
      :data:`_QUARTER_CAR_SOIL_STIFFENING`) or softening (1 − n in
      :data:`_QUARTER_CAR_SOIL_SOFTENING`) with equal chance, the origin
      ratio ζ log-uniform in :data:`_QUARTER_CAR_SOIL_ORIGIN`.
    """
    if effect == "sensor_delay":
        streams = [name for name in values if not (vehicle == "lrv" and name == "sensor_delay")]
        late = streams[int(rng.integers(len(streams)))]
        for name in values:
            values[name] = 0.0
            rules[name] = {"rule": "off (another stream is late)"}
        values[late] = _log_uniform(rng, *_QUARTER_CAR_DELAY_RANGE)
        rules[late] = {"rule": "single_stream", "range": list(_QUARTER_CAR_DELAY_RANGE)}
    elif effect in ("accel_bias", "accel_scale") and len(values) > 1:
        names = list(values)
        keep = [bool(rng.random() < 0.5) for _ in names]
        if not any(keep):
            keep[int(rng.integers(len(names)))] = True
        for name, kept in zip(names, keep, strict=True):
            if not kept:
                values[name] = 0.0
                rules[name] = {"rule": "off (one sensor)"}
    elif effect == "nonlinear_soil":
        stiffening = bool(rng.random() < 0.5)
        span = _QUARTER_CAR_SOIL_STIFFENING if stiffening else _QUARTER_CAR_SOIL_SOFTENING
        values["soil_exponent"] = 1.0 + (1.0 if stiffening else -1.0) * _log_uniform(rng, *span)
        rules["soil_exponent"] = {"rule": "stiffening" if stiffening else "softening", "range": list(span)}
        values["soil_origin_ratio"] = _log_uniform(rng, *_QUARTER_CAR_SOIL_ORIGIN)
        rules["soil_origin_ratio"] = {"rule": "shape", "range": list(_QUARTER_CAR_SOIL_ORIGIN)}


#: Skid steer: effects with one parameter per axis (or stream) of which a real case often has one
#: dominant component (a bank without a grade, one biased axis).
_SKID_STEER_PER_AXIS = ("accel_bias", "accel_scale", "gyro_bias", "terrain_grade")
#: Skid steer: stream latencies, drawn over their whole physical range (issue 22: up to 0.3 s).
_SKID_STEER_DELAYS = ("sensor_delay", "wheel_speed_delay")


def _skid_steer_draw(
    effect: str, values: dict[str, float], rules: dict[str, dict[str, Any]], rng: np.random.Generator
) -> None:
    """Skid-steer rules on top of :func:`draw_parameter` (in place; issue 22).

    * Per-axis effects (:data:`_SKID_STEER_PER_AXIS`): each component stays
      on with probability ½, at least one (chosen at random) on; the others
      are set to their off value (``rule`` ``"off (one sensor)"``, as the quarter car's). So the
      suite holds a bank alone, a grade alone, a bias on one axis.
    * Stream delays (:data:`_SKID_STEER_DELAYS`): log-uniform between the
      typical value and the top of the plausible range (0.05–0.3 s), a single stream
      per bag (the effect names the stream).
    """
    parameters = {p.name: p for p in CATALOGUE["skid_steer"][effect].parameters}
    if effect in _SKID_STEER_PER_AXIS and len(parameters) > 1:
        names = list(parameters)
        keep = [bool(rng.random() < 0.5) for _ in names]
        if not any(keep):
            keep[int(rng.integers(len(names)))] = True
        for name, on in zip(names, keep, strict=True):
            if not on:
                values[name] = parameters[name].off
                rules[name] = {"rule": "off (one sensor)"}
    if effect in _SKID_STEER_DELAYS:
        for name, p in parameters.items():
            low, high = abs(p.typical - p.off), p.plausible_range[1] - p.off
            values[name] = p.off + float(math.exp(rng.uniform(math.log(low), math.log(high))))
            rules[name] = {"rule": "single_stream", "range": [p.off + low, p.off + high]}


def _draw_ooc(vehicle: str, name: str, rng: np.random.Generator) -> dict[str, Any]:
    if name == "imu_vibration":
        lo, hi = _VIBRATION_AMPLITUDE[vehicle]
        return {
            "amplitude": float(rng.uniform(lo, hi)),
            "frequency_fraction_of_rate": float(rng.uniform(0.1, 0.4)),
            "phases": [float(v) for v in rng.uniform(0.0, 2.0 * math.pi, 3)],
        }
    if name == "accel_spikes":
        lo, hi = _SPIKE_MAGNITUDE[vehicle]
        return {
            "probability": float(rng.uniform(0.01, 0.03)),
            "magnitude_range": [lo, hi],
            "noise_seed": int(rng.integers(2**31 - 1)),
        }
    if name == "channel_scale":
        magnitude = float(rng.uniform(0.1, 0.3))
        sign = 1.0 if rng.random() < 0.5 else -1.0
        return {"scale_error": sign * magnitude, "channel": _SCALE_CHANNEL[vehicle][1]}
    raise ValueError(f"unknown out-of-catalogue effect {name!r}; known: {', '.join(OUT_OF_CATALOGUE)}")


def plan_suite(
    seed: int,
    vehicles: Sequence[str] = VEHICLES,
    *,
    per_effect: int,
    controls: int | None = None,
    out_of_catalogue: int | None = None,
    duration: float | None = None,
    effects: Sequence[str] | None = None,
    rough_controls: int | None = None,
) -> list[BagPlan]:
    """Draw the whole suite (no simulation): one :class:`BagPlan` per bag, in generation order.

    Args:
        seed: master seed.
        vehicles: vehicles to include.
        per_effect: bags per catalogue effect.
        controls: no-effect bags per vehicle (default ``per_effect``).
        out_of_catalogue: out-of-catalogue bags per vehicle, cycling through
            :data:`OUT_OF_CATALOGUE` (default ``per_effect`` × their number).
        duration: fixed duration (s) of every bag (default: drawn, :data:`DURATIONS`).
        effects: restrict to these catalogue effects (default: all; unknown
            names of a vehicle are an error only if no vehicle has them).
        rough_controls: quarter car and LRV: more no-effect bags on the
            rough roads (:data:`ROUGH_ROADS`), drawn after all others
            (default ``controls // 2``).
    """
    if per_effect < 0:
        raise ValueError(f"per-effect must be >= 0, got {per_effect}")
    n_controls = per_effect if controls is None else controls
    n_ooc = per_effect * len(OUT_OF_CATALOGUE) if out_of_catalogue is None else out_of_catalogue
    n_rough = n_controls // 2 if rough_controls is None else rough_controls
    if n_controls < 0 or n_ooc < 0 or n_rough < 0:
        raise ValueError(
            f"controls, out-of-catalogue and rough-road control counts must be >= 0, "
            f"got {n_controls}, {n_ooc}, {n_rough}"
        )
    if duration is not None and not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    for v in vehicles:
        if v not in VEHICLES:
            raise ValueError(f"unknown vehicle {v!r}; known: {', '.join(VEHICLES)}")
    if effects is not None:
        known = {name for v in vehicles for name in CATALOGUE[v]}
        unknown = sorted(set(effects) - known)
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown} for vehicles {list(vehicles)}; known: {sorted(known)}")
    plans: list[BagPlan] = []
    ids: set[str] = set()
    ooc_names = tuple(OUT_OF_CATALOGUE)
    for vehicle in vehicles:
        rng = _vehicle_rng(seed, vehicle)
        desired_speed = 0.02
        if vehicle == "rover":
            entry = get_simulator("rover")
            desired_speed = float(simulator_parameters(entry)["scenario.desired_speed"])
        jobs: list[tuple[str, str | None, str | None, bool]] = []  # kind, effect, out-of-catalogue, rough road
        for name in CATALOGUE[vehicle]:
            if effects is None or name in effects:
                jobs += [("effect", name, None, name == "wheel_liftoff")] * per_effect
        jobs += [("control", None, None, False)] * n_controls
        jobs += [("out_of_catalogue", None, ooc_names[i % len(ooc_names)], False) for i in range(n_ooc)]
        if vehicle in _SOILS:
            jobs += [("control", None, None, True)] * n_rough
        for kind, effect, ooc, rough in jobs:
            bag_id = rng.bytes(6).hex()
            while bag_id in ids:
                bag_id = rng.bytes(6).hex()
            ids.add(bag_id)
            lo, hi = DURATIONS[vehicle]
            length = float(duration) if duration is not None else round(float(rng.uniform(lo, hi)), 2)
            scenario = _scenario(vehicle, rng, rough)
            bag_seed = int(rng.integers(2**31 - 1))
            start = int(rng.integers(int(_START_TIME_RANGE_S[0] * 1e9), int(_START_TIME_RANGE_S[1] * 1e9)))
            values: dict[str, float] = {}
            rules: dict[str, dict[str, Any]] = {}
            ooc_values: dict[str, Any] = {}
            if effect is not None:
                values, rules = _draw_effect(vehicle, effect, length, desired_speed, rng)
            if ooc is not None:
                ooc_values = _draw_ooc(vehicle, ooc, rng)
            plans.append(
                BagPlan(
                    id=bag_id,
                    vehicle=vehicle,
                    kind=kind,
                    effect=effect,
                    parameters=values,
                    draw=rules,
                    out_of_catalogue=ooc,
                    ooc_parameters=ooc_values,
                    scenario=scenario,
                    seed=bag_seed,
                    duration=length,
                    start_time_ns=start,
                    path=f"bags/{bag_id}",
                )
            )
    return plans


# ---------------------------------------------------------------------------
# Simulating
# ---------------------------------------------------------------------------


def _install_effects(adapter: Any, vehicle: str, plan: BagPlan) -> None:
    """Replace the adapter's plant effects by the catalogue's (nominal + the plan's effect) and rebuild its simulator.

    The adapters expose only some effects as parameters (the rover none of
    slip-sinkage, grousers, path undulation or the soil-change scales), so the
    plant's effects object is built with :func:`vehicle_sim.effects.effects_for`
    and the simulator rebuilt the way the adapter builds it.
    """
    named = {plan.effect: plan.parameters} if plan.effect is not None else {}
    if vehicle in ("quarter_car", "lrv"):
        from vehicle_sim.plants.quarter_car import QuarterCarSimulator

        adapter.scenario = replace(adapter.scenario, effects=effects_for(vehicle, named))
        adapter.simulator = QuarterCarSimulator(adapter.vehicle, adapter.scenario, plan.seed)
    elif vehicle == "skid_steer":
        from vehicle_sim.plants.skid_steer import SkidSteerSimulator
        from vehicle_sim.plants.skid_steer_ground import SkidSteerGround

        # The catalogue's nominal model: the brush tire (B.4) on level, uniform ground, whatever the node's truth.
        adapter.scenario = replace(
            adapter.scenario,
            vehicle=replace(adapter.scenario.vehicle, tire_law="brush"),
            ground=SkidSteerGround(),
            effects=effects_for(vehicle, named),
        )
        adapter.simulator = SkidSteerSimulator(adapter.scenario, plan.seed)
    elif vehicle == "rover":
        from vehicle_sim.plants.rover import RoverSimulator

        effects = effects_for(vehicle, named, soil=adapter.scenario.soil)
        adapter.scenario = replace(adapter.scenario, effects=effects)
        adapter.simulator = RoverSimulator(adapter.scenario)
    else:
        raise ValueError(f"unknown vehicle {vehicle!r}")


_AXES = ("x", "y", "z")


def _ooc_transform(plan: BagPlan, imu_keys: Sequence[str], rate: float) -> Callable[[str, Any, float], None]:
    """In-place message transform of the plan's out-of-catalogue effect (identity if none)."""
    name, values = plan.out_of_catalogue, plan.ooc_parameters
    if name is None:
        return lambda key, msg, t: None
    if name == "imu_vibration":
        amplitude = float(values["amplitude"])
        omega = 2.0 * math.pi * float(values["frequency_fraction_of_rate"]) * rate
        phases = values["phases"]

        def vibrate(key: str, msg: Any, t: float) -> None:
            if key not in imu_keys:
                return
            acc, cov = msg.linear_acceleration, msg.linear_acceleration_covariance
            for i, axis in enumerate(_AXES):
                if cov[4 * i] > 0.0:
                    setattr(acc, axis, getattr(acc, axis) + amplitude * math.sin(omega * t + phases[i]))

        return vibrate
    if name == "accel_spikes":
        rng = np.random.default_rng(int(values["noise_seed"]))
        p = float(values["probability"])
        lo, hi = values["magnitude_range"]
        target = imu_keys[0]

        def spike(key: str, msg: Any, t: float) -> None:
            if key != target:
                return
            hit, magnitude, sign = rng.random(), rng.uniform(lo, hi), rng.random() < 0.5
            if hit < p:
                msg.linear_acceleration.z += magnitude if sign else -magnitude

        return spike
    if name == "channel_scale":
        factor = 1.0 + float(values["scale_error"])
        channel_key = _SCALE_CHANNEL[plan.vehicle][0]

        def scale(key: str, msg: Any, t: float) -> None:
            if key != channel_key:
                return
            if plan.vehicle in ("quarter_car", "lrv"):
                msg.point.z *= factor
            elif plan.vehicle == "skid_steer":
                index = list(msg.name).index("left_motor")
                position, velocity = list(msg.position), list(msg.velocity)
                position[index] *= factor
                velocity[index] *= factor
                msg.position, msg.velocity = position, velocity
            else:
                msg.twist.linear.x *= factor

        return scale
    raise ValueError(f"unknown out-of-catalogue effect {name!r}")


def _open(plan: BagPlan) -> tuple[Any, dict[str, tuple[str, str]], list[str]]:
    """The plan's adapter (effects installed), its kept sensor topics (key → (bag topic, topic)) and IMU keys."""
    entry = get_simulator(plan.vehicle)
    overrides: dict[str, Any] = {**plan.scenario, "seed": plan.seed}
    if plan.vehicle in ("skid_steer", "rover"):
        overrides["scenario.duration"] = plan.duration + 1.0  # margin: the loop stops at plan.duration
    values = simulator_parameters(entry, None, overrides)
    adapter = entry.make_adapter(values, entry.namespace)
    _install_effects(adapter, plan.vehicle, plan)
    keep = {
        spec.key: (topic_name(entry.namespace, spec.topic), spec.topic)
        for spec in adapter.outputs
        if spec.kind == "sensor" and not spec.topic.startswith("ground_truth")
    }
    imu_keys = [spec.key for spec in adapter.outputs if spec.key in keep and spec.topic.startswith("imu")]
    return adapter, keep, imu_keys


def _messages(adapter: Any, keep: Mapping[str, tuple[str, str]], duration: float) -> Iterator[tuple[str, Any, int]]:
    """(key, message, stamp in ns from the run's start) of every kept sensor message of a run of ``duration``."""
    t = 0.0
    while t < duration - 1e-9:
        t, messages = adapter.step()
        for key, msg in messages:
            if key in keep:
                yield key, msg, stamp_to_ns(msg.header.stamp)


# ---------------------------------------------------------------------------
# Effect signature (labels only: the diagnosis never sees it)
# ---------------------------------------------------------------------------

#: Noise σ of a vehicle's channels: from two nominal runs of this length (s) with these noise seeds.
SIGMA_DURATION = 10.0
SIGMA_SEEDS = (1, 2)
_NUMERIC_TYPES = frozenset(
    {"double", "float", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"}
)
_QUATERNION_TYPE = "geometry_msgs/Quaternion"


@dataclass(frozen=True)
class _Field:
    path: str
    kind: str  # "scalar" | "array" | "quaternion"
    get: Callable[[Any], Any]


_LAYOUTS: dict[type, tuple[_Field, ...]] = {}


def _layout(msg_type: type) -> tuple[_Field, ...]:
    """The numeric leaves of a message type: scalars, numeric arrays/sequences and quaternions.

    Generic over rosidl message types: left out are the header, strings,
    booleans, ``*covariance`` arrays (metadata, not readings) and arrays of
    messages.
    """
    fields: list[_Field] = []

    def walk(cls: type, prefix: str) -> None:
        instance = cls()
        for name, typ in cls.get_fields_and_field_types().items():  # type: ignore[attr-defined]
            path = f"{prefix}{name}"
            if name == "header" or name.endswith("covariance"):
                continue
            is_array = typ.startswith("sequence<") or typ.endswith("]")
            base = typ[len("sequence<") :].split(",")[0].rstrip(">") if typ.startswith("sequence<") else typ
            base = base.split("[")[0].strip()
            if base in _NUMERIC_TYPES:
                fields.append(_Field(path, "array" if is_array else "scalar", operator.attrgetter(path)))
            elif "/" in base and not is_array:
                if base == _QUATERNION_TYPE:
                    fields.append(_Field(path, "quaternion", operator.attrgetter(path)))
                else:
                    walk(type(getattr(instance, name)), f"{path}.")

    cached = _LAYOUTS.get(msg_type)
    if cached is None:
        walk(msg_type, "")
        cached = _LAYOUTS[msg_type] = tuple(fields)
    return cached


Series = tuple[np.ndarray, list[str], np.ndarray, list[str], np.ndarray]
"""One topic of a recorded run: stamps (ns), channel names, values (N, C), quaternion names, quaternions (N, Q, 4)."""


class _Recorder:
    """Collects the numeric channels of a run's sensor messages, per topic."""

    def __init__(self) -> None:
        self._stamps: dict[str, list[int]] = {}
        self._names: dict[str, tuple[list[str], list[str]]] = {}
        self._rows: dict[str, list[list[float]]] = {}
        self._quats: dict[str, list[list[float]]] = {}

    def add(self, topic: str, stamp_ns: int, msg: Any) -> None:
        layout = _layout(type(msg))
        row: list[float] = []
        quat: list[float] = []
        if topic not in self._names:
            names: list[str] = []
            quat_names: list[str] = []
            labels = list(getattr(msg, "name", [])) if hasattr(msg, "name") else []
            for f in layout:
                if f.kind == "scalar":
                    names.append(f"{topic} {f.path}")
                elif f.kind == "array":
                    n = len(f.get(msg))
                    tags = labels if len(labels) == n and all(isinstance(x, str) for x in labels) else range(n)
                    names += [f"{topic} {f.path}[{tag}]" for tag in tags]
                else:
                    quat_names.append(f"{topic} {f.path}")
            self._names[topic] = (names, quat_names)
            self._stamps[topic], self._rows[topic], self._quats[topic] = [], [], []
        for f in layout:
            value = f.get(msg)
            if f.kind == "scalar":
                row.append(float(value))
            elif f.kind == "array":
                row.extend(float(v) for v in value)
            else:
                quat += (float(value.x), float(value.y), float(value.z), float(value.w))
        if len(row) != len(self._names[topic][0]):
            raise ValueError(f"{topic}: the message layout changed during the run ({len(row)} values)")
        self._stamps[topic].append(stamp_ns)
        self._rows[topic].append(row)
        self._quats[topic].append(quat)

    def series(self) -> dict[str, Series]:
        """topic → (stamps, scalar channel names, values (N, C), quaternion names, quaternions (N, Q, 4))."""
        out: dict[str, Series] = {}
        for topic, stamps in self._stamps.items():
            names, quat_names = self._names[topic]
            n = len(stamps)
            values = np.asarray(self._rows[topic], dtype=float).reshape(n, len(names))
            quats = np.asarray(self._quats[topic], dtype=float).reshape(n, len(quat_names), 4)
            out[topic] = (np.asarray(stamps, dtype=np.int64), names, values, quat_names, quats)
        return out


def _rotation_vector(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of qb⁻¹ ⊗ qa, (..., 4) (x, y, z, w) → (..., 3): the wrap-free orientation difference."""
    av, aw, bv, bw = qa[..., :3], qa[..., 3:], qb[..., :3], qb[..., 3:]
    w = aw * bw + np.sum(av * bv, axis=-1, keepdims=True)
    v = bw * av - aw * bv - np.cross(bv, av)
    sign = np.where(w < 0.0, -1.0, 1.0)
    w, v = w * sign, v * sign
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(norm, w)
    factor = np.divide(angle, norm, out=np.full_like(norm, 2.0), where=norm > 1e-12)
    return v * factor


def channel_differences(
    a: Mapping[str, Series],
    b: Mapping[str, Series],
) -> dict[str, np.ndarray]:
    """Per channel, the sample-by-sample difference a − b of two recorded runs (aligned on the stamps).

    A quaternion field gives three channels ``<field>.r{x,y,z}``: the rotation
    vector of b⁻¹ ⊗ a (no wrap at ±π, no q ≡ −q jump).
    """
    if set(a) != set(b):
        raise ValueError(f"the runs record different topics: {sorted(set(a) ^ set(b))}")
    out: dict[str, np.ndarray] = {}
    for topic in sorted(a):
        sa, names, va, qnames, qa = a[topic]
        sb, names_b, vb, qnames_b, qb = b[topic]
        if names != names_b or qnames != qnames_b:
            raise ValueError(f"{topic}: the runs record different channels")
        if not np.array_equal(sa, sb):
            _, ia, ib = np.intersect1d(sa, sb, assume_unique=True, return_indices=True)
            va, vb, qa, qb = va[ia], vb[ib], qa[ia], qb[ib]
        for j, name in enumerate(names):
            out[name] = va[:, j] - vb[:, j]
        for j, name in enumerate(qnames):
            rv = _rotation_vector(qa[:, j], qb[:, j])
            for k, axis in enumerate("xyz"):
                out[f"{name}.r{axis}"] = rv[:, k]
    return out


def record(plan: BagPlan) -> dict[str, Series]:
    """Simulate ``plan`` (plant only: no out-of-catalogue transform, nothing written) and record its channels."""
    adapter, keep, _ = _open(plan)
    recorder = _Recorder()
    for key, msg, stamp in _messages(adapter, keep, plan.duration):
        recorder.add(keep[key][1], stamp, msg)
    return recorder.series()


def twin(plan: BagPlan) -> BagPlan:
    """The plan with every effect off: same scenario, noise seed, duration and start time."""
    return replace(plan, effect=None, parameters={}, draw={}, out_of_catalogue=None, ooc_parameters={})


def _nominal_plan(vehicle: str, seed: int, duration: float) -> BagPlan:
    return BagPlan(
        id=f"sigma-{seed}",
        vehicle=vehicle,
        kind="control",
        effect=None,
        parameters={},
        draw={},
        out_of_catalogue=None,
        ooc_parameters={},
        scenario={},
        seed=seed,
        duration=duration,
        start_time_ns=0,
    )


@functools.cache
def _noise_sigma(vehicle: str, duration: float, seeds: tuple[int, int]) -> tuple[tuple[str, float], ...]:
    a, b = (record(_nominal_plan(vehicle, seed, duration)) for seed in seeds)
    return tuple(
        (name, float(np.sqrt(np.mean(d * d)) / math.sqrt(2.0)) if d.size else 0.0)
        for name, d in channel_differences(a, b).items()
    )


def noise_sigma(
    vehicle: str, duration: float = SIGMA_DURATION, seeds: tuple[int, int] = SIGMA_SEEDS
) -> dict[str, float]:
    """Sensor-noise σ per channel of ``vehicle``: RMS(y₁ − y₂)/√2 of two nominal runs differing only in the noise seed.

    The vehicle's default scenario, every catalogue effect off. A channel with
    σ = 0 is noise-free (the two runs agree bit for bit). Cached per process.
    """
    return dict(_noise_sigma(vehicle, float(duration), (int(seeds[0]), int(seeds[1]))))


def _g4(x: float) -> float:
    return float(f"{x:.4g}")


#: Per vehicle, the topics whose channels count in the signature's ``snr``: the vehicle's
#: *responses*. Left out are the inputs every replay of the vehicle is driven by (the
#: measured road profile; the drive's commands and encoders in joint_states) and the GNSS
#: fix (an integral of the motion: its drift from an unknown start is no evidence a blind
#: diagnosis can use). Their channels are still listed, with ``in_snr`` false.
RESPONSE_TOPICS: Mapping[str, tuple[str, ...]] = {
    "quarter_car": ("imu/body", "imu/wheel"),
    "lrv": ("imu/body",),
    "skid_steer": ("imu",),
    "rover": ("imu", "velocimeter", "wheel/front/load", "wheel/middle/load", "wheel/rear/load"),
}


def _topic_of(channel: str) -> str:
    return channel.split(" ", 1)[0]


def signature(
    deltas: Mapping[str, np.ndarray], sigma: Mapping[str, float], response: Sequence[str] | None = None
) -> dict[str, Any]:
    """The effect signature of the differences ``deltas`` (effect − twin) given the noise σ per channel.

    Returns ``snr`` = sqrt(Σ_channels Σ_samples (Δ/σ)²) over the noisy
    channels (σ > 0) of the ``response`` topics (default: every topic; see
    :data:`RESPONSE_TOPICS`), ``snr_all`` over every noisy channel, per noisy
    channel ``rms_over_sigma`` = RMS(Δ)/σ, its own ``snr`` (its share) and
    ``in_snr``, ``most_affected`` (the response channel of the largest share;
    None when none changed), ``samples`` compared, and ``noise_free_changed``:
    max |Δ| of the noise-free channels (σ = 0) that changed, which are left
    out of the SNR (no noise scale to measure them against).
    """
    total = 0.0
    total_all = 0.0
    samples = 0
    channels: dict[str, dict[str, float]] = {}
    noise_free: dict[str, float] = {}
    for name, d in deltas.items():
        s = sigma.get(name)
        if s is None:
            raise ValueError(f"no noise sigma for channel {name!r}")
        if not s > 0.0:
            if d.size and np.any(d != 0.0):
                noise_free[name] = _g4(float(np.max(np.abs(d))))
            continue
        z2 = float(np.sum((d / s) ** 2))
        counted = response is None or _topic_of(name) in response
        total_all += z2
        if counted:
            total += z2
            samples += d.size
        channels[name] = {
            "rms_over_sigma": _g4(math.sqrt(z2 / d.size)) if d.size else 0.0,
            "snr": _g4(math.sqrt(z2)),
            "in_snr": counted,
        }
    counted_names = [c for c in channels if channels[c]["in_snr"]]
    most = max(counted_names, key=lambda c: channels[c]["snr"]) if total > 0.0 else None
    return {
        "snr": _g4(math.sqrt(total)),
        "snr_all": _g4(math.sqrt(total_all)),
        "most_affected": most,
        "samples": samples,
        "channels": channels,
        "noise_free_changed": noise_free,
    }


def effect_deltas(plan: BagPlan, *, simulate_twin: bool = False) -> dict[str, np.ndarray]:
    """Δ = y_effect − y_twin per channel of ``plan`` (no bag written).

    The twin is simulated separately when the plan has a plant effect (or
    ``simulate_twin``); otherwise it is the same run before the
    out-of-catalogue transform, which is what :func:`write_bag` does.
    """
    adapter, keep, imu_keys = _open(plan)
    transform = _ooc_transform(plan, imu_keys, 1.0 / float(adapter.period))
    effect, same_run = _Recorder(), _Recorder()
    for key, msg, stamp in _messages(adapter, keep, plan.duration):
        same_run.add(keep[key][1], stamp, msg)
        transform(key, msg, stamp * 1e-9)
        effect.add(keep[key][1], stamp, msg)
    reference = record(twin(plan)) if plan.effect is not None or simulate_twin else same_run.series()
    return channel_differences(effect.series(), reference)


def write_bag(plan: BagPlan, out: str | Path, sigma: Mapping[str, float] | None = None) -> dict[str, Any]:
    """Simulate ``plan`` and write its bag to ``out/plan.path``; return timing and message counts.

    With ``sigma`` (:func:`noise_sigma` of the vehicle), a bag of kind
    ``effect`` or ``out_of_catalogue`` also gets its effect ``signature``
    (:func:`signature`) against its twin (:func:`twin`): simulated
    separately when the plan has a plant effect, else recorded from the same
    run before the out-of-catalogue transform (which changes messages only).
    """
    started = time.monotonic()
    adapter, keep, imu_keys = _open(plan)
    transform = _ooc_transform(plan, imu_keys, 1.0 / float(adapter.period))
    measure = sigma is not None and plan.kind != "control"
    effect = _Recorder() if measure else None
    same_run = _Recorder() if measure and plan.effect is None else None
    offset = plan.start_time_ns
    with AtomicBagWriter(Path(out) / plan.path) as writer:
        for key, msg, stamp in _messages(adapter, keep, plan.duration):
            topic, short = keep[key]
            if same_run is not None:
                same_run.add(short, stamp, msg)
            transform(key, msg, stamp * 1e-9)
            if effect is not None:
                effect.add(short, stamp, msg)
            msg.header.stamp = ns_to_stamp(stamp + offset)
            writer.write(topic, msg, stamp + offset)
        count = writer.count
    result: dict[str, Any] = {"id": plan.id, "messages": count}
    if effect is not None and sigma is not None:
        reference = same_run.series() if same_run is not None else record(twin(plan))
        deltas = channel_differences(effect.series(), reference)
        result["signature"] = signature(deltas, sigma, RESPONSE_TOPICS.get(plan.vehicle))
    result["seconds"] = time.monotonic() - started
    return result


def _write_job(args: tuple[BagPlan, str, Mapping[str, float] | None]) -> dict[str, Any]:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    return write_bag(*args)


def _sigma_job(vehicle: str) -> dict[str, float]:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    return noise_sigma(vehicle)


def _write_json(path: Path, data: Any) -> None:
    tmp = path.with_name(f".{path.name}.partial")
    tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    tmp.replace(path)


def generate(
    out: str | Path,
    plans: Sequence[BagPlan],
    *,
    jobs: int = 1,
    progress: bool = True,
    signatures: bool = True,
) -> dict[str, Any]:
    """Write the bags of ``plans``, ``manifest.json`` and ``labels.json`` under ``out``.

    With ``signatures`` (default), every ``effect`` and ``out_of_catalogue``
    label gets the bag's effect ``signature`` (module docstring), and
    ``labels.json`` the noise σ per channel of each vehicle
    (``noise_sigma``). A previous suite of this tool's in ``out`` is replaced; a directory
    it did not create is refused. Returns a summary
    (bag count, seconds).
    """
    tool = "vehicle_sim.tools.withheld"
    root = prepare_output_dir(out, tool=tool)  # refuses a non-empty directory no project tool made
    bags = root / "bags"
    if bags.exists():
        marker = root / MARKER
        if not (marker.is_file() and marker.read_text().startswith(f"created by {tool}:")):
            raise OutputExistsError(f"{str(bags)!r} exists in a directory this tool did not create: not replaced")
        shutil.rmtree(bags)  # a previous suite of this tool's
    for name in ("manifest.json", "labels.json"):
        (root / name).unlink(missing_ok=True)
    started = time.monotonic()
    total = len(plans)
    vehicles = list(dict.fromkeys(p.vehicle for p in plans if p.kind != "control")) if signatures else []
    results: dict[str, dict[str, Any]] = {}

    def report(i: int, plan: BagPlan, result: dict[str, Any]) -> None:
        results[plan.id] = result
        if progress:
            sig = result.get("signature")
            seen = f"; signature SNR {sig['snr']:.3g} ({sig['most_affected'] or 'no change'})" if sig else ""
            print(
                f"[{i}/{total}] {plan.vehicle} {plan.id}: {plan.duration:g} s simulated, "
                f"{result['messages']} messages in {result['seconds']:.1f} s{seen}",
                file=sys.stderr,
            )

    def report_sigma(vehicle: str, sigma: Mapping[str, float], seconds: float) -> None:
        if progress:
            noisy = sum(s > 0.0 for s in sigma.values())
            print(
                f"noise sigma of {vehicle}: {noisy} noisy of {len(sigma)} channels "
                f"(2 x {SIGMA_DURATION:g} s nominal runs) in {seconds:.1f} s",
                file=sys.stderr,
            )

    sigmas: dict[str, dict[str, float]] = {}
    if jobs <= 1:
        for vehicle in vehicles:
            t0 = time.monotonic()
            sigmas[vehicle] = noise_sigma(vehicle)
            report_sigma(vehicle, sigmas[vehicle], time.monotonic() - t0)
        for i, plan in enumerate(plans, 1):
            report(i, plan, write_bag(plan, root, sigmas.get(plan.vehicle)))
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            t0 = time.monotonic()
            for vehicle, sigma in zip(vehicles, pool.map(_sigma_job, vehicles), strict=True):
                sigmas[vehicle] = sigma
                report_sigma(vehicle, sigma, time.monotonic() - t0)
            work = [(p, str(root), sigmas.get(p.vehicle)) for p in plans]
            for i, (plan, result) in enumerate(zip(plans, pool.map(_write_job, work), strict=True), 1):
                report(i, plan, result)
    manifest = {
        "note": _NOTE_MANIFEST,
        "bags": [{"id": p.id, "vehicle": p.vehicle, "bag": p.path} for p in sorted(plans, key=lambda p: p.id)],
    }
    labels: dict[str, Any] = {"note": _NOTE_LABELS, "labels": {}}
    for p in sorted(plans, key=lambda p: p.id):
        label = p.label()
        if "signature" in results[p.id]:
            label["signature"] = results[p.id]["signature"]
        labels["labels"][p.id] = label
    if sigmas:
        labels["signature"] = {
            "definition": _NOTE_SIGNATURE,
            "sigma_runs": {"duration": SIGMA_DURATION, "seeds": list(SIGMA_SEEDS)},
            "noise_sigma": {v: {c: _g4(s) for c, s in sigma.items()} for v, sigma in sigmas.items()},
            "response_topics": {v: list(RESPONSE_TOPICS.get(v, ())) for v in sigmas},
        }
    _write_json(root / "manifest.json", manifest)
    _write_json(root / "labels.json", labels)
    return {"bags": total, "seconds": time.monotonic() - started}


@cli_main("withheld")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m vehicle_sim.tools.withheld", description=(__doc__ or "").splitlines()[0]
    )
    parser.add_argument(
        "--out", required=True, help="output directory (its bags/, manifest.json, labels.json are replaced)"
    )
    parser.add_argument("--per-effect", type=int, required=True, help="bags per catalogue effect and vehicle")
    parser.add_argument("--seed", type=int, required=True, help="master seed (never given to the diagnosis)")
    parser.add_argument("--vehicle", action="append", choices=VEHICLES, help="vehicle(s) (default: all)")
    parser.add_argument("--duration", type=float, help="fixed duration of every bag (s); default: drawn per vehicle")
    parser.add_argument("--controls", type=int, help="no-effect bags per vehicle (default: --per-effect)")
    parser.add_argument(
        "--out-of-catalogue",
        type=int,
        help=f"out-of-catalogue bags per vehicle, cycling {', '.join(OUT_OF_CATALOGUE)} (default: 3 x --per-effect)",
    )
    parser.add_argument(
        "--rough-controls",
        type=int,
        help="quarter car and LRV: more no-effect bags on ISO 8608 E/F roads (default: half of --controls)",
    )
    parser.add_argument("--effect", action="append", help="only these catalogue effects (default: all)")
    parser.add_argument("--jobs", type=int, default=1, help="parallel simulation processes (default 1)")
    parser.add_argument(
        "--no-signature",
        action="store_true",
        help="skip the effect signatures in labels.json (no twin simulations: about half the time)",
    )
    args = parser.parse_args(argv)
    vehicles = tuple(dict.fromkeys(args.vehicle)) if args.vehicle else VEHICLES
    try:
        plans = plan_suite(
            args.seed,
            vehicles,
            per_effect=args.per_effect,
            controls=args.controls,
            out_of_catalogue=args.out_of_catalogue,
            duration=args.duration,
            effects=args.effect,
            rough_controls=args.rough_controls,
        )
        if not plans:
            raise ValueError("nothing to generate (all counts are 0)")
        print(f"withheld: generating {len(plans)} bags for {', '.join(vehicles)} in {args.out}", file=sys.stderr)
        summary = generate(args.out, plans, jobs=max(1, args.jobs), signatures=not args.no_signature)
    except (BagError, ParameterError, ValueError, OSError) as exc:
        print(f"withheld: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("withheld: interrupted; the suite is incomplete", file=sys.stderr)
        return 130
    print(
        f"wrote {summary['bags']} bags in {summary['seconds']:.1f} s to {args.out} "
        f"(manifest.json for the diagnosis, labels.json for the scorer only)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
