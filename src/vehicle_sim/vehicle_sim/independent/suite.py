"""Drawing, simulating and writing the independent generator's suite (see the package docstring)."""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from vehicle_sim.independent import messages as msgs
from vehicle_sim.independent import quarter_car as qc
from vehicle_sim.independent import skid_steer as ss
from vehicle_sim.independent.blind_suite import (
    check_request,
    draw_bag,
    g4,
    keep_some,
    log_uniform,
    map_jobs,
    run_suite_cli,
    vehicle_rng,
    worker_pool,
    write_manifest_and_labels,
)

__all__ = [
    "EFFECTS",
    "OUT_OF_CATALOGUE",
    "VEHICLES",
    "Plan",
    "generate",
    "main",
    "plan_suite",
    "streams",
    "write_bag",
]

VEHICLES = ("quarter_car", "skid_steer")
#: Effects per vehicle, named as the catalogue's effect of the same physics.
EFFECTS: dict[str, tuple[str, ...]] = {
    "quarter_car": (
        "sensor_delay",
        "accel_bias",
        "accel_scale",
        "nonlinear_soil",
        "sprung_mass_change",
        "tire_damping",
        "suspension_friction",
        "tire_enveloping",
        "wheel_liftoff",
    ),
    "skid_steer": (
        "sensor_delay",
        "wheel_speed_delay",
        "accel_bias",
        "accel_scale",
        "gyro_bias",
        "gyro_scale",
        "terrain_grade",
        "tire_relaxation",
        "friction_change",
        "cornering_stiffness_change",
        "wheel_radius_error",
        "turning_resistance",
    ),
}
#: Out-of-catalogue effects (none of them in vehicle_sim.tools.withheld.OUT_OF_CATALOGUE).
OUT_OF_CATALOGUE: dict[str, str] = {
    "sample_dropouts": "bursts in which the IMU stream repeats its last reading (a bus or driver glitch)",
    "accel_lowpass": "a first-order low-pass (an on-chip digital filter set too low) on the IMU's readings",
    "clock_drift": "the IMU stream's clock runs fast or slow: its stamps drift against the other streams",
}
STRUCTURE = {
    "quarter_car": "viscoelastic (Zener) soil: a spring in parallel with a Maxwell branch (frequency-dependent)",
    "skid_steer": "Dugoff tire law instead of the brush law, same C_x, C_alpha and mu",
}
DURATIONS = {"quarter_car": (10.0, 20.0), "skid_steer": (15.0, 20.0)}
NAMESPACE = {"quarter_car": "/quarter_car", "skid_steer": "/skid_steer"}
_ROADS = ("B", "C", "D")
_ROUGH = ("E", "F")
_SOILS = ("graneville_loam", "upland_sandy_loam", "north_gower_clayey_loam", "rubicon_sandy_loam")
_START_S = (1.6e9, 1.8e9)
_MARKER = ".independent_suite"
_TOOL = "vehicle_sim.independent"
EXPECTED_STRUCTURE = "structure differs"


@dataclass(frozen=True)
class Plan:
    """One bag: what to simulate and its label (picklable: sent to worker processes)."""

    id: str
    vehicle: str
    kind: str  # effect | control | out_of_catalogue | structure_control
    effect: str | None
    parameters: dict[str, float]
    scenario: dict[str, Any]
    seed: int
    duration: float
    start_time_ns: int
    structure: dict[str, Any] = field(default_factory=dict)
    out_of_catalogue: str | None = None
    ooc_parameters: dict[str, Any] = field(default_factory=dict)

    @property
    def path(self) -> str:
        return f"bags/{self.id}"

    def label(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "vehicle": self.vehicle,
            "kind": self.kind,
            "effect": self.effect,
            "parameters": self.parameters,
            "out_of_catalogue": self.out_of_catalogue,
            "out_of_catalogue_parameters": self.ooc_parameters,
            "structure": self.structure,
            "scenario": self.scenario,
            "seed": self.seed,
            "duration": self.duration,
            "start_time_ns": self.start_time_ns,
            "bag": self.path,
            "generator": _TOOL,
        }
        if self.kind == "structure_control":
            out["expected"] = EXPECTED_STRUCTURE
        elif self.kind == "out_of_catalogue":
            out["expected"] = "not confidently attributed to a catalogue effect"
        elif self.kind == "control":
            out["expected"] = "no significant gap"
        return out


