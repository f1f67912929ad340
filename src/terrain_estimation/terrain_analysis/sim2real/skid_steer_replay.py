"""The replay model of one skid-steer bag (:class:`SkidSteerReplay`, the attribution's ``ReplayModel``).

Channels, candidate effects, nuisance parameters and the noise budget of the replay described in the docstring
of :mod:`terrain_analysis.sim2real.skid_steer`; the dynamics are :mod:`~terrain_analysis.sim2real.skid_steer_kernel`.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import Candidate, Channel, FitParameter, candidates_from_catalogue
from terrain_analysis.sim2real.skid_steer_bag import SkidSteerBagData, wheel_speeds_at
from terrain_analysis.sim2real.skid_steer_input import smooth_wheel_speeds
from terrain_analysis.sim2real.skid_steer_kernel import (
    RELAXATION_LENGTH_MIN,
    TURNING_RESISTANCE_SPEED,
    Physics,
    Sensing,
    replay_imu,
)
from terrain_analysis.sim2real.skid_steer_vehicle import ReplayVehicle, no_slip_motion

__all__ = ["DIAGNOSIS_STEP", "NUISANCE", "SkidSteerReplay"]

FloatArray = NDArray[np.float64]

#: Nuisance parameters a replay can fit: name → (unit, bounds, scale, description). Off/start value 1 (scale
#: factors of the config value) except rolling_resistance (absolute, start at the config value).
NUISANCE: Mapping[str, tuple[str, tuple[float, float], float, str]] = {
    "longitudinal_stiffness_scale": ("–", (0.05, 10.0), 0.3, "C_x = config C_x × scale"),
    "cornering_stiffness_scale": ("–", (0.05, 10.0), 0.3, "C_α = config C_α × scale (nuisance, not the effect)"),
    "friction_scale": ("–", (0.2, 3.0), 0.2, "μ = config μ × scale"),
    "rolling_resistance": ("–", (0.0, 0.3), 0.02, "motion-resistance coefficient f_rr"),
    "yaw_inertia_scale": ("–", (0.3, 3.0), 0.3, "I_z = config I_z × scale"),
}


#: Largest RK4 step (s) of the skid-steer diagnosis's replay (:func:`terrain_analysis.sim2real.skid_steer.build_model`).
#: The kernel's stiffness bound on the slip dynamics (λ_max Δt ≤ 2) is kept and still sets the step wherever the
#: wheels roll slowly (below ≈ 0.6 m/s for the simulated 6-wheeler); elsewhere 5 ms is accurate far below the
#: noise: against 2 ms (the plant's step) the replayed IMU of a 60 s bag moves by ≤ 0.4 % of the noise σ RMS on
#: ax, ay and ≤ 0.03 % on the gyros, for the nominal model and every physical effect, some 30× less than the
#: replay's own error against the plant (module :mod:`~terrain_analysis.sim2real.skid_steer`: 0.006–0.007 m/s² on
#: ax), at less than half the cost. Models built directly (:class:`SkidSteerReplay`, the Husky's) keep 2 ms.
DIAGNOSIS_STEP = 5.0e-3

#: Replays kept for re-use (the noise-free IMU of one physics): at most this many, and this many bytes.
_CACHE_ENTRIES = 4096
_CACHE_BYTES = 256 * 2**20

_CHANNELS = (
    ("yaw_rate", "imu angular_velocity.z", "rad/s"),
    ("ax", "imu linear_acceleration.x", "m/s²"),
    ("ay", "imu linear_acceleration.y", "m/s²"),
    ("az", "imu linear_acceleration.z", "m/s²"),
    ("roll_rate", "imu angular_velocity.x", "rad/s"),
    ("pitch_rate", "imu angular_velocity.y", "rad/s"),
)
_IMU_COLUMN = {"ax": 0, "ay": 1, "az": 2, "roll_rate": 3, "pitch_rate": 4, "yaw_rate": 5}
#: Gyro x, y: the sprung mass's roll and pitch rates, which only load_transfer_dynamics moves.
_BODY_RATE_CHANNELS = ("roll_rate", "pitch_rate")


#: Sensor parameters that act on one channel only: parameter → channel.
_SENSOR_CHANNEL = {
    **{f"accel_bias_{axis}": f"a{axis}" for axis in "xyz"},
    **{f"accel_scale_{axis}": f"a{axis}" for axis in "xyz"},
    "gyro_bias": "yaw_rate",
    "gyro_bias_x": "roll_rate",
    "gyro_bias_y": "pitch_rate",
    "gyro_scale": "yaw_rate",
}


#: ``tire_relaxation`` with its lengths fitted (the catalogue's is a switch with the vehicle's lengths): a real
#: tire's relaxation lengths vary with the tire, its load and inflation (Pacejka, *Tire and Vehicle Dynamics*,
#: ch. 7: about 0.5-2 wheel radii laterally, shorter along), and a switch with fixed ones cannot tell the
#: independent generator's 0.2-1.3 m apart from a wheel-speed delay (0 of 6 attributed). A length of 0 is no
#: lag on that axis. The lag's rate V/L needs the speed at which the carcass deflection is carried away: the
#: literature uses the contact's travel speed |v_c| (Pacejka's transient slip) or, so that a spinning wheel on
#: a stuck vehicle still builds its force, the larger of that and the rolling speed R|ω| (the catalogue's
#: plant); ``relaxation_rolling_weight`` w spans both, V = max(w R|ω|, |v_c|, V_floor), and the fit starts
#: from each end (both ends laws of the family).
RELAXATION_CANDIDATE = Candidate(
    "tire_relaxation",
    (
        FitParameter("relaxation_length_x", "m", 0.0, (0.0, 2.5), 0.3),
        FitParameter("relaxation_length_y", "m", 0.0, (0.0, 2.5), 0.5),
        FitParameter("relaxation_rolling_weight", "–", 1.0, (0.0, 1.0), 0.5, physical_bounds=True),
    ),
    "first-order tire force lag Ḟ = (V/L)(F_ss − F), relaxation length L_x along and L_y across the wheel "
    "(0: no lag on that axis), V = max(w R|ω|, |v_contact|, V_floor)",
    starts=(
        (("relaxation_length_x", 0.3), ("relaxation_length_y", 0.5), ("relaxation_rolling_weight", 0.0)),
        (("relaxation_length_x", 0.3), ("relaxation_length_y", 0.5), ("relaxation_rolling_weight", 1.0)),
    ),
)


#: ``turning_resistance`` with the speed over which it builds up fitted, v_b (the catalogue's is fixed at 0.05 m/s):
#: how fast the soil's lateral resistance rises with a wheel's lateral sliding depends on the soil and the
#: sinkage (a rut sheared at once, or a berm bulldozed up over centimetres of travel). Below that speed the
#: resistance grows like a cornering stiffness (c_b F_z / v_b per m/s of sliding), above it like a friction: a
#: fixed speed makes a slower law look like a cornering-stiffness change. Both ends of its range are laws of the
#: family: a Coulomb step, and a lateral damping that never saturates in the bag.
TURNING_RESISTANCE_SPEED_PARAMETER = FitParameter(
    "turning_resistance_speed", "m/s", TURNING_RESISTANCE_SPEED, (0.005, 0.5), 0.05, physical_bounds=True
)
TURNING_RESISTANCE_DESCRIPTION = (
    "lateral soil resistance F_b = −c_b F_z tanh(v_y / v_b) per wheel against its lateral sliding v_y (v_b the "
    "speed over which it builds up): a resistive yaw moment in skid-steer turns"
)


def _no_lag(values: Mapping[str, float]) -> bool:
    """Whether relaxation lengths are given and both are below the shortest the replay integrates (no lag)."""
    return all(name in values and float(values[name]) <= RELAXATION_LENGTH_MIN for name in _LENGTHS)


_LENGTHS = ("relaxation_length_x", "relaxation_length_y")


def _optional(values: Mapping[str, float], name: str) -> float | None:
    """``values[name]`` as a float, None when absent (the vehicle's own value then)."""
    return float(values[name]) if name in values else None


def _restrict_to_channels(
    candidates: Mapping[str, Candidate], channels: Sequence[str], notes: list[str]
) -> dict[str, Candidate]:
    """The candidates without the sensor parameters of channels the model does not compare.

    A bias or scale of an axis the bag does not measure (or the replay does not
    predict) has no effect on any residual: fitting it would only add an
    unidentifiable parameter (and its penalty). An effect left without
    parameters (it had some) is dropped; both are noted for the report.
    """
    out: dict[str, Candidate] = {}
    for name, candidate in candidates.items():
        keep = tuple(p for p in candidate.parameters if _SENSOR_CHANNEL.get(p.name, channels[0]) in channels)
        dropped = [p.name for p in candidate.parameters if p not in keep]
        if dropped and not keep:
            notes.append(f"{name} not offered: its channels are not compared ({', '.join(dropped)})")
            continue
        if dropped:
            notes.append(f"{name}: {', '.join(dropped)} not fitted (channel not compared)")
            candidate = replace(candidate, parameters=keep)
        out[name] = candidate
    return out


class SkidSteerReplay:
    """:class:`~terrain_analysis.sim2real.model.ReplayModel` of one skid-steer bag (module docstring)."""

    #: Per channel, the samples inside the model's domain (set when some are not: model.py "valid").
    valid: Mapping[str, NDArray[np.bool_]]

    def __init__(
        self,
        data: SkidSteerBagData,
        vehicle: ReplayVehicle,
        *,
        vehicle_key: str = "skid_steer",
        nuisance: Sequence[str] = (),
        candidates: Mapping[str, Candidate] | None = None,
        channels: Sequence[str] | None = None,
        warmup: float = 1.0,
        integration_step: float = 2.0e-3,
        noise_repeats: int = 2,
        noise_seed: int = 0,
        wheel_speed_bandwidth: float | None = None,
    ) -> None:
        self.vehicle: str = vehicle_key
        #: Zero-phase low-pass of the wheel speeds driving the replay (Hz; None: as read), :mod:`.skid_steer_input`.
        self.wheel_speed_bandwidth = wheel_speed_bandwidth
        self._omega = smooth_wheel_speeds(data.t, data.omega, wheel_speed_bandwidth)
        self.replay_vehicle = vehicle
        self.data = data
        self.warmup: float = float(warmup)
        self.integration_step = float(integration_step)
        self.notes: list[str] = list(data.notes)
        self._cache: OrderedDict[tuple[Any, ...], FloatArray] = OrderedDict()
        if channels is None:
            # The roll and pitch gyros carry the sprung mass's motion: compared when the IMU measures
            # them and the vehicle has a suspension (a rigid chassis predicts 0 and a real one shakes).
            channels = ("yaw_rate", "ax", "ay", "az")
            if data.body_rates is not None and vehicle.suspension is not None:
                channels += _BODY_RATE_CHANNELS
        self._channel_names = tuple(channels)
        for name in self._channel_names:
            if name not in _IMU_COLUMN:
                raise ValueError(f"unknown channel {name!r}; known: {sorted(_IMU_COLUMN)}")
            if name in _BODY_RATE_CHANNELS and data.body_rates is None:
                raise ValueError(f"channel {name!r}: the bag's IMU does not measure angular_velocity.x/y")
        measured = {
            "ax": data.accel[:, 0],
            "ay": data.accel[:, 1],
            "az": data.accel[:, 2],
            "yaw_rate": data.yaw_rate,
        }
        if data.body_rates is not None:
            measured["roll_rate"], measured["pitch_rate"] = data.body_rates[:, 0], data.body_rates[:, 1]
        self.times: Mapping[str, FloatArray] = {name: data.t for name in self._channel_names}
        self.measured: Mapping[str, FloatArray] = {
            name: np.asarray(measured[name], dtype=float) for name in self._channel_names
        }
        unknown = sorted(set(nuisance) - set(NUISANCE))
        if unknown:
            raise ValueError(f"unknown nuisance parameter(s) {unknown}; known: {sorted(NUISANCE)}")
        self.nuisance: Sequence[FitParameter] = tuple(
            FitParameter(
                name,
                NUISANCE[name][0],
                vehicle.rolling_resistance if name == "rolling_resistance" else 1.0,
                NUISANCE[name][1],
                NUISANCE[name][2],
            )
            for name in nuisance
        )
        if candidates is None:
            exclude = () if vehicle.suspension is not None else ("load_transfer_dynamics",)
            candidates = candidates_from_catalogue("skid_steer", exclude=exclude)
            if exclude:
                self.notes.append(
                    "load_transfer_dynamics not offered: the vehicle config has no suspension (rigid chassis)"
                )
        candidates = dict(candidates)
        if "tire_relaxation" in candidates and not candidates["tire_relaxation"].parameters:
            candidates["tire_relaxation"] = RELAXATION_CANDIDATE
        if "turning_resistance" in candidates and len(candidates["turning_resistance"].parameters) == 1:
            c_b = candidates["turning_resistance"].parameters[0]  # the catalogue's, with its plausible range
            candidates["turning_resistance"] = Candidate(
                "turning_resistance", (c_b, TURNING_RESISTANCE_SPEED_PARAMETER), TURNING_RESISTANCE_DESCRIPTION
            )
        self.candidates: Mapping[str, Candidate] = _restrict_to_channels(candidates, self._channel_names, self.notes)
        if "wheel_speed_delay" in self.candidates:
            # The IMU's last d seconds follow wheel speeds the bag no longer holds: with the encoder-stream delay
            # at its upper bound they cannot be predicted by any model; they are left out of every fit and score.
            longest = max(p.bounds[1] for p in self.candidates["wheel_speed_delay"].parameters)
            inside = data.t <= data.t[-1] - longest
            self.valid = {name: inside for name in self._channel_names}
            self.notes.append(
                f"last {longest:g} s left out: a wheel-encoder stream delayed by up to {longest:g} s "
                "(wheel_speed_delay) leaves the IMU's last samples without wheel speeds"
            )
        speed, encoder_rate = self.no_slip_motion()
        self.regimes: Mapping[str, tuple[FloatArray, FloatArray]] = {
            "speed (m/s)": (data.t, np.abs(speed)),
            "|encoder yaw rate| (rad/s)": (data.t, np.abs(encoder_rate)),
        }
        sigma_input = self._input_noise(noise_repeats, noise_seed)
        sensor = {"ax": vehicle.accel_noise_std, "ay": vehicle.accel_noise_std, "az": vehicle.accel_noise_std}
        sensor["yaw_rate"] = sensor["roll_rate"] = sensor["pitch_rate"] = vehicle.gyro_noise_std
        self.input_noise = sigma_input
        self.channels: Sequence[Channel] = tuple(
            Channel(
                name,
                topic,
                unit,
                float(max(math.hypot(sensor[name], sigma_input[name]), 1e-9)),
            )
            for name, topic, unit in _CHANNELS
            if name in self._channel_names
        )

    def no_slip_motion(self) -> tuple[FloatArray, FloatArray]:
        """Forward speed (m/s) and yaw rate (rad/s) of the bag's wheel speeds without slip (the encoders' motion)."""
        v = self.replay_vehicle
        return no_slip_motion(self.data.omega, v.wheel_radius, v.track)

    # --- physics ----------------------------------------------------------

    def _physics(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> tuple[Physics, Sensing]:
        """(dynamic physics, sensor post-processing) of an effects/nuisance mapping."""
        unknown = sorted(set(effects) - set(self.candidates))
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown} for this replay; known: {sorted(self.candidates)}")

        def value(effect: str, name: str, off: float) -> float:
            return float(effects.get(effect, {}).get(name, off))

        physics = Physics(
            wheel_radius_error=value("wheel_radius_error", "wheel_radius_error", 0.0),
            friction_factor=value("friction_change", "friction_change", 1.0)
            * float(nuisance.get("friction_scale", 1.0)),
            cornering_factor=value("cornering_stiffness_change", "cornering_stiffness_change", 1.0)
            * float(nuisance.get("cornering_stiffness_scale", 1.0)),
            longitudinal_factor=float(nuisance.get("longitudinal_stiffness_scale", 1.0)),
            yaw_inertia_factor=float(nuisance.get("yaw_inertia_scale", 1.0)),
            rolling_resistance=float(nuisance["rolling_resistance"]) if "rolling_resistance" in nuisance else None,
            terrain_grade=value("terrain_grade", "terrain_grade", 0.0),
            terrain_bank=value("terrain_grade", "terrain_bank", 0.0),
            turning_resistance=value("turning_resistance", "turning_resistance", 0.0),
            turning_resistance_speed=value("turning_resistance", "turning_resistance_speed", TURNING_RESISTANCE_SPEED),
            load_transfer_dynamics="load_transfer_dynamics" in effects,
            tire_relaxation="tire_relaxation" in effects and not _no_lag(effects["tire_relaxation"]),
            relaxation_length_x=_optional(effects.get("tire_relaxation", {}), "relaxation_length_x"),
            relaxation_length_y=_optional(effects.get("tire_relaxation", {}), "relaxation_length_y"),
            relaxation_rolling_weight=value("tire_relaxation", "relaxation_rolling_weight", 1.0),
        )
        sensing = Sensing(
            shift=value("sensor_delay", "sensor_delay", 0.0) - value("wheel_speed_delay", "wheel_speed_delay", 0.0),
            scale=np.array(
                [value("accel_scale", f"accel_scale_{axis}", 0.0) for axis in "xyz"]
                + [0.0, 0.0, value("gyro_scale", "gyro_scale", 0.0)]
            ),
            bias=np.array(
                [value("accel_bias", f"accel_bias_{axis}", 0.0) for axis in "xyz"]
                + [value("gyro_bias", "gyro_bias_x", 0.0), value("gyro_bias", "gyro_bias_y", 0.0)]
                + [value("gyro_bias", "gyro_bias", 0.0)]
            ),
        )
        return physics, sensing

    def _dynamic(self, physics: Physics, omega: FloatArray | None = None) -> FloatArray:
        if omega is not None:
            return replay_imu(self.replay_vehicle, self.data.t, omega, physics, integration_step=self.integration_step)
        key = tuple(sorted(vars(physics).items()))
        hit = self._cache.get(key)
        if hit is None:
            hit = replay_imu(
                self.replay_vehicle, self.data.t, self._omega, physics, integration_step=self.integration_step
            )
            # Least recently used out first, within a memory budget: the fits revisit the same physics (the
            # nominal refit of each cross-fitted candidate's folds, starts, the stability refits).
            limit = max(16, min(_CACHE_ENTRIES, _CACHE_BYTES // max(hit.nbytes, 1)))
            while len(self._cache) >= limit:
                self._cache.popitem(last=False)
            self._cache[key] = hit
        else:
            self._cache.move_to_end(key)
        return hit

    def imu(self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]) -> FloatArray:
        """Predicted IMU (M, 6) with the stream delays, scale factors and biases applied (:class:`Sensing`)."""
        physics, sensing = self._physics(effects, nuisance)
        return sensing.apply(self.data.t, self._dynamic(physics))

    def predict(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, FloatArray]:
        imu = self.imu(effects, nuisance)
        return {name: imu[:, _IMU_COLUMN[name]] for name in self._channel_names}

    def _input_noise(self, repeats: int, seed: int) -> dict[str, float]:
        """RMS change of each channel when the wheel speeds get white noise of their reported σ (after warm-up)."""
        vehicle = self.replay_vehicle
        sigma = vehicle.wheel_speed_noise_std
        zero = {name: 0.0 for name in _IMU_COLUMN}
        if repeats <= 0 or (sigma <= 0.0 and vehicle.encoder_step <= 0.0 and vehicle.speed_step <= 0.0):
            return zero
        base = self._dynamic(Physics())
        rng = np.random.default_rng(seed)
        use = self.data.t >= self.data.t[0] + self.warmup
        if not np.any(use):
            return zero
        # The noise is drawn on the joint reports (at their own times and rate) and goes through the same
        # interpolation as the data; an encoder at rest reports exactly 0, so only non-zero reports get noise.
        data = self.data
        ratio = data.transmission_ratio
        moving = np.abs(data.motor_velocity) > 0.0
        acc = {name: 0.0 for name in _IMU_COLUMN}
        for _ in range(repeats):
            shape = data.motor_velocity.shape
            noise = sigma * ratio * rng.standard_normal(shape)
            if vehicle.encoder_step > 0.0:
                # Difference of quantised positions over the report period: (u_k − u_(k−1))/T, u ~ U(0, step).
                # (Integrating the reported speeds would only give back the quantised positions.)
                u = rng.uniform(0.0, vehicle.encoder_step, (shape[0] + 1, shape[1]))
                period = np.diff(data.joint_t, prepend=2.0 * data.joint_t[0] - data.joint_t[1])[:, None]
                noise += (u[1:] - u[:-1]) / period
            if vehicle.speed_step > 0.0:
                noise += rng.uniform(-0.5, 0.5, shape) * vehicle.speed_step * ratio
            noisy_motor = data.motor_velocity + noise * moving
            noisy = smooth_wheel_speeds(
                data.t,
                wheel_speeds_at(data.t, data.joint_t, noisy_motor, ratio, data.timing),
                self.wheel_speed_bandwidth,
            )
            diff = self._dynamic(Physics(), noisy) - base
            for name, col in _IMU_COLUMN.items():
                acc[name] += float(np.mean(diff[use, col] ** 2)) / repeats
        return {name: math.sqrt(v) for name, v in acc.items()}
