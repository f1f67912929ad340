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
import math
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from terrain_estimation.bag import AtomicBagWriter, BagError
from terrain_estimation.cli import cli_main
from terrain_estimation.outputs import MARKER, OutputExistsError, prepare_output_dir
from terrain_estimation.params import ParameterError
from terrain_estimation.ros.time import ns_to_stamp, stamp_to_ns
from terrain_estimation.tools.estimate import topic_name
from vehicle_sim.effects import effects_for
from vehicle_sim.independent.blind_suite import g4, map_jobs, run_suite_cli, worker_pool, write_manifest_and_labels
from vehicle_sim.ros.registry import get_simulator, simulator_parameters
from vehicle_sim.tools.withheld_plan import (
    _SCALE_CHANNEL,
    DURATIONS,
    OUT_OF_CATALOGUE,
    ROUGH_ROADS,
    VEHICLES,
    BagPlan,
    draw_parameter,
    plan_suite,
)
from vehicle_sim.tools.withheld_signature import RESPONSE_TOPICS, Series, _Recorder, signature

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
    with worker_pool(jobs) as pool:
        t0 = time.monotonic()
        for vehicle, sigma in zip(vehicles, map_jobs(_sigma_job, vehicles, pool), strict=True):
            sigmas[vehicle] = sigma
            report_sigma(vehicle, sigma, time.monotonic() - t0)
            t0 = time.monotonic()
        work = [(p, str(root), sigmas.get(p.vehicle)) for p in plans]
        for i, (plan, result) in enumerate(zip(plans, map_jobs(_write_job, work, pool), strict=True), 1):
            report(i, plan, result)
    manifest: dict[str, Any] = {"note": _NOTE_MANIFEST}
    labels: dict[str, Any] = {"note": _NOTE_LABELS}
    if sigmas:
        labels["signature"] = {
            "definition": _NOTE_SIGNATURE,
            "sigma_runs": {"duration": SIGMA_DURATION, "seeds": list(SIGMA_SEEDS)},
            "noise_sigma": {v: {c: g4(s) for c, s in sigma.items()} for v, sigma in sigmas.items()},
            "response_topics": {v: list(RESPONSE_TOPICS.get(v, ())) for v in sigmas},
        }
    write_manifest_and_labels(root, plans, results, manifest, labels)
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
    return run_suite_cli(
        "withheld",
        args,
        VEHICLES,
        plan_suite,
        generate,
        (BagError, ParameterError, ValueError, OSError),
        plan_options={"rough_controls": args.rough_controls},
    )


if __name__ == "__main__":
    sys.exit(main())