# ---------------------------------------------------------------------------
# Drawing
# ---------------------------------------------------------------------------


def _signed(rng: np.random.Generator, low: float, high: float) -> float:
    value = log_uniform(rng, low, high)
    return value if rng.random() < 0.5 else -value


def _subset(rng: np.random.Generator, names: Sequence[str]) -> list[str]:
    """Each name kept with probability ½, at least one."""
    return [name for name, kept in zip(names, keep_some(rng, len(names)), strict=True) if kept]


def _factor(rng: np.random.Generator, low: tuple[float, float], high: tuple[float, float]) -> float:
    return log_uniform(rng, *low) if rng.random() < 0.5 else log_uniform(rng, *high)


def _draw_quarter_car(effect: str, rng: np.random.Generator) -> tuple[dict[str, float], dict[str, Any]]:
    """(parameters, structure) of a quarter-car effect; ranges in the package docstring."""
    if effect == "sensor_delay":
        stream = ("body", "wheel", "profile")[int(rng.integers(3))]
        return {f"sensor_delay_{stream}": log_uniform(rng, 0.01, 0.3)}, {}
    if effect in ("accel_bias", "accel_scale"):
        low, high = (0.1, 0.6) if effect == "accel_bias" else (0.03, 0.1)
        return {f"{effect}_{s}": _signed(rng, low, high) for s in _subset(rng, ("body", "wheel"))}, {}
    if effect == "nonlinear_soil":
        if rng.random() < 0.5:
            return {"load_ratio": float(rng.uniform(0.2, 0.6))}, {"soil_law": "hyperbolic"}
        return {"depth_ratio": float(rng.uniform(0.2, 0.6))}, {"soil_law": "hard_layer"}
    if effect == "sprung_mass_change":
        return {"sprung_mass_change": _signed(rng, 0.1, 0.3)}, {}
    if effect == "tire_damping":
        return {"tire_damping": log_uniform(rng, 300.0, 1500.0)}, {}
    if effect == "suspension_friction":
        return {"suspension_friction": log_uniform(rng, 50.0, 250.0)}, {}
    if effect == "tire_enveloping":
        return {"tire_contact_length": float(rng.uniform(0.1, 0.3))}, {}
    if effect == "wheel_liftoff":
        return {"wheel_liftoff": 1.0}, {}
    raise ValueError(f"unknown quarter-car effect {effect!r}; known: {', '.join(EFFECTS['quarter_car'])}")


def _draw_skid_steer(effect: str, rng: np.random.Generator) -> tuple[dict[str, float], dict[str, Any]]:
    if effect in ("sensor_delay", "wheel_speed_delay"):
        return {effect: log_uniform(rng, 0.01, 0.3)}, {}
    if effect in ("accel_bias", "accel_scale"):
        low, high = (0.1, 0.6) if effect == "accel_bias" else (0.03, 0.1)
        return {f"{effect}_{a}": _signed(rng, low, high) for a in _subset(rng, ("x", "y", "z"))}, {}
    if effect == "gyro_bias":
        return {n: _signed(rng, 0.005, 0.03) for n in _subset(rng, ("gyro_bias", "gyro_bias_x", "gyro_bias_y"))}, {}
    if effect == "gyro_scale":
        return {"gyro_scale": _signed(rng, 0.03, 0.1)}, {}
    if effect == "terrain_grade":
        return {n: _signed(rng, 0.05, 0.2) for n in _subset(rng, ("terrain_grade", "terrain_bank"))}, {}
    if effect == "tire_relaxation":
        return {
            "tire_relaxation": 1.0,
            "relaxation_length_x": float(rng.uniform(0.1, 1.0)),
            "relaxation_length_y": float(rng.uniform(0.2, 1.5)),
        }, {}
    if effect == "friction_change":
        return {"friction_change": _factor(rng, (0.4, 0.75), (1.3, 1.8))}, {}
    if effect == "cornering_stiffness_change":
        return {"cornering_stiffness_change": _factor(rng, (0.4, 0.75), (1.35, 2.5))}, {}
    if effect == "wheel_radius_error":
        return {"wheel_radius_error": _signed(rng, 0.03, 0.08)}, {}
    if effect == "turning_resistance":
        return {
            "turning_resistance": log_uniform(rng, 0.1, 0.5),
            "turning_resistance_speed": float(rng.uniform(0.02, 0.1)),
        }, {}
    raise ValueError(f"unknown skid-steer effect {effect!r}; known: {', '.join(EFFECTS['skid_steer'])}")


