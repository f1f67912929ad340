"""The rover's run: controller, sensor noise, sim-to-real effects, scenario, and the samples a run produces.

Configuration and records only; the plant that runs them is
:mod:`vehicle_sim.plants.rover` (its docstring, the "plant docstring" below,
describes the physics each field refers to).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.models.rover import RoverParams
from vehicle_sim.plants.checks import (
    changed_fields,
    check_fields,
    check_float_finite,
    check_float_non_negative,
    check_float_positive,
    finite_tuple,
    without_noise,
)
from vehicle_sim.plants.rover_paths import TERRAINS, WheelPath, undulated_path
from vehicle_sim.terrain.wong_reece import DEFAULT_SIMPSON_POINTS, TABLE_II_SOIL, WongReeceSoil

Array = NDArray[np.float64]
TerramechanicsName = Literal["wong_reece", "surrogate"]

CONTROL_RATE = 50.0
"""PID, recording and sensor rate (Hz), [RB] III-C."""

N_WHEELS = 3
"""Wheels of the modelled side: rear, middle, front (:data:`~terrain_estimation.models.rover.WHEELS`)."""

# ---------------------------------------------------------------------------
# Controller, sensors, effects, scenario
# ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class RoverController:
    """Per-wheel discrete PID on the rim speed r_w q̇_j (Table III; form in the plant docstring).

    Attributes:
        proportional_gain: K_p (N·m per m/s).
        integral_gain: K_i (N·m per m/s, per sample of the running sum).
        derivative_gain: K_d (N·m per m/s of change between samples).
        max_torque: saturation of τ_W at the wheel (N·m) [recon: the paper
            gives none; 10 N·m exceeds τ_R at 200 N and full slip, 7.9 N·m].
    """

    proportional_gain: float = 25.0
    integral_gain: float = 0.5
    derivative_gain: float = 12.5
    max_torque: float = 10.0

    def __post_init__(self) -> None:
        gains = ("proportional_gain", "integral_gain", "derivative_gain")
        check_fields(self, gains, rule="non_negative", strict_types=True)
        check_float_positive("RoverController", "max_torque", self.max_torque)


@dataclass(frozen=True, kw_only=True)
class RoverSensorNoise:
    """Sensor noise σ of [RB] Table IV in SI units (one LSB / 6 for the digital sensors).

    Attributes:
        bogie_angle_std: 16-bit absolute encoder, 9.155e-4° (rad).
        pitch_rate_std: IMU gyro, 0.56 °/s (rad/s).
        forward_velocity_std: optic-flow velocimeter, 1 mm/s (m/s).
        acceleration_std: IMU accelerometer per axis, 1.245e-3 m/s².
        wheel_angle_std: 500-count quadrature encoder behind 1400:1, 2.143e-5° (rad).
        load_cell_std: 200 N full scale, 10-bit ADC, 3.255e-2 N (both axes).
        quantise: round the encoders and load cells to their LSB (2π/2¹⁶,
            2π/(4·500·1400), 200 N/1024) instead of adding their Gaussian
            noise (the paper adds Gaussian noise).
    """

    bogie_angle_std: float = math.radians(9.155e-4)
    pitch_rate_std: float = math.radians(0.56)
    forward_velocity_std: float = 1.0e-3
    acceleration_std: float = 1.245e-3
    wheel_angle_std: float = math.radians(2.143e-5)
    load_cell_std: float = 3.255e-2
    quantise: bool = False

    def __post_init__(self) -> None:
        noise = (f.name for f in fields(self) if f.name.endswith("_std"))
        check_fields(self, noise, rule="non_negative", strict_types=True)

    @classmethod
    def noiseless(cls) -> RoverSensorNoise:
        """No noise anywhere."""
        return without_noise(cls)


#: LSBs of the digital sensors (Table IV footnotes).
BOGIE_ENCODER_STEP = 2.0 * math.pi / 2**16
WHEEL_ENCODER_STEP = 2.0 * math.pi / (4 * 500 * 1400)
LOAD_CELL_STEP = 200.0 / 1024


@dataclass(frozen=True, kw_only=True)
class RoverEffects:
    """Sim-to-real effects, all off by default (the nominal plant).

    Attributes:
        load_cell_bias: constant offset of each axial load cell F_L (N), (rear, middle, front).
        load_cell_crosstalk: fraction c of each axis leaking into the other:
            F_L + c F_⊥ and F_⊥ + c F_L (–).
        imu_accel_bias: accelerometer bias (x, z) in the body frame (m/s²).
        imu_gyro_bias: pitch-rate gyro bias (rad/s).
        sensor_delay: latency of every measured channel (s), rounded to whole
            samples (20 ms); the effort (commanded torque) is not delayed.
        soil_change_distance: wheel-centre x (m) beyond which a wheel runs on
            ``soil_change_soil`` instead of the scenario's soil; None: no change.
        soil_change_soil: the soil after the change.
        slip_sinkage_coefficient: c of k_eff = k/(1 + c |i|) (–), plant docstring.
        grouser_height: h_g, grouser height above the rim (m), plant docstring.
        path_undulation_amplitude: A of the undulation A (1 − cos(2π x/λ)) added
            to the wheel-centre path (m); 0: none.
        path_undulation_wavelength: λ of that undulation (m).
    """

    load_cell_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    load_cell_crosstalk: float = 0.0
    imu_accel_bias: tuple[float, float] = (0.0, 0.0)
    imu_gyro_bias: float = 0.0
    sensor_delay: float = 0.0
    soil_change_distance: float | None = None
    soil_change_soil: WongReeceSoil | None = None
    slip_sinkage_coefficient: float = 0.0
    grouser_height: float = 0.0
    path_undulation_amplitude: float = 0.0
    path_undulation_wavelength: float = 0.5

    def __post_init__(self) -> None:
        owner = "RoverEffects"
        check_float_non_negative(owner, "slip_sinkage_coefficient", self.slip_sinkage_coefficient)
        check_float_non_negative(owner, "grouser_height", self.grouser_height)
        check_float_non_negative(owner, "path_undulation_amplitude", self.path_undulation_amplitude)
        check_float_positive(owner, "path_undulation_wavelength", self.path_undulation_wavelength)
        object.__setattr__(self, "load_cell_bias", finite_tuple(owner, "load_cell_bias", self.load_cell_bias, 3))
        object.__setattr__(self, "imu_accel_bias", finite_tuple(owner, "imu_accel_bias", self.imu_accel_bias, 2))
        check_float_finite(owner, "load_cell_crosstalk", self.load_cell_crosstalk)
        check_float_finite(owner, "imu_gyro_bias", self.imu_gyro_bias)
        check_float_non_negative(owner, "sensor_delay", self.sensor_delay)
        if (self.soil_change_distance is None) != (self.soil_change_soil is None):
            raise ValueError(f"{owner}: soil_change_distance and soil_change_soil must be given together")
        if self.soil_change_distance is not None:
            check_float_finite(owner, "soil_change_distance", self.soil_change_distance)

    @property
    def active(self) -> tuple[str, ...]:
        """Names of the effects that are switched on."""
        return changed_fields(self, RoverEffects())


@dataclass(frozen=True, kw_only=True)
class RoverScenario:
    """One run of the rover over a terrain of :data:`TERRAINS`.

    Attributes:
        terrain: key of :data:`TERRAINS`.
        duration: simulated time (s); None takes the terrain's.
        seed: seed of the sensor noise (the truth never depends on it).
        terramechanics: ``"surrogate"`` (the paper's simulation, 4th-order
            polynomial) or ``"wong_reece"`` (the full model, root-finding).
        desired_speed: v_d (m/s), Table III.
        params: rover parameters.
        soil: Wong–Reece soil (Table II); the surrogate is fitted to it.
        controller: wheel-speed PID.
        sensors: sensor noise.
        effects: sim-to-real effects.
        baumgarte_alpha, baumgarte_beta: α, β of eq. 31 (Table III).
        integration_step: largest RK4 step (s); 2 ms keeps the truth converged to ≤ 1e-4 N (plant docstring).
        slip_stencil: δ of the per-step slip quadratic (plant docstring).
        start_x: world x of O at t = 0 (m).
        simpson_points: rim nodes per flow region of the full model.
        wheel_sinkage: sink each wheel into the soil by its Wong–Reece sinkage
            (plant docstring "Sinkage"); False: the wheel centres ride on the
            path offset r_w from the terrain (the plant before issue 21).
        sinkage_loading_time: time constant of the sinkage following a rising
            load or slip (s), > 0; 0.1 s by default (plant docstring).
    """

    terrain: str = "rolling"
    duration: float | None = None
    seed: int = 0
    terramechanics: TerramechanicsName = "surrogate"
    desired_speed: float = 0.02
    params: RoverParams = field(default_factory=RoverParams)
    soil: WongReeceSoil = TABLE_II_SOIL
    controller: RoverController = field(default_factory=RoverController)
    sensors: RoverSensorNoise = field(default_factory=RoverSensorNoise)
    effects: RoverEffects = field(default_factory=RoverEffects)
    baumgarte_alpha: float = 500.0
    baumgarte_beta: float = 500.0
    integration_step: float = 2.0e-3
    slip_stencil: float = 0.02
    start_x: float = 0.0
    simpson_points: int = DEFAULT_SIMPSON_POINTS
    wheel_sinkage: bool = True
    sinkage_loading_time: float = 0.1

    def __post_init__(self) -> None:
        owner = "RoverScenario"
        check_float_positive(owner, "sinkage_loading_time", self.sinkage_loading_time)
        if self.terrain not in TERRAINS:
            raise ValueError(f"{owner}.terrain must be one of {sorted(TERRAINS)}, got {self.terrain!r}")
        if self.duration is not None:
            check_float_positive(owner, "duration", self.duration)
        if self.terramechanics not in ("surrogate", "wong_reece"):
            raise ValueError(f"{owner}.terramechanics must be 'surrogate' or 'wong_reece', got {self.terramechanics!r}")
        check_float_positive(owner, "desired_speed", self.desired_speed)
        check_float_non_negative(owner, "baumgarte_alpha", self.baumgarte_alpha)
        check_float_non_negative(owner, "baumgarte_beta", self.baumgarte_beta)
        check_float_positive(owner, "integration_step", self.integration_step)
        if not (0.0 < self.slip_stencil <= 0.1):
            raise ValueError(f"{owner}.slip_stencil must be in (0, 0.1], got {self.slip_stencil!r}")
        check_float_finite(owner, "start_x", self.start_x)
        amplitude = self.effects.path_undulation_amplitude
        if amplitude > 0.0:
            curvature = amplitude * (2.0 * math.pi / self.effects.path_undulation_wavelength) ** 2
            if curvature * self.params.wheel_radius >= 1.0:
                raise ValueError(
                    f"{owner}.effects: path undulation curvature A (2π/λ)² = {curvature:.3g} 1/m must be below "
                    f"1/r_w = {1.0 / self.params.wheel_radius:.3g} 1/m"
                )

    @property
    def path(self) -> WheelPath:
        """The wheel-centre path of :attr:`terrain`, with the path-undulation effect if it is on."""
        path = TERRAINS[self.terrain]()
        amplitude = self.effects.path_undulation_amplitude
        if amplitude > 0.0:
            path = undulated_path(path, amplitude, self.effects.path_undulation_wavelength)
        return path

    @property
    def run_duration(self) -> float:
        """Simulated time (s): ``duration`` or the terrain's."""
        return self.path.duration if self.duration is None else self.duration

    @property
    def n_samples(self) -> int:
        """Samples of the run at 50 Hz (t = 0 … duration − T)."""
        return max(1, int(round(self.run_duration * CONTROL_RATE)))


