"""Truth plant for soil-stiffness estimation: 2-DOF quarter car and 1-DOF LRV.

Reina, Leanza, Messina, *Terrain estimation via vehicle vibration measurement
and Cubature Kalman Filtering* (MODELS.md A.1, A.7, A.9). The soil is an
equivalent spring k_s in series with the tire (eq. 3); the plant is integrated
in continuous time and sampled by the sensors the estimator uses.

Truth integration
    Classical fixed-step RK4 with step ≤ 1 ms by default (sensor period / an
    integer number of sub-steps). The road h(s(t)) and its rate are evaluated
    exactly at every RK4 stage (t, t + Δt/2, t + Δt); s(t) is the exact
    integral of the speed profile. This is deliberately *not* the filter's own
    10 ms / 4th-order-Taylor discretisation (DESIGN.md: a filter tested against
    its own model proves nothing; MODELS.md A.10: the road between filter steps
    decides the k_s error).

Coordinates
    y1 (body) and y2 (wheel) are vertical displacements (m, up positive) from
    static equilibrium on a level road at h = 0, so gravity cancels in the
    equations of motion (eq. 2). Accelerometers report specific force along
    +z (REP 145): ÿ + g, i.e. +g at rest.

2-DOF quarter car (eq. 2)::

    m_s  ÿ1 = k(y2 − y1) + c(ẏ2 − ẏ1)
    m_ns ÿ2 = −k(y2 − y1) − c(ẏ2 − ẏ1) + F_d,     F_d = k_tot (h − y2)

1-DOF LRV (section 5.3, MODELS.md A.7)::

    m ÿ1 = F_d,   F_d = k_tot (h − y1) + c (ḣ − ẏ1)        (damper_reference="ground")
    m ÿ1 = k_tot (h − y1) − c ẏ1                          (damper_reference="inertial")

  k_tot = k k_s / (k + k_s), k the combined suspension/tire stiffness. The
  physical default puts the damper between body and ground, c(ẏ1 − ḣ); the
  paper's literal reduction of the 2-DOF matrices puts it on the absolute body
  velocity and is kept as an option for comparisons. The damper acts across the
  whole series chain (soil included): a massless simplification that avoids the
  extra internal state a damper across k only would need.

Contact
    The total normal ground force is F = W + F_d, W the static load
    (total mass × g). With ``wheel_liftoff`` the contact is unilateral:
    F = max(0, W + F_d) — the wheel leaves the ground when the dynamic force
    would pull (MODELS.md A.10 item 5: 7–9 % of the time at ISO F, 10 m/s).
    Without it (the paper's linear model) F may go negative.

Effects
    :class:`QuarterCarEffects` (``Scenario.effects``) switches on the
    unmodelled effects of the sim-to-real catalogue (CONTRACT.md "Nominal
    model and effects"; :data:`QUARTER_CAR_EFFECTS`): accelerometer bias,
    scale and delay, Bekker-type nonlinear soil, wheel lift-off, Coulomb
    suspension friction, tire damping, tire enveloping and a sprung-mass
    change. All off (the default) is the linear model above, bit for bit:
    the nominal path runs the same arithmetic as before the effects existed.

Soil changes
    The soil under the tire is looked up at every RK4 stage from the distance
    travelled. Coordinates stay deviations from the *current* soil's static
    equilibrium, as in the paper: a change of soil changes k_tot, not the
    equilibrium height (the extra static sinkage of a softer soil is not
    modelled).

The plant is split by concept: the vehicles
(:mod:`~vehicle_sim.plants.quarter_car_vehicles`), the effects
(:mod:`~vehicle_sim.plants.quarter_car_effects`), the scenario and the
samples (:mod:`~vehicle_sim.plants.quarter_car_scenario`) and the equations
of motion with their integrator (:mod:`~vehicle_sim.plants.quarter_car_dynamics`).
This module runs them (:class:`QuarterCarSimulator`: sensors, delays, truth)
and re-exports the names of :data:`__all__` so that a caller needs one import.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from vehicle_sim.plants.quarter_car_dynamics import (
    _advance,
    _Dynamics,
    _lrv_forces,
    _two_dof_forces,
)
from vehicle_sim.plants.quarter_car_effects import (
    FRICTION_VELOCITY_SCALE,
    LRV_IGNORED_EFFECTS,
    QUARTER_CAR_EFFECTS,
    QuarterCarEffects,
    enveloped_profile,
)
from vehicle_sim.plants.quarter_car_scenario import (
    ProfileReadings,
    QuarterCarSample,
    QuarterCarTruth,
    Scenario,
    SimulationResult,
    SpeedProfile,
)
from vehicle_sim.plants.quarter_car_vehicles import STANDARD_GRAVITY, LRVVehicle, QuarterCarVehicle, Vehicle
from vehicle_sim.plants.stepping import SampleClock

__all__ = [
    "FRICTION_VELOCITY_SCALE",
    "LRV_IGNORED_EFFECTS",
    "QUARTER_CAR_EFFECTS",
    "STANDARD_GRAVITY",
    "QuarterCarEffects",
    "LRVVehicle",
    "ProfileReadings",
    "QuarterCarSample",
    "QuarterCarSimulator",
    "QuarterCarTruth",
    "QuarterCarVehicle",
    "Scenario",
    "SimulationResult",
    "SpeedProfile",
    "enveloped_profile",
    "simulate",
]


_ACCEL_FIELDS = frozenset(("accel_bias_body", "accel_bias_wheel", "accel_scale_body", "accel_scale_wheel"))


class QuarterCarSimulator(SampleClock):
    """Stepping truth simulator for the quarter car or the LRV.

    Each :meth:`step` advances one sensor period (``scenario.sensor_period``,
    10 ms by default) with RK4 sub-steps and returns a :class:`QuarterCarSample`.

    Args:
        vehicle: :class:`QuarterCarVehicle` (2-DOF) or :class:`LRVVehicle` (1-DOF).
        scenario: Road, soil, speed, sensors.
        seed: Seed of the sensor noise (accelerometers and profile sampler use
            independent streams spawned from it).
        initial_state: [y1, ẏ1, y2, ẏ2] (2-DOF) or [y1, ẏ1] (LRV) in m and m/s;
            default: at rest at the road height under the wheel at t = 0.
    """

    def __init__(
        self,
        vehicle: Vehicle,
        scenario: Scenario,
        seed: int,
        initial_state: Sequence[float] | None = None,
    ) -> None:
        if not isinstance(vehicle, QuarterCarVehicle | LRVVehicle):
            raise TypeError(f"vehicle must be QuarterCarVehicle or LRVVehicle, got {vehicle!r}")
        self.vehicle = vehicle
        self.scenario = scenario
        self.seed = seed
        self._two_dof = isinstance(vehicle, QuarterCarVehicle)
        effects = scenario.effects
        if not self._two_dof:
            for name in LRV_IGNORED_EFFECTS:
                if getattr(effects, name) != 0.0:
                    raise ValueError(
                        f"QuarterCarEffects.{name} = {getattr(effects, name)} does not apply to the 1-DOF LRV "
                        "(no wheel accelerometer, no separate suspension or tire); leave it at 0"
                    )
        self._period = scenario.sensor_period
        self._substeps = scenario.substeps
        self._dt = self._period / self._substeps
        self._stage_offsets = 0.5 * self._dt * np.arange(2 * self._substeps + 1)
        accel_seed, profile_seed = np.random.SeedSequence(seed).spawn(2)
        self._accel_rng = np.random.default_rng(accel_seed)
        self._profile_rng = np.random.default_rng(profile_seed)
        self._accel_std = math.sqrt(scenario.accel_noise_variance)
        # The plant actually integrated: the vehicle with the sprung-mass change.
        self._plant: Vehicle = (
            replace(vehicle, sprung_mass=vehicle.sprung_mass * (1.0 + effects.sprung_mass_change))
            if effects.sprung_mass_change
            else vehicle
        )
        self._static_load = self._plant.total_mass * scenario.gravity
        self._k_tot_by_segment = [vehicle.k_tot(soil.k_s) for soil in scenario.soil_path.soils]
        self._dynamics = _Dynamics(
            soil_exponent=effects.soil_exponent if effects.nonlinear_soil else 0.0,
            friction=effects.suspension_friction,
            tire_damping=effects.tire_damping,
            soil_origin=effects.soil_origin_ratio if effects.nonlinear_soil else 1.0,
        )
        self._nominal_dynamics = self._dynamics == _Dynamics(0.0, 0.0, 0.0)
        if self._dynamics.friction and isinstance(self._plant, QuarterCarVehicle):
            reduced = self._plant.sprung_mass * self._plant.unsprung_mass / self._plant.total_mass
            stiffness = self._dynamics.friction * self._dt / (FRICTION_VELOCITY_SCALE * reduced)
            if stiffness > 1.0:
                raise ValueError(
                    f"QuarterCarEffects.suspension_friction = {effects.suspension_friction} N is too stiff for the "
                    f"RK4 step {self._dt} s (F_c·dt/(v_f·mu) = {stiffness:.3g} > 1); reduce it or integration_step"
                )
        # The road the tire feels (contact-patch average); the profiler measures scenario.profile.
        self._tire_profile = enveloped_profile(scenario.profile, effects.tire_contact_length)
        self._enveloping = self._tire_profile is not scenario.profile
        self._step_index = 0
        self._next_profile_index = 0
        n_states = 4 if self._two_dof else 2
        if initial_state is None:
            h0 = float(self._tire_profile.elevation(np.array([0.0]))[0])
            state: tuple[float, ...] = (h0, 0.0, h0, 0.0) if self._two_dof else (h0, 0.0)
        else:
            state = tuple(float(x) for x in initial_state)
            if len(state) != n_states:
                raise ValueError(f"initial_state needs {n_states} values, got {len(state)}")
        self._state: tuple[float, ...] = state
        # Noise-free true accelerations (body, wheel) at every RK4 step from t = 0, for the delay:
        # the delayed reading is interpolated on the integration grid, not between sensor samples
        # (linear interpolation at the sensor rate would low-pass the signal: −5 % at 10 Hz, 100 Hz).
        # Each accelerometer has its own lag (sensor_delay plus the stream's own latency).
        body_delay, wheel_delay = effects.accelerometer_delays()
        self._delay_lags = (body_delay / self._dt, wheel_delay / self._dt)
        self._delaying = body_delay > 0.0 or wheel_delay > 0.0
        self._accel_history: deque[tuple[float, float]] = deque(maxlen=int(math.ceil(max(self._delay_lags))) + 2)
        self._record: list[tuple[float, float]] | None = [] if self._delaying else None
        # Profile readings taken but not yet delivered (sensor_delay_profile): (taken at, distance, elevation).
        self._profile_buffer: deque[tuple[float, float, float]] = deque()

    @property
    def state(self) -> tuple[float, ...]:
        """Current [y1, ẏ1, y2, ẏ2] (2-DOF) or [y1, ẏ1] (LRV), m and m/s."""
        return self._state

    @property
    def integration_step(self) -> float:
        """RK4 step actually used (s)."""
        return self._dt

    def step(self) -> QuarterCarSample:
        """Advance one sensor period and report the sensors and the truth at its end.

        Returns:
            The sample at t = (step_index + 1) · period. Its profile readings are
            those with times in (t − period, t]; the first call also delivers the
            reading at t = 0, so successive calls hand over every reading once.
        """
        scenario = self.scenario
        speed_profile = scenario.speed
        t0 = self._step_index * self._period
        t1 = (self._step_index + 1) * self._period
        constant_speed = speed_profile.is_constant_on(t0, t1)

        if constant_speed:
            v = float(speed_profile.speed(t0))
            s0 = float(speed_profile.distance(t0))
            stage_spacing = v * 0.5 * self._dt
            stage_distance = np.asarray(s0 + stage_spacing * np.arange(self._stage_offsets.size), dtype=np.float64)
            road, slope = scenario.profile.evaluate_uniform(s0, stage_spacing, self._stage_offsets.size)
            road_rate = v * slope
        else:
            stage_times = t0 + self._stage_offsets
            stage_distance = speed_profile.distance(stage_times)
            road, slope = scenario.profile.elevation_and_slope(stage_distance)
            road_rate = speed_profile.speed(stage_times) * slope

        if self._enveloping:
            # The same stage grid on the road the tire feels.
            if constant_speed:
                tire_road, tire_slope = self._tire_profile.evaluate_uniform(s0, stage_spacing, stage_distance.size)
                tire_rate = v * tire_slope
            else:
                tire_road, tire_slope = self._tire_profile.elevation_and_slope(stage_distance)
                tire_rate = speed_profile.speed(t0 + self._stage_offsets) * tire_slope
        else:
            tire_road, tire_rate = road, road_rate

        soil_index = scenario.soil_path.index_at(stage_distance)
        stiffness = [self._k_tot_by_segment[i] for i in soil_index.tolist()]
        road_list = tire_road.tolist()
        liftoff = scenario.effects.wheel_liftoff
        soils = scenario.soil_path.soils
        soil_stiffness = [soils[i].k_s for i in soil_index.tolist()]
        self._state = _advance(
            self._state,
            road_list,
            tire_rate.tolist(),
            stiffness,
            soil_stiffness,
            self._substeps,
            self._dt,
            self._plant,
            self._static_load,
            liftoff,
            None if self._nominal_dynamics else self._dynamics,
            self._record,
        )
        self._step_index += 1

        distance = float(stage_distance[-1])
        speed = float(speed_profile.speed(t1))
        truth = self._truth(
            float(road[-1]),
            float(road_rate[-1]),
            float(tire_road[-1]),
            float(tire_rate[-1]),
            stiffness[-1],
            int(soil_index[-1]),
        )
        noise = self._accel_rng.standard_normal(2) * self._accel_std
        body_accel, wheel_accel = self._accelerometers(truth, noise)
        radius = self.vehicle.wheel_radius
        return QuarterCarSample(
            t=t1,
            body_accel_z=body_accel,
            wheel_accel_z=wheel_accel,
            distance=distance,
            wheel_angle=distance / radius,
            wheel_rate=speed / radius,
            speed=speed,
            profile=self._deliver_profile(self._profile_readings(t0, t1, constant_speed, stage_distance, road), t1),
            truth=truth,
        )

    def _specific_forces(self, truth: QuarterCarTruth) -> tuple[float, float]:
        """Noise-free true specific forces ÿ + g (body, wheel; 0 for the LRV's wheel), m/s²."""
        g = self.scenario.gravity
        wheel = truth.wheel_acceleration
        return float(truth.body_acceleration) + g, (float(wheel) + g if wheel is not None else 0.0)

    def _accelerometers(self, truth: QuarterCarTruth, noise: NDArray[np.float64]) -> tuple[float, float | None]:
        """The accelerometer readings: true specific force, delayed, scaled, biased, plus noise."""
        effects = self.scenario.effects
        g = self.scenario.gravity
        if not (self._delaying or _ACCEL_FIELDS.intersection(effects.active)):
            # Nominal sensors: the same arithmetic as always (bit-identical output).
            body = float(truth.body_acceleration) + g + float(noise[0])
            wheel = (
                float(truth.wheel_acceleration) + g + float(noise[1])  # type: ignore[arg-type]
                if self._two_dof
                else None
            )
            return body, wheel
        body_sf, wheel_sf = self._delayed(self._specific_forces(truth))
        body = (1.0 + effects.accel_scale_body) * body_sf + effects.accel_bias_body + float(noise[0])
        if not self._two_dof:
            return body, None
        return body, (1.0 + effects.accel_scale_wheel) * wheel_sf + effects.accel_bias_wheel + float(noise[1])

    def _delayed(self, current: tuple[float, float]) -> tuple[float, float]:
        """The (body, wheel) specific forces each its own latency ago, linearly interpolated on the RK4 grid.

        The history holds the accelerations at the start of every RK4 step
        since t = 0 (recorded by the integrator); ``current`` is the value at
        the end of this sensor period. Before the run has lasted a channel's
        delay, its t = 0 value is returned.
        """
        if not self._delaying:
            return current
        g = self.scenario.gravity
        history = self._accel_history
        if self._record:
            two = self._two_dof
            history.extend((a + g, (b + g) if two else 0.0) for a, b in self._record)
            self._record.clear()
        sequence = list(history) + [current]
        out = []
        for channel, lag in enumerate(self._delay_lags):
            whole = int(math.floor(lag + 1e-9))
            frac = max(lag - whole, 0.0)
            if frac <= 1e-9:
                frac = 0.0
            needed = whole + (1 if frac else 0)
            if needed > len(sequence) - 1:
                out.append(sequence[0][channel])
                continue
            newer = sequence[-1 - whole][channel]
            if not frac:
                out.append(newer)
                continue
            older = sequence[-2 - whole][channel]
            out.append((1.0 - frac) * newer + frac * older)
        return out[0], out[1]

    def _deliver_profile(self, readings: ProfileReadings, t1: float) -> ProfileReadings:
        """The profile sampler's latency: buffer the readings taken, deliver those due by ``t1`` (stamped when due)."""
        delay = self.scenario.effects.sensor_delay_profile
        if not delay:
            return readings
        for t, s, h in zip(readings.t.tolist(), readings.distance.tolist(), readings.elevation.tolist(), strict=True):
            self._profile_buffer.append((t, s, h))
        due = []
        while self._profile_buffer and self._profile_buffer[0][0] + delay <= t1 + 1e-9:
            due.append(self._profile_buffer.popleft())
        if not due:
            empty = np.empty(0)
            return ProfileReadings(empty, empty.copy(), empty.copy())
        taken, distance, elevation = (np.array(column, dtype=float) for column in zip(*due, strict=True))
        return ProfileReadings(taken + delay, distance, elevation)

    def _truth(
        self, h: float, h_rate: float, h_tire: float, h_tire_rate: float, kt: float, segment: int
    ) -> QuarterCarTruth:
        """Truth at the current state; ``h``/``h_rate`` the true road, ``h_tire``/``h_tire_rate`` the one felt."""
        soil = self.scenario.soil_path.soils[segment]
        load = self._static_load
        liftoff = self.scenario.effects.wheel_liftoff
        dynamics = self._dynamics
        if self._two_dof:
            vehicle: QuarterCarVehicle = self._plant  # type: ignore[assignment]
            y1, v1, y2, v2 = self._state
            if self._nominal_dynamics:
                suspension = vehicle.suspension_stiffness * (y2 - y1) + vehicle.suspension_damping * (v2 - v1)
                dynamic = kt * (h_tire - y2)
            else:
                suspension, dynamic = _two_dof_forces(
                    y1, v1, y2, v2, h_tire, h_tire_rate, kt, soil.k_s, vehicle, load, dynamics
                )
            in_contact = load + dynamic > 0.0
            if liftoff and not in_contact:
                dynamic = -load
            a1 = suspension / vehicle.sprung_mass
            a2 = (dynamic - suspension) / vehicle.unsprung_mass
            wheel: tuple[float | None, float | None, float | None] = (y2, v2, a2)
        else:
            lrv: LRVVehicle = self._plant  # type: ignore[assignment]
            y1, v1 = self._state
            dynamic, skyhook = _lrv_forces(y1, v1, h_tire, h_tire_rate, kt, soil.k_s, lrv, load, dynamics)
            in_contact = load + dynamic > 0.0
            if liftoff and not in_contact:
                dynamic = -load
            a1 = (dynamic + skyhook) / lrv.sprung_mass
            wheel = (None, None, None)
        return QuarterCarTruth(
            soil_name=soil.name,
            k_s=soil.k_s,
            k_tot=kt,
            body_displacement=y1,
            body_velocity=v1,
            body_acceleration=a1,
            wheel_displacement=wheel[0],
            wheel_velocity=wheel[1],
            wheel_acceleration=wheel[2],
            road_elevation=h,
            road_rate=h_rate,
            contact_force=load + dynamic,
            in_contact=bool(in_contact),
        )

    def _profile_readings(
        self,
        t0: float,
        t1: float,
        constant_speed: bool,
        stage_distance: NDArray[np.float64],
        stage_road: NDArray[np.float64],
    ) -> ProfileReadings:
        scenario = self.scenario
        rate = scenario.profile_rate
        first = self._next_profile_index
        last = math.floor(t1 * rate + 1e-9)
        self._next_profile_index = max(first, last + 1)
        indices = np.arange(first, last + 1)
        times = indices / rate
        if indices.size == 0:
            empty = np.empty(0)
            return ProfileReadings(empty, empty.copy(), empty.copy())
        # Readings that fall on RK4 stage times (1 kHz with 1 ms steps) reuse the
        # stage road, which is the same exact h(s) at the same s.
        stage = (times - t0) / (0.5 * self._dt)
        stage_index = np.rint(stage).astype(int)
        if np.all(np.abs(stage - stage_index) < 1e-6):
            distance = stage_distance[stage_index]
            elevation = stage_road[stage_index]
        else:
            distance = scenario.speed.distance(times)
            if constant_speed:
                spacing = float(scenario.speed.speed(t0)) / rate
                elevation, _ = scenario.profile.evaluate_uniform(float(distance[0]), spacing, indices.size)
            else:
                elevation = scenario.profile.elevation(distance)
        if scenario.profile_noise_std > 0.0:
            elevation = elevation + scenario.profile_noise_std * self._profile_rng.standard_normal(indices.size)
        return ProfileReadings(times, distance, elevation)


def simulate(
    vehicle: Vehicle,
    scenario: Scenario,
    duration: float,
    seed: int,
    initial_state: Sequence[float] | None = None,
) -> SimulationResult:
    """Run a :class:`QuarterCarSimulator` for ``duration`` seconds and stack the samples.

    Args:
        vehicle: The vehicle.
        scenario: The scenario.
        duration: Simulated time (s); rounded to a whole number of sensor periods.
        seed: Sensor-noise seed.
        initial_state: As for :class:`QuarterCarSimulator`.

    Returns:
        The stacked result: N = round(duration × sensor_rate) samples at
        t = period … duration, profile readings over [0, duration].
    """
    n_samples = int(round(duration * scenario.sensor_rate))
    if n_samples < 1:
        raise ValueError(f"duration {duration} s is shorter than one sensor period")
    simulator = QuarterCarSimulator(vehicle, scenario, seed, initial_state)
    samples = [simulator.step() for _ in range(n_samples)]

    def stack(getter) -> NDArray:
        return np.array([getter(sample) for sample in samples])

    two_dof = vehicle.has_wheel_accelerometer
    truths = [sample.truth for sample in samples]

    def truth_array(name: str) -> NDArray | None:
        values = [getattr(truth, name) for truth in truths]
        return None if values[0] is None else np.array(values)

    # The per-sample truth fields stacked into arrays (the dataclass allows both).
    truth = QuarterCarTruth(**{name: truth_array(name) for name in QuarterCarTruth.__dataclass_fields__})  # type: ignore[arg-type]
    return SimulationResult(
        vehicle=vehicle,
        scenario=scenario,
        seed=seed,
        t=stack(lambda s: s.t),
        body_accel_z=stack(lambda s: s.body_accel_z),
        wheel_accel_z=stack(lambda s: s.wheel_accel_z) if two_dof else None,
        distance=stack(lambda s: s.distance),
        wheel_angle=stack(lambda s: s.wheel_angle),
        wheel_rate=stack(lambda s: s.wheel_rate),
        speed=stack(lambda s: s.speed),
        profile=ProfileReadings(
            t=np.concatenate([s.profile.t for s in samples]),
            distance=np.concatenate([s.profile.distance for s in samples]),
            elevation=np.concatenate([s.profile.elevation for s in samples]),
        ),
        truth=truth,
    )