def _draw_structure(vehicle: str, rng: np.random.Generator) -> dict[str, Any]:
    if vehicle == "quarter_car":
        return {
            "soil_law": "zener",
            "stiffness_ratio": log_uniform(rng, 0.5, 2.0),
            "relaxation_time": 1.0 / (2.0 * math.pi * log_uniform(rng, 2.0, 10.0)),
            "description": STRUCTURE[vehicle],
        }
    return {"tire_law": "dugoff", "description": STRUCTURE[vehicle]}


def _draw_ooc(vehicle: str, name: str, rng: np.random.Generator) -> dict[str, Any]:
    if name == "sample_dropouts":
        return {
            "burst_probability": float(rng.uniform(0.005, 0.02)),
            "burst_samples": [3, 15],
            "noise_seed": int(rng.integers(2**31 - 1)),
        }
    if name == "accel_lowpass":
        low, high = (3.0, 10.0) if vehicle == "quarter_car" else (0.5, 2.0)
        return {"cutoff_hz": log_uniform(rng, low, high)}
    if name == "clock_drift":
        return {"rate_error": _signed(rng, 0.005, 0.02)}
    raise ValueError(f"unknown out-of-catalogue effect {name!r}; known: {', '.join(OUT_OF_CATALOGUE)}")


def _scenario(vehicle: str, rng: np.random.Generator, rough: bool) -> dict[str, Any]:
    if vehicle == "quarter_car":
        roads = _ROUGH if rough else _ROADS
        return {
            "road": roads[int(rng.integers(len(roads)))],
            "road_seed": int(rng.integers(2**31 - 1)),
            "soil": _SOILS[int(rng.integers(len(_SOILS)))],
            "speed": round(float(rng.uniform(6.0, 12.0)), 2),
        }
    kind = ss.MANOEUVRES[int(rng.integers(len(ss.MANOEUVRES)))]
    man: dict[str, Any] = {"kind": kind}
    if kind == "turn":
        man.update(ramp=float(rng.uniform(2.0, 4.0)), speed=float(rng.uniform(1.0, 2.5)))
        man["difference"] = _signed(rng, 0.4, 1.0)
    elif kind == "s_shape":
        man.update(ramp=float(rng.uniform(3.0, 5.0)), speed=float(rng.uniform(3.0, 7.0)))
        man.update(difference=float(rng.uniform(0.3, 0.8)), period=float(rng.uniform(5.0, 10.0)))
    else:
        man.update(ramp=3.0, speed=float(rng.uniform(2.0, 5.0)), turn_at=float(rng.uniform(5.0, 8.0)))
        man["difference"] = _signed(rng, 0.3, 0.8)
    return {"manoeuvre": man, "rolling_resistance": round(float(rng.uniform(0.01, 0.04)), 4)}


