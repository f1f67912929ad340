"""Drawing the withheld-effect suite: one :class:`BagPlan` per bag, from the master seed (no simulation).

The rules (which effects, magnitudes, scenarios, seeds, durations) are those
of :mod:`vehicle_sim.tools.withheld`'s docstring, which writes the bags.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vehicle_sim.effects import CATALOGUE, EffectParameter
from vehicle_sim.independent.blind_suite import check_request, draw_bag, keep_some, log_uniform, vehicle_rng
from vehicle_sim.ros.registry import get_simulator, simulator_parameters

__all__ = [
    "DURATIONS",
    "OUT_OF_CATALOGUE",
    "ROUGH_ROADS",
    "VEHICLES",
    "BagPlan",
    "draw_parameter",
    "plan_suite",
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
        from vehicle_sim.plants.skid_steer_manoeuvres import MANOEUVRES

        names = sorted(MANOEUVRES)
        return {"scenario.manoeuvre": names[int(rng.integers(len(names)))]}
    if vehicle == "rover":
        from vehicle_sim.plants.rover_paths import TERRAINS

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
        values[late] = log_uniform(rng, *_QUARTER_CAR_DELAY_RANGE)
        rules[late] = {"rule": "single_stream", "range": list(_QUARTER_CAR_DELAY_RANGE)}
    elif effect in ("accel_bias", "accel_scale") and len(values) > 1:
        names = list(values)
        for name, kept in zip(names, keep_some(rng, len(names)), strict=True):
            if not kept:
                values[name] = 0.0
                rules[name] = {"rule": "off (one sensor)"}
    elif effect == "nonlinear_soil":
        stiffening = bool(rng.random() < 0.5)
        span = _QUARTER_CAR_SOIL_STIFFENING if stiffening else _QUARTER_CAR_SOIL_SOFTENING
        values["soil_exponent"] = 1.0 + (1.0 if stiffening else -1.0) * log_uniform(rng, *span)
        rules["soil_exponent"] = {"rule": "stiffening" if stiffening else "softening", "range": list(span)}
        values["soil_origin_ratio"] = log_uniform(rng, *_QUARTER_CAR_SOIL_ORIGIN)
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
        for name, kept in zip(names, keep_some(rng, len(names)), strict=True):
            if not kept:
                values[name] = parameters[name].off
                rules[name] = {"rule": "off (one sensor)"}
    if effect in _SKID_STEER_DELAYS:
        for name, p in parameters.items():
            low, high = abs(p.typical - p.off), p.plausible_range[1] - p.off
            values[name] = p.off + log_uniform(rng, low, high)
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
    check_request(vehicles, VEHICLES, CATALOGUE, effects, duration, shortest=0.0)
    plans: list[BagPlan] = []
    ids: set[str] = set()
    ooc_names = tuple(OUT_OF_CATALOGUE)
    for vehicle in vehicles:
        rng = vehicle_rng(seed, vehicle)
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
            bag_id, length, scenario, bag_seed, start = draw_bag(
                rng,
                ids,
                vehicle,
                rough,
                durations=DURATIONS[vehicle],
                duration=duration,
                start_range_s=_START_TIME_RANGE_S,
                scenario=_scenario,
            )
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