# ---------------------------------------------------------------------------
# Samples and runs
# ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RoverSensors:
    """Sensor readings of one sample (scalars / (3,) / (2,)), or stacked (N, …) in a run.

    Attributes:
        bogie_angle: q̌1 (rad).
        pitch_rate: θ̇̌0y about +y (rad/s).
        forward_velocity: ẋ̌0^R along the body x axis (m/s).
        acceleration: (x, z) body-frame specific force (m/s², eqs. 72–73).
        wheel_angle: q̌2…q̌4 relative to the carriers (rad), (3,).
        load_axial: F̌_L per wheel (N), (3,), the single-axis cells.
        load_perpendicular: F̌_⊥ per wheel (N), (3,), the second axis.
        effort: applied wheel torque τ_W (N·m), (3,).
    """

    bogie_angle: Any
    pitch_rate: Any
    forward_velocity: Any
    acceleration: Any
    wheel_angle: Any
    load_axial: Any
    load_perpendicular: Any
    effort: Any


@dataclass(frozen=True, slots=True)
class RoverTruth:
    """What only the simulator knows; per-wheel arrays in :data:`WHEELS` order.

    Attributes:
        configuration: g (7,).
        velocity: ġ (7,).
        acceleration: g̈ (7,).
        pitch, pitch_rate, bogie_angle: θ (rad), θ̇ (rad/s), q1 (rad).
        forward_velocity: ẋ0^R (m/s), body x.
        vertical_velocity: ż0^R (m/s), body z (what eq. 45 assumes zero).
        specific_force: (x, z) body frame (m/s²), eqs. 72–73.
        slip: i per wheel (–), eqs. 1–2.
        normal_load: W per wheel (N), held over the step.
        drawbar_pull: DP per wheel (N) at (W, i).
        resistive_torque: τ_R per wheel (N·m) at (W, i).
        contact_angle: γ per wheel (rad), positive downhill: the slope of the
            undisturbed terrain surface under the wheel (the soil forces act
            in its frame), not the direction the sinking centre moves in.
        entry_angle: Wong–Reece θ0 per wheel (rad); NaN with the surrogate.
        sinkage: depth of each wheel centre below its path, i.e. of the rim's
            lowest point below the undisturbed surface (m), plant docstring
            "Sinkage"; 0 without ``wheel_sinkage``.
        carrier_angle: ε per wheel (rad).
        wheel_rate: absolute wheel spin θ̇ (+ q̇1) + q̇_j (rad/s).
        wheel_centre: (3, 2) world (x, z) (m).
        wheel_centre_velocity: (3, 2) world (ẋ, ż) (m/s).
        path_curvature: κ of the wheel-centre path under each wheel (1/m).
        terrain_curvature: κ_t of the terrain under each wheel (1/m).
        constraint_residual: Ψ (m).
        vertical_reaction: λ (N), eq. 30.
        load_axial, load_perpendicular: noise-free F_L, F_⊥ (N), eqs. 81–82, of the
            contact force that acts at the sample (its normal load from λ, not the held W).
        wheel_torque: τ_W applied from this sample on (N·m).
        soil_index: 0 = scenario soil, 1 = changed soil (effect), per wheel.
        substeps: RK4 steps of the coming control step.
    """

    configuration: Any
    velocity: Any
    acceleration: Any
    pitch: Any
    pitch_rate: Any
    bogie_angle: Any
    forward_velocity: Any
    vertical_velocity: Any
    specific_force: Any
    slip: Any
    normal_load: Any
    drawbar_pull: Any
    resistive_torque: Any
    contact_angle: Any
    entry_angle: Any
    sinkage: Any
    carrier_angle: Any
    wheel_rate: Any
    wheel_centre: Any
    wheel_centre_velocity: Any
    path_curvature: Any
    terrain_curvature: Any
    constraint_residual: Any
    vertical_reaction: Any
    load_axial: Any
    load_perpendicular: Any
    wheel_torque: Any
    soil_index: Any
    substeps: Any


@dataclass(frozen=True, slots=True)
class RoverSample:
    """One 50 Hz sample: time, sensors, truth at t."""

    t: float
    sensors: RoverSensors
    truth: RoverTruth


@dataclass(frozen=True)
class RoverRun:
    """Stacked samples of one run (N = duration × 50 Hz, t = 0 … duration − T).

    Attributes:
        scenario: the scenario.
        time: (N,) s.
        sensors: readings with arrays (N,), (N, 2) or (N, 3).
        truth: truth with arrays (N, …).
    """

    scenario: RoverScenario
    time: Array
    sensors: RoverSensors
    truth: RoverTruth