def plan_suite(
    seed: int,
    vehicles: Sequence[str] = VEHICLES,
    *,
    per_effect: int,
    controls: int,
    structure_controls: int | None = None,
    out_of_catalogue: int | None = None,
    effects: Sequence[str] | None = None,
    duration: float | None = None,
) -> list[Plan]:
    """Draw the suite (no simulation), one :class:`Plan` per bag; each vehicle from its own seeded generator."""
    n_struct = controls if structure_controls is None else structure_controls
    n_ooc = per_effect * len(OUT_OF_CATALOGUE) if out_of_catalogue is None else out_of_catalogue
    for name, n in (("per-effect", per_effect), ("controls", controls), ("structure controls", n_struct)):
        if n < 0:
            raise ValueError(f"{name} must be >= 0, got {n}")
    if n_ooc < 0:
        raise ValueError(f"out-of-catalogue must be >= 0, got {n_ooc}")
    check_request(vehicles, VEHICLES, EFFECTS, effects, duration, shortest=2.0)
    plans: list[Plan] = []
    ids: set[str] = set()
    ooc_names = tuple(OUT_OF_CATALOGUE)
    for vehicle in vehicles:
        rng = vehicle_rng(seed, f"independent/{vehicle}")
        jobs: list[tuple[str, str | None, str | None]] = []
        for name in EFFECTS[vehicle]:
            if effects is None or name in effects:
                jobs += [("effect", name, None)] * per_effect
        jobs += [("control", None, None)] * controls
        jobs += [("structure_control", None, None)] * n_struct
        jobs += [("out_of_catalogue", None, ooc_names[i % len(ooc_names)]) for i in range(n_ooc)]
        for kind, effect, ooc in jobs:
            bag_id, length, scenario, bag_seed, start = draw_bag(
                rng,
                ids,
                vehicle,
                effect == "wheel_liftoff",
                durations=DURATIONS[vehicle],
                duration=duration,
                start_range_s=_START_S,
                scenario=_scenario,
            )
            parameters: dict[str, float] = {}
            structure: dict[str, Any] = {}
            ooc_values: dict[str, Any] = {}
            if effect is not None:
                draw = _draw_quarter_car if vehicle == "quarter_car" else _draw_skid_steer
                parameters, structure = draw(effect, rng)
            elif kind == "structure_control":
                structure = _draw_structure(vehicle, rng)
            if ooc is not None:
                ooc_values = _draw_ooc(vehicle, ooc, rng)
            plans.append(
                Plan(
                    id=bag_id,
                    vehicle=vehicle,
                    kind=kind,
                    effect=effect,
                    parameters=parameters,
                    scenario=scenario,
                    seed=bag_seed,
                    duration=length,
                    start_time_ns=start,
                    structure=structure,
                    out_of_catalogue=ooc,
                    ooc_parameters=ooc_values,
                )
            )
    return plans


# ---------------------------------------------------------------------------
# Simulating: streams as arrays, per topic
# ---------------------------------------------------------------------------

#: A topic's recording: stamps (ns from the run's start) and named value columns.
Topic = tuple[np.ndarray, dict[str, np.ndarray]]


def _soil(plan: Plan) -> tuple[str, dict[str, float]]:
    law = str(plan.structure.get("soil_law", "linear"))
    if law == "zener":
        return law, {k: float(plan.structure[k]) for k in ("stiffness_ratio", "relaxation_time")}
    if law in ("hyperbolic", "hard_layer"):
        return law, dict(plan.parameters)
    return "linear", {}


def streams(plan: Plan, noise: bool = True) -> dict[str, Topic]:
    """Simulate the plan's plant and sensors (no out-of-catalogue transform): topic → (stamps, columns)."""
    if plan.vehicle == "quarter_car":
        law, shape = _soil(plan)
        effects = {} if law != "linear" else dict(plan.parameters)
        sc = plan.scenario
        q = qc.simulate(
            qc.QuarterCarRun(
                duration=plan.duration,
                speed=float(sc["speed"]),
                road_class=str(sc["road"]),
                road_seed=int(sc["road_seed"]),
                soil=str(sc["soil"]),
                seed=plan.seed,
                soil_law=law,
                soil_shape=shape,
                effects=effects,
            ),
            noise,
        )
        return {
            "imu/body": (q.body_t, {"linear_acceleration.z": q.body}),
            "imu/wheel": (q.wheel_t, {"linear_acceleration.z": q.wheel}),
            "joint_states": (q.joint_t, {"position": q.joint_position, "velocity": q.joint_velocity}),
            "terrain/profile": (q.profile_t, {"point.x": q.profile_x, "point.z": q.profile_z}),
        }
    s = ss.simulate(
        ss.SkidSteerRun(
            duration=plan.duration,
            manoeuvre=dict(plan.scenario["manoeuvre"]),
            rolling_resistance=float(plan.scenario["rolling_resistance"]),
            seed=plan.seed,
            tire_law=str(plan.structure.get("tire_law", "brush")),
            effects=dict(plan.parameters),
        ),
        noise,
    )
    imu_cols = {f"linear_acceleration.{a}": s.accel[:, i] for i, a in enumerate("xyz")}
    imu_cols.update({f"angular_velocity.{a}": s.gyro[:, i] for i, a in enumerate("xyz")})
    joints = {
        "position[left_motor]": s.position[:, 0],
        "position[right_motor]": s.position[:, 1],
        "velocity[left_motor]": s.velocity[:, 0],
        "velocity[right_motor]": s.velocity[:, 1],
        "effort[left_motor]": s.effort[:, 0],
        "effort[right_motor]": s.effort[:, 1],
    }
    return {"imu": (s.imu_t, imu_cols), "joint_states": (s.joint_t, joints)}


_IMU_TOPIC = {"quarter_car": "imu/body", "skid_steer": "imu"}


def _apply_ooc(plan: Plan, rec: dict[str, Topic]) -> dict[str, Topic]:
    """The recording with the plan's out-of-catalogue effect applied to its IMU stream (a copy)."""
    name, p = plan.out_of_catalogue, plan.ooc_parameters
    if name is None:
        return rec
    key = _IMU_TOPIC[plan.vehicle]
    stamps, cols = rec[key]
    stamps, cols = stamps.copy(), {k: v.copy() for k, v in cols.items()}
    if name == "sample_dropouts":
        rng = np.random.default_rng(int(p["noise_seed"]))
        n = stamps.size
        start = rng.random(n) < float(p["burst_probability"])
        lengths = rng.integers(int(p["burst_samples"][0]), int(p["burst_samples"][1]) + 1, n)
        held = np.zeros(n, dtype=bool)
        for first in np.flatnonzero(start):
            held[max(int(first), 1) : int(first) + int(lengths[first])] = True
        for values in cols.values():
            for j in np.flatnonzero(held):
                values[j] = values[j - 1]
    elif name == "accel_lowpass":
        period = float(np.median(np.diff(stamps))) * 1e-9
        alpha = 1.0 - math.exp(-2.0 * math.pi * float(p["cutoff_hz"]) * period)
        for k, values in cols.items():
            if not k.startswith("linear_acceleration"):
                continue
            smooth = values.copy()
            for i in range(1, smooth.size):
                smooth[i] = smooth[i - 1] + alpha * (values[i] - smooth[i - 1])
            cols[k] = smooth
    elif name == "clock_drift":
        stamps = np.round(stamps * (1.0 + float(p["rate_error"]))).astype(np.int64)
    else:
        raise ValueError(f"unknown out-of-catalogue effect {name!r}")
    out = dict(rec)
    out[key] = (stamps, cols)
    return out


# ---------------------------------------------------------------------------
# Signature (labels only)
# ---------------------------------------------------------------------------

#: Noise σ per response channel (known exactly: the generator adds it).
NOISE_SIGMA: dict[str, dict[str, float]] = {
    "quarter_car": {
        "imu/body linear_acceleration.z": math.sqrt(qc.ACCEL_VARIANCE),
        "imu/wheel linear_acceleration.z": math.sqrt(qc.ACCEL_VARIANCE),
    },
    "skid_steer": {
        **{f"imu linear_acceleration.{a}": ss.SkidSteerVehicle().accel_noise for a in "xyz"},
        **{f"imu angular_velocity.{a}": ss.SkidSteerVehicle().gyro_noise for a in "xyz"},
    },
}


def signature(vehicle: str, bag: dict[str, Topic], twin: dict[str, Topic]) -> dict[str, Any]:
    """SNR of bag − twin over the response channels: sqrt(Σ (Δ/σ)²), σ the noise the generator added.

    Aligned on the stamps (the samples both have).
    """
    total = 0.0
    samples = 0
    channels: dict[str, dict[str, float]] = {}
    for name, sigma in NOISE_SIGMA[vehicle].items():
        topic_key, column = name.split(" ", 1)
        ta, ca = bag[topic_key]
        tb, cb = twin[topic_key]
        _, ia, ib = np.intersect1d(ta, tb, assume_unique=True, return_indices=True)
        d = ca[column][ia] - cb[column][ib]
        z2 = float(np.sum((d / sigma) ** 2))
        total += z2
        samples += d.size
        channels[name] = {"rms_over_sigma": g4(math.sqrt(z2 / d.size)) if d.size else 0.0, "snr": g4(math.sqrt(z2))}
    most = max(channels, key=lambda c: channels[c]["snr"]) if total > 0.0 else None
    return {"snr": g4(math.sqrt(total)), "most_affected": most, "samples": samples, "channels": channels}


def _relative_shift(plan: Plan) -> Callable[[np.ndarray], np.ndarray] | None:
    """For a timing effect on a stream the signature above cannot see (an input stream's delay, the IMU's clock
    drift): the IMUs' time shift relative to the other streams at their stamps (ns), else None."""
    p = plan.parameters
    if plan.vehicle == "quarter_car" and "sensor_delay_profile" in p:
        d = float(p["sensor_delay_profile"]) * 1e9
        return lambda t: np.full(t.shape, d)
    if plan.vehicle == "skid_steer" and "wheel_speed_delay" in p:
        d = float(p["wheel_speed_delay"]) * 1e9
        return lambda t: np.full(t.shape, d)
    if plan.out_of_catalogue == "clock_drift":
        eps = float(plan.ooc_parameters["rate_error"])
        return lambda t: eps * t.astype(float)
    return None


def timing_signature(plan: Plan, shift: Callable[[np.ndarray], np.ndarray]) -> dict[str, Any]:
    """Signature of a relative timing error: the noise-free twin's response channels read ``shift`` later
    (linear interpolation between its samples) minus the same channels on time, over the noise σ."""
    clean = streams(twin(plan), noise=False)
    shifted: dict[str, Topic] = {}
    for key, (t, cols) in clean.items():
        moved = t + shift(t)
        inside = (moved >= t[0]) & (moved <= t[-1])
        shifted[key] = (t[inside], {c: np.interp(moved[inside], t, v) for c, v in cols.items()})
    out = signature(plan.vehicle, shifted, clean)
    out["timing"] = "relative time shift of the streams, on the noise-free twin (interpolated)"
    return out


def twin(plan: Plan) -> Plan:
    """The plan with every effect off (same scenario, noise seed, duration)."""
    return replace(plan, effect=None, parameters={}, structure={}, out_of_catalogue=None, ooc_parameters={})


# ---------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------


def _messages(plan: Plan, rec: dict[str, Topic]) -> list[tuple[int, str, str, Any]]:
    """(stamp ns, topic, msgtype, message) of every recorded sample, stamps shifted by the start time."""
    ns = NAMESPACE[plan.vehicle]
    prefix = ns.strip("/")
    out: list[tuple[int, str, str, Any]] = []
    off = plan.start_time_ns
    if plan.vehicle == "quarter_car":
        var = (0.0, 0.0, qc.ACCEL_VARIANCE)
        for key, frame in (("imu/body", "body_imu"), ("imu/wheel", "wheel_imu")):
            t, c = rec[key]
            for i in range(t.size):
                st = int(t[i]) + off
                a = (0.0, 0.0, float(c["linear_acceleration.z"][i]))
                out.append((st, msgs.topic(ns, key), msgs.IMU, msgs.imu(st, f"{prefix}/{frame}", a, var)))
        t, c = rec["joint_states"]
        for i in range(t.size):
            st = int(t[i]) + off
            m = msgs.joint_state(st, f"{prefix}/base_link", ["wheel"], [c["position"][i]], [c["velocity"][i]])
            out.append((st, msgs.topic(ns, "joint_states"), msgs.JOINT_STATE, m))
        t, c = rec["terrain/profile"]
        for i in range(t.size):
            st = int(t[i]) + off
            m = msgs.point_stamped(st, f"{prefix}/odom", c["point.x"][i], c["point.z"][i])
            out.append((st, msgs.topic(ns, "terrain/profile"), msgs.POINT_STAMPED, m))
    else:
        vehicle = ss.SkidSteerVehicle()
        av, gv = (vehicle.accel_noise**2,) * 3, (vehicle.gyro_noise**2,) * 3
        t, c = rec["imu"]
        for i in range(t.size):
            st = int(t[i]) + off
            acc = [float(c[f"linear_acceleration.{x}"][i]) for x in "xyz"]
            rate = [float(c[f"angular_velocity.{x}"][i]) for x in "xyz"]
            imu = msgs.imu(st, f"{prefix}/imu_link", acc, av, rate, gv)
            out.append((st, msgs.topic(ns, "imu"), msgs.IMU, imu))
        t, c = rec["joint_states"]
        names = ("left_motor", "right_motor")
        for i in range(t.size):
            st = int(t[i]) + off
            m = msgs.joint_state(
                st,
                f"{prefix}/base_link",
                names,
                [c[f"position[{n}]"][i] for n in names],
                [c[f"velocity[{n}]"][i] for n in names],
                [c[f"effort[{n}]"][i] for n in names],
            )
            out.append((st, msgs.topic(ns, "joint_states"), msgs.JOINT_STATE, m))
    out.sort(key=lambda item: item[0])
    return out


def write_bag(plan: Plan, root: str | Path, with_signature: bool = True) -> dict[str, Any]:
    """Simulate ``plan``, write its bag under ``root``; return message count, seconds and (if asked) the signature."""
    started = time.monotonic()
    clean = streams(plan)
    rec = _apply_ooc(plan, clean)
    with msgs.BagOut(Path(root) / plan.path) as bag:
        for stamp, name, msgtype, msg in _messages(plan, rec):
            bag.write(name, msgtype, msg, stamp)
        count = bag.count
    result: dict[str, Any] = {"id": plan.id, "messages": count}
    if with_signature and plan.kind != "control":
        shift = _relative_shift(plan)
        if shift is not None:
            result["signature"] = timing_signature(plan, shift)
        else:
            reference = clean if plan.out_of_catalogue is not None else streams(twin(plan))
            result["signature"] = signature(plan.vehicle, rec, reference)
    result["seconds"] = time.monotonic() - started
    return result


def _job(args: tuple[Plan, str, bool]) -> dict[str, Any]:
    return write_bag(*args)


def _prepare(out: Path) -> Path:
    """``out`` ready for a suite: new, empty, or a previous suite of this tool's (its bags are removed)."""
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{str(out)!r} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not (out / _MARKER).is_file():
        raise FileExistsError(
            f"{str(out)!r} is a non-empty directory this generator did not create (no {_MARKER}): not touched"
        )
    out.mkdir(parents=True, exist_ok=True)
    (out / _MARKER).write_text(f"created by {_TOOL}\n")
    shutil.rmtree(out / "bags", ignore_errors=True)
    for name in ("manifest.json", "labels.json"):
        (out / name).unlink(missing_ok=True)
    return out


def generate(
    out: str | Path,
    plans: Sequence[Plan],
    *,
    jobs: int = 1,
    signatures: bool = True,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Write every plan's bag, ``manifest.json`` and ``labels.json`` under ``out``; return a summary."""
    root = _prepare(Path(out))
    started = time.monotonic()
    results: dict[str, dict[str, Any]] = {}
    total = len(plans)

    def report(i: int, plan: Plan, result: dict[str, Any]) -> None:
        results[plan.id] = result
        if progress is not None:
            sig = result.get("signature")
            seen = f"; signature SNR {sig['snr']:.3g} ({sig['most_affected'] or 'no change'})" if sig else ""
            what = plan.effect or plan.out_of_catalogue or plan.kind
            progress(
                f"[{i}/{total}] {plan.vehicle} {plan.id} ({plan.kind}: {what}): {plan.duration:g} s, "
                f"{result['messages']} messages in {result['seconds']:.1f} s{seen}"
            )

    work = [(p, str(root), signatures) for p in plans]
    with worker_pool(jobs) as pool:
        for i, (plan, result) in enumerate(zip(plans, map_jobs(_job, work, pool), strict=True), 1):
            report(i, plan, result)
    manifest: dict[str, Any] = {
        "note": "What the diagnosis is given: bag id -> vehicle and bag path. Labels are withheld.",
        "generator": _TOOL,
    }
    labels: dict[str, Any] = {
        "note": (
            f"Ground-truth labels of the independent generator ({_TOOL}): for the scorer only. "
            "The sim-to-real diagnosis must NEVER read this file."
        ),
        "generator": _TOOL,
    }
    if signatures:
        labels["signature"] = {
            "definition": (
                "bag minus its twin (the same plan with every effect off and the same noise realisation; for an "
                "out-of-catalogue effect the same run before the transform), per response channel (IMUs) over the "
                "noise sigma the generator added: snr = sqrt(sum over channels and samples of (Delta/sigma)^2)"
            ),
            "noise_sigma": {v: NOISE_SIGMA[v] for v in sorted({p.vehicle for p in plans})},
        }
    write_manifest_and_labels(root, plans, results, manifest, labels)
    return {"bags": total, "seconds": time.monotonic() - started}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m vehicle_sim.independent",
        description="Independent generator of blind sim-to-real validation bags (issue 22, item 7).",
    )
    parser.add_argument("--out", required=True, help="output directory (its bags/, manifest.json, labels.json)")
    parser.add_argument("--per-effect", type=int, required=True, help="bags per effect and vehicle")
    parser.add_argument("--controls", type=int, required=True, help="nominal (no-effect) bags per vehicle")
    parser.add_argument("--seed", type=int, required=True, help="master seed (never given to the diagnosis)")
    parser.add_argument("--vehicle", nargs="+", choices=VEHICLES, help="vehicles (default: both)")
    parser.add_argument(
        "--structure-controls", type=int, help="structure-gap controls per vehicle (default: --controls)"
    )
    parser.add_argument(
        "--out-of-catalogue", type=int, help="out-of-catalogue bags per vehicle (default: 3 x --per-effect)"
    )
    parser.add_argument("--effect", action="append", help="only these effects (default: all)")
    parser.add_argument("--duration", type=float, help="fixed duration of every bag (s); default: drawn")
    parser.add_argument("--jobs", type=int, default=1, help="parallel processes (default 1)")
    parser.add_argument("--no-signature", action="store_true", help="skip the effect signatures (no twin runs)")
    args = parser.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    return run_suite_cli(
        "independent",
        args,
        VEHICLES,
        plan_suite,
        generate,
        (ValueError, OSError, FloatingPointError),
        plan_options={"structure_controls": args.structure_controls},
        generate_options={"progress": lambda line: print(line, file=sys.stderr, flush=True)},
    )
