"""Truth plant of one side of the Kapvik rocker-bogie rover on deformable soil ([RB] III, MODELS.md C.1–C.4).

The estimators of [RB] (MODELS.md C.5–C.6) see the rover through its sensors
only and drop the Coriolis terms, the inertial coupling of the wheels and the
z-velocity of the body; this plant keeps all of them (DESIGN.md: the truth
has more physics than the filter). The rigid-body model is shared with the
estimators (:mod:`terrain_estimation.models.rover`), the soil is the
Wong–Reece rigid wheel (:mod:`vehicle_sim.terrain.wong_reece`) or its 4th-order
polynomial surrogate (:mod:`vehicle_sim.terrain.terramechanics_surrogate`, the
paper's choice for its simulation), selected by
:attr:`RoverScenario.terramechanics`.

Dynamics (eq. 32)
    Constrained Lagrangian dynamics of the 7 planar coordinates g (see
    :data:`~terrain_estimation.models.rover.COORDINATES`) with the three
    wheel-centre path constraints Ψ_j = z_j − z_wc(x_j) (eq. 26) and Baumgarte
    stabilisation Ψ̈ + 2α Ψ̇ + β² Ψ = 0 (eq. 31, α = β = 500: a critically damped
    constraint mode at 500 s⁻¹). At every evaluation the bordered system::

        [ H    Ψ_gᵀ ] [ g̈  ]   [ Q − c − ∂V/∂g ]
        [ Ψ_g  0    ] [ −λ ] = [ ζ             ],
        ζ = −(J̇_z ġ − z'_wc J̇_x ġ − z''_wc ẋ_j²) − 2α Ψ̇ − β² Ψ

    is solved for g̈ and λ. c = Ḣ ġ − ∂T/∂g is kept in full (the paper
    dropped ∂T/∂g in its simulation, and both in its estimator). λ_j is the
    vertical component of wheel j's constraint reaction (eq. 30); the
    reaction Ψ_gᵀ λ is a world force λ_j (−z'_wc, 1) at the wheel centre,
    normal to the path, so the **normal load** is W_j = λ_j √(1 + z'_wc²).
    Q (eqs. 33–40) holds DP_j along the terrain tangent (cos γ_j, −sin γ_j)
    at the wheel centre, the soil's moment −τ_R,j on the wheel (which also
    loads θ and q1, eq. 34), and the internal drive torque τ_W,j − b_d q̇_j
    between wheel and carrier (eq. 40).

Contact angle γ
    γ_j = −atan(dz_wc/dx) at the wheel centre: the angle of the terrain
    tangent below the horizontal, positive downhill, the sense of eq. 39's
    tangent (cos γ, −sin γ), of eq. 79 (γ = atan(−v_z/v_x) of the centre
    velocity, which is along the path) and of the pitch. The terrain is the
    path offset by r_w along its normal (eq. 25), so the terrain normal under
    the wheel is the path normal at its centre.

Sinkage (``RoverScenario.wheel_sinkage``, on by default; issue 21)
    Each wheel sinks into the soil: its centre runs the depth s_j below the
    path (Ψ_j = z_j − z_wc(x_j) + s_j(t)), so wheels under different loads and
    slips ride at different depths and the body pitches by their difference
    over the wheelbase, which the estimators' geometry (all three centres on
    one path) does not know. The steady depth is the plant's own Wong–Reece
    solution (:func:`~vehicle_sim.terrain.wong_reece.contact_angle`, with the
    full model even when the forces come from the surrogate)::

        z*_j = r (1 − cos θ0(W_j, |i_j|))      (static at i = 0, dynamic: deeper with slip)

    ≈ 14–17 mm for Table II's soil at 40–60 N (≈ 0.2 mm/N; + 0.5 mm from
    i = 0 to 0.4). The depth follows z* (held over the step with W) as a
    critically damped second-order lag s̈ = ω² (z* − s) − 2ω ṡ, solved in
    closed form within the step, so s and ṡ are continuous and the constraint
    sees no velocity jump. Its rate is asymmetric, as a plastic soil is:
    a rising load presses the soil under the rim at once (ω = 1 /
    ``sinkage_loading_time``, 0.1 s: quasi-static pressure–sinkage, smoothed
    over five control steps; a first-order lag with the load held over the
    step fed the constraint's Baumgarte force back into W and diverged); a
    falling load leaves a compacted rut that does not spring back, and the
    rim climbs onto fresh soil over about one contact length r sin θ0 of
    travel (ω = |v_t| / (r sin θ0), ≈ 0.5 s⁻¹ at 2 cm/s). ṡ enters Ψ̇, s̈ the
    constraint acceleration ζ. The soil forces keep acting in the frame of
    the undisturbed surface (γ from the path slope), so a sinking centre
    moves at atan(ṡ/v) off the γ it reports. Off: bit-identical to the
    plant without sinkage.

What is held over a 50 Hz step, and why
    As in the paper, the wheel torques τ_W (PID at 50 Hz) and the normal loads
    W are held over a control step while the slip evolves continuously: DP
    and τ_R are very sensitive to slip (the paper's reason for ode45). With
    Table II's soil dDP/di ≈ 30 N per wheel at W ≈ 50 N and ∂i/∂v = −1/(r_w ω)
    ≈ −43 s/m at 2 cm/s, so the forward speed relaxes to its slip equilibrium
    with a time constant of ≈ 4 ms: holding DP itself over 20 ms would be
    unstable. The terramechanics is therefore evaluated **once per step**, in
    one vectorised call, at the held load W_j and three slips i_j − δ, i_j,
    i_j + δ (δ = :attr:`RoverScenario.slip_stencil`); DP(i) and τ_R(i) in the
    step are the quadratics through those points, evaluated at the current
    slip of every integration stage (the slip moves by ≲ 1e-3 in a step, so
    the quadratic is exact to far below the surrogate's own error).

    W_j is λ_j at the start of the step (evaluated with the new wheel
    torques and the previous step's DP/τ_R model — the algebraic loop W → DP →
    λ is broken by this one-step hold, as in the paper's "previously evaluated
    generalized constraint forces"). A wheel with W_j ≤ 0 has lifted off: it
    gets no soil force (DP = τ_R = 0) and reports W_j = 0; the path constraint
    itself stays bilateral (the paper's model), so the wheel centre cannot
    leave the path. Loads above what the wheel can carry are saturated:
    the full model at θ0 = π/2 (``overload="saturate"``), the surrogate at
    the 200 N edge of its fitting grid.

    The load cells read the contact force that acts at the sample: DP of
    this step's model and the normal load of λ evaluated with it. The held
    W_j is the soil model's input; the two agree to ≈ 4e-4 N (median) except
    at the sample where a wheel enters another soil, where DP jumps and λ
    with it (0.5–3 N). Until session 7 the cells reported the held W_j: a
    40–50 σ spike in the replay of a soil change that no real cell makes.

Slip (eqs. 1–2)
    From the wheel's absolute spin θ̇ + q̇1 + q̇_j (θ̇ + q̇4 for the front wheel)
    and the centre's speed along the path tangent, clipped to [−1, 1]
    (:func:`~terrain_estimation.models.rover.slip_from_motion`); a stalled
    rover sliding back under turning wheels is at full slip i = 1, so the
    soil pushes it forward. The estimator uses the relative rate q̇_j (eq. 68);
    the difference is the carrier rate.

Wheel-speed control (Table III)
    A discrete PID per wheel at 50 Hz on the rim-speed error
    e = v_d − r_w q̇_j (m/s), the quantity the paper names, with the gains
    applied per sample as Table III's unit column ("–") suggests::

        τ_W,k = K_p e_k + K_i Σ_{m≤k} e_m + K_d (e_k − e_{k−1})      (N·m)

    (continuous-time equivalents K_i/T = 25 N·m/m, K_d·T = 0.25 N·m·s²/m).
    Other readings of Table III: with continuous-time gains on e in m/s the
    integral is too weak to reach v_d within a run (the ≈ 1.7 N·m of steady
    wheel torque needs ≈ 3 m of accumulated rim-speed error); with e in rad/s
    and the derivative per second the loop is unstable at 50 Hz (K_d/I_wg =
    11.6 > 1 with one sample of delay); e in rad/s with per-sample gains is
    stable and 1/r_w ≈ 13 times stiffer (scale the gains to get it). Output
    saturated at ±:attr:`RoverController.max_torque`
    with conditional integration (no wind-up). The controller reads the true
    relative wheel rates (the 1400:1 motor encoders resolve them far better
    than the estimator needs).

Start
    The rover starts rolling in a steady state at O's x = :attr:`RoverScenario.start_x`:
    all three wheel centres on the path (Newton on z0, θ, q1), the velocity
    along the constraint manifold, wheel rates at v_d / r_w, body speed
    v_d (1 − i0) with the common slip i0 that balances the forces along the
    path, PID integrators preloaded with τ_R + b_d q̇. (The steady-state soil
    model has DP(i = 0) < 0: a rover at rest would be pushed backward, so
    starting from rest is not modelled.)

Integration
    Classical RK4 over each 20 ms control step, divided into the smallest
    number of equal steps ≤ :attr:`RoverScenario.integration_step` and more
    when the slip modes demand it (estimate λ ≈ Σ|dDP/di| |∂i/∂v| / m +
    |dτ_R/di| |∂i/∂ω| / I_wg, step ≤ 1.5/λ; λ ≈ 350 s⁻¹ while rolling at
    2 cm/s, far more near standstill). The default 2 ms puts the Baumgarte
    mode at λΔt = 1 (RK4 is stable to 2.78). Measured against 0.5 ms steps
    over 30 s on terrains 1 and 6 (surrogate soil): 2 ms → |ΔW| ≤ 1e-4 N,
    |Δi| ≤ 1e-6, |ΔDP| ≤ 3e-5 N, |Δf| ≤ 1e-5 m/s², |Ψ| ≤ 5e-11 m; 4 ms
    (about 1.5× faster) → |ΔW| ≤ 4e-3 N, |Δi| ≤ 6e-5, |Δf| ≤ 4e-4 m/s² (a
    third of the accelerometer's σ), |Ψ| ≤ 3e-9 m.

Sensors (Table IV, MODELS.md C.4) at 50 Hz, unbiased Gaussian noise unless an
    effect adds bias: bogie angle q1, pitch rate θ̇ (about +y), velocimeter
    ẋ0^R = ẋ0 cos θ − ż0 sin θ, body specific force (eqs. 72–73, REP 145: +g
    on z at rest), wheel angles q2…q4, load cells F_L and F_⊥ (eqs. 81–82 with
    the true W, DP, γ, ε), effort = applied wheel torque τ_W (no noise). A
    sample at t_k reports the state at t_k and the torque applied from t_k on.

Effects (:class:`RoverEffects`, all off by default): load-cell bias and
    cross-talk, IMU biases, sensor delay, a soil change at a given distance,
    slip-sinkage, grousers and a short-wavelength undulation of the wheel
    path. The vertical body velocity the estimator ignores is always present
    (terrain-induced); the undulation makes it larger. With every effect off
    the plant is bit-identical to the nominal one (each effect is a separate
    branch that is skipped when off). The catalogue with fit ranges is
    :mod:`vehicle_sim.effects`.

    Slip-sinkage (``slip_sinkage_coefficient`` c ≥ 0, –): the pressure–sinkage
        moduli (k1, k2 of eqs. 4–5, i.e. Bekker's k_c, k_φ) fall with slip,
        k_eff = k / (1 + c |i|), so a slipping wheel sinks deeper than the
        static pressure–sinkage law says (Lyasko 2010's slip-sinkage; Ding et
        al. 2011 obtain the same trend by raising n with slip). Implemented
        at the force level, so it works with the full model and the surrogate
        alike: with zero cohesion every stress of eqs. 4–6 scales with k at a
        given θ0, hence W, DP and τ_R do too, and a wheel on modulus s·k at
        load W has the θ0 of a wheel on modulus k at load W/s with forces
        s × those. With s = 1/(1 + c |i|) the soil model is evaluated at
        W (1 + c |i|) and its DP, τ_R are divided by 1 + c |i| (θ0 is the
        model's own). Cohesion breaks the identity by ≈ c_soil/(σ tan φ)
        (≈ 1 % with Table II's soil at 50 N). The surrogate's 200 N cap
        applies to the scaled load.
    Grousers (``grouser_height`` h_g ≥ 0, m): the soil between the grousers
        moves with the wheel, so the shearing surface is the cylinder through
        the grouser tips (Wong, *Theory of Ground Vehicles*, lugged wheels;
        Ishigami et al. 2007 use the same effective radius). The soil model is
        evaluated for a rigid wheel of radius r_w + h_g (same width) at the
        tip slip i_g = 1 − (1 − i) r_w/(r_w + h_g) (the tip speed is
        (r_w + h_g) ω); its DP and τ_R (about the axle) act on the plant. The
        kinematics (path offset r_w, slip i) are unchanged: the rim rests on
        the terrain and the grousers dig into it. The surrogate is fitted for
        the larger wheel (≈ 0.5 s, cached).
    Path undulation (``path_undulation_amplitude`` A ≥ 0, m,
        ``path_undulation_wavelength`` λ > 0, m): A (1 − cos(2π x/λ)) is added
        to the terrain's wheel-centre path (:attr:`RoverScenario.path`):
        short-wavelength ground roughness that moves the body vertically
        (ż0^R ≠ 0, what the estimators assume away, eq. 45) and adds terrain
        curvature A (2π/λ)², which must stay below 1/r_w (smooth terrain
        under the rim).

The plant is split by concept: the wheel-centre paths
(:mod:`~vehicle_sim.plants.rover_paths`), the scenario, effects, sensors and
samples (:mod:`~vehicle_sim.plants.rover_scenario`), the soil forces per step
(:mod:`~vehicle_sim.plants.rover_terramechanics`) and the constrained
dynamics (:mod:`~vehicle_sim.plants.rover_dynamics`). This module runs them
(:class:`RoverSimulator`: start, control, sensors) and re-exports the names of
:data:`__all__` so that a caller needs one import.

Units: SI throughout (m, s, kg, rad, N, N·m).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.models.rover import (
    WHEELS,
    body_specific_force,
    carrier_angles,
    load_cell_forces,
    wheel_centres,
)
from vehicle_sim.plants.rover_dynamics import _Equations, _Evaluation, _manifold_direction, _rk4, solve_configuration
from vehicle_sim.plants.rover_paths import (
    TERRAIN_NUMBERS,
    TERRAINS,
    WheelPath,
    flat_path,
    rolling_path,
    slope_path,
    step_path,
    undulated_path,
)
from vehicle_sim.plants.rover_scenario import (
    BOGIE_ENCODER_STEP,
    CONTROL_RATE,
    LOAD_CELL_STEP,
    WHEEL_ENCODER_STEP,
    RoverController,
    RoverEffects,
    RoverRun,
    RoverSample,
    RoverScenario,
    RoverSensorNoise,
    RoverSensors,
    RoverTruth,
    TerramechanicsName,
)
from vehicle_sim.plants.rover_scenario import N_WHEELS as _N_WHEELS
from vehicle_sim.plants.rover_terramechanics import _fit_force_model, _ForceModel, _static_sinkage, _Terramechanics
from vehicle_sim.plants.stepping import FiniteRun, stack_fields

__all__ = [
    "CONTROL_RATE",
    "TERRAINS",
    "TERRAIN_NUMBERS",
    "RoverController",
    "RoverEffects",
    "RoverRun",
    "RoverSample",
    "RoverScenario",
    "RoverSensorNoise",
    "RoverSensors",
    "RoverSimulator",
    "RoverTruth",
    "TerramechanicsName",
    "WHEELS",
    "WheelPath",
    "flat_path",
    "rolling_path",
    "simulate_rover",
    "slope_path",
    "solve_configuration",
    "step_path",
    "undulated_path",
]

Array = NDArray[np.float64]


# ---------------------------------------------------------------------------
# Simulator
# ---------------------------------------------------------------------------


class RoverSimulator(FiniteRun):
    """Stepping truth simulator: one :meth:`step` = one 50 Hz control and sensor period.

    Each step computes the wheel torques (PID), the held normal loads and the
    terramechanics model at the current state, reports the sensors and truth
    at t, then integrates to t + 20 ms.

    Args:
        scenario: terrain, duration, seed, models, effects.
    """

    def __init__(self, scenario: RoverScenario) -> None:
        self.scenario = scenario
        self.path = scenario.path
        self._params = scenario.params
        self._period = 1.0 / CONTROL_RATE
        self._n_samples = scenario.n_samples
        self._equations = _Equations(scenario, self.path)
        self._terramechanics = _Terramechanics(scenario)
        streams = np.random.SeedSequence(scenario.seed).spawn(7)
        (
            self._bogie_rng,
            self._gyro_rng,
            self._velocity_rng,
            self._accel_rng,
            self._wheel_rng,
            self._axial_rng,
            self._perpendicular_rng,
        ) = (np.random.default_rng(s) for s in streams)
        delay = int(round(scenario.effects.sensor_delay * CONTROL_RATE))
        self._delay = delay
        self._history: deque[dict[str, Array]] = deque(maxlen=delay + 1)
        self._step_index = 0
        self._integral = np.zeros(_N_WHEELS)
        self._previous_error = np.zeros(_N_WHEELS)
        self._sinkage = np.zeros(_N_WHEELS)
        self._sinkage_rate = np.zeros(_N_WHEELS)
        self._model_elapsed = 0.0  # time into the held model's step where the state is (s)
        self._state, self._model = self._steady_start()

    # --- public state (t: time of the next sample, step_index, done: FiniteRun) --

    @property
    def state(self) -> Array:
        """Copy of [g, ġ] (14,)."""
        return self._state.copy()

    # --- start --------------------------------------------------------------

    def _soil_index(self, x: Array) -> NDArray[np.int_]:
        distance = self.scenario.effects.soil_change_distance
        if distance is None:
            return np.zeros(_N_WHEELS, dtype=int)
        return (x >= distance).astype(int)

    def _steady_start(self) -> tuple[Array, _ForceModel]:
        """Rolling steady state at start_x (module docstring "Start")."""
        scenario = self.scenario
        p = self._params
        g = solve_configuration(p, self.path, scenario.start_x)
        direction = _manifold_direction(p, self.path, g)
        wheel_rate = scenario.desired_speed / p.wheel_radius
        state = np.concatenate([g, np.zeros(7)])
        state[11:] = wheel_rate
        soil_index = self._soil_index(wheel_centres(p, g)[:, 0])

        slips = np.linspace(-0.6, 0.9, 61)
        load = self._equations.evaluate(
            state, _ForceModel.constant(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
        ).vertical_reaction
        slip0 = 0.0
        for _ in range(3):
            norm = np.sqrt(1.0 + self._equations.evaluate(state, self._null_model()).slope ** 2)
            load = np.maximum(load * norm, 0.0)
            n = slips.size
            dp, tau, _ = self._terramechanics(
                np.repeat(load[None, :], n, axis=0).ravel(), np.repeat(slips, 3), np.tile(soil_index, n)
            )
            dp, tau = dp.reshape(n, 3), tau.reshape(n, 3)
            drive = tau + p.wheel_damping * wheel_rate
            # Forward acceleration along the path for each common slip; the steady slip zeroes it.
            forward = np.array(
                [
                    self._equations.evaluate(state, _ForceModel.constant(drive[k], load, dp[k], tau[k])).g_ddot[0]
                    for k in range(n)
                ]
            )
            crossing = np.flatnonzero((forward[:-1] < 0.0) & (forward[1:] >= 0.0))
            if crossing.size:
                k = int(crossing[0])
                slip0 = float(slips[k] - forward[k] * (slips[k + 1] - slips[k]) / (forward[k + 1] - forward[k]))
            else:
                slip0 = float(slips[int(np.argmin(np.abs(forward)))])
            dp0, tau0, _ = self._terramechanics(load, np.full(3, slip0), soil_index)
            drive0 = tau0 + p.wheel_damping * wheel_rate
            load = self._equations.evaluate(state, _ForceModel.constant(drive0, load, dp0, tau0)).vertical_reaction

        if scenario.wheel_sinkage:
            # Sunk to the steady depth at the start load and slip; the loads are then re-evaluated there.
            self._sinkage = self._terramechanics.sinkage(load, np.full(3, slip0), soil_index)[0]
            g = solve_configuration(p, self.path, scenario.start_x, sinkage=self._sinkage)
            direction = _manifold_direction(p, self.path, g)
            state[:7] = g
        # Body speed for slip i0 at the wheels' mean tangent speed per unit ẋ0.
        unit = np.concatenate([g, direction])
        tangent = self._equations.evaluate(unit, self._null_model()).tangent_speed
        speed = scenario.desired_speed * (1.0 - slip0) / float(np.mean(tangent))
        state[7:14] = speed * direction
        state[11:] = wheel_rate
        self._integral = (tau0 + p.wheel_damping * wheel_rate) / max(scenario.controller.integral_gain, 1e-12)
        if scenario.controller.integral_gain == 0.0:
            self._integral[:] = 0.0
        self._previous_error = np.zeros(_N_WHEELS)
        evaluation = self._equations.evaluate(state, _ForceModel.constant(drive0, load, dp0, tau0, self._sinkage))
        model = _fit_force_model(
            self._terramechanics,
            drive0,
            evaluation.vertical_reaction * np.sqrt(1.0 + evaluation.slope**2),
            evaluation.slip,
            soil_index,
            scenario.slip_stencil,
            _static_sinkage(self._sinkage),
        )
        return state, model

    @staticmethod
    def _null_model() -> _ForceModel:
        zeros = np.zeros(_N_WHEELS)
        return _ForceModel.constant(zeros, zeros, zeros, zeros)

    # --- control ------------------------------------------------------------

    def _control(self, state: Array) -> Array:
        """Discrete PID on e = v_d − r_w q̇_j (module docstring), saturated, conditional integration."""
        c = self.scenario.controller
        error = self.scenario.desired_speed - self._params.wheel_radius * state[11:14]
        integral = self._integral + error
        torque = (
            c.proportional_gain * error
            + c.integral_gain * integral
            + c.derivative_gain * (error - self._previous_error)
        )
        saturated = np.abs(torque) > c.max_torque
        # Integrate only where not saturated (or where the error unwinds the saturation).
        keep = ~saturated | (np.sign(error) != np.sign(torque))
        self._integral = np.where(keep, integral, self._integral)
        self._previous_error = error
        clipped: Array = np.clip(torque, -c.max_torque, c.max_torque)
        return clipped

    # --- stepping -----------------------------------------------------------

    def step(self) -> RoverSample:
        """Report the sample at t and advance the plant to t + 20 ms."""
        scenario = self.scenario
        t = self._step_index * self._period
        state = self._state
        torque = self._control(state)

        # W held over the step: λ now, with the new torques and the previous DP/τ_R model.
        # (The previous model at the end of its step: the sinkage's own s, ṡ, s̈ continue, so no spurious
        # Baumgarte force from a sinking wheel enters W.)
        before = self._equations.evaluate(state, self._model.with_torque(torque), self._model_elapsed)
        normal_load = before.vertical_reaction * np.sqrt(1.0 + before.slope**2)
        soil_index = self._soil_index(before.centres[:, 0])
        sinkage = self._sinkage_over_step(normal_load, before, soil_index)
        model = _fit_force_model(
            self._terramechanics, torque, normal_load, before.slip, soil_index, scenario.slip_stencil, sinkage
        )
        evaluation = self._equations.evaluate(state, model)
        step = min(scenario.integration_step, self._equations.stable_step(evaluation, model))
        substeps = max(1, math.ceil(self._period / step - 1e-9))
        sample = self._sample(t, state, evaluation, model, torque, soil_index, substeps)

        self._state = _rk4(self._equations, state, model, self._period / substeps, substeps)
        self._model = model
        self._sinkage, self._sinkage_rate = model.sinkage_at(self._period)
        self._model_elapsed = self._period
        self._step_index += 1
        return sample

    def _sinkage_over_step(
        self, load: Array, before: _Evaluation, soil_index: NDArray[np.int_]
    ) -> tuple[tuple[float, float, float, float], ...]:
        """(s0, ṡ0, z*, ω) per wheel for the coming step (module docstring "Sinkage")."""
        if not self.scenario.wheel_sinkage:
            return _static_sinkage(np.zeros(_N_WHEELS))
        target, length = self._terramechanics.sinkage(np.where(load > 0.0, load, 0.0), before.slip, soil_index)
        loading = 1.0 / self.scenario.sinkage_loading_time
        rows = []
        for j in range(_N_WHEELS):
            start = float(self._sinkage[j])
            if target[j] >= start:
                omega = loading
            else:
                # Unloading: the compacted rut does not spring back; the rim climbs onto fresh soil over one
                # contact length of travel (the longer of the two contacts; ≥ 1 mm).
                contact = max(float(length[j]), self._contact_length(start), 1.0e-3)
                omega = min(abs(float(before.tangent_speed[j])) / contact, loading)
            rows.append((start, float(self._sinkage_rate[j]), float(target[j]), omega))
        return tuple(rows)

    def _contact_length(self, depth: float) -> float:
        """r_e sin θ0 of a rim sunk ``depth`` (m) below the surface (grouser tips h_g deeper)."""
        radius = self._terramechanics.wheel.radius
        cos_theta = 1.0 - min((depth + self._terramechanics.grouser_height) / radius, 1.0)
        return radius * math.sqrt(max(1.0 - cos_theta * cos_theta, 0.0))

    def _sample(
        self,
        t: float,
        state: Array,
        evaluation: _Evaluation,
        model: _ForceModel,
        torque: Array,
        soil_index: NDArray[np.int_],
        substeps: int,
    ) -> RoverSample:
        p = self._params
        g, g_dot = state[:7], state[7:]
        pitch = float(g[2])
        cos_p, sin_p = math.cos(pitch), math.sin(pitch)
        forward = float(g_dot[0] * cos_p - g_dot[1] * sin_p)
        vertical = float(g_dot[0] * sin_p + g_dot[1] * cos_p)
        specific = body_specific_force(p, g, evaluation.g_ddot)
        gamma = -np.arctan(evaluation.slope)
        epsilon = carrier_angles(p, g)
        load = np.where(model.normal_load > 0.0, model.normal_load, 0.0)
        # The cells read the contact force that acts: the normal load of the constraint reaction
        # at this sample with this step's DP model, not the W held for the soil model (computed
        # with the previous step's forces). The two agree to ≈ 4e-4 N (median) except where a
        # wheel enters another soil: there DP jumps and the reaction with it, 0.5-3 N in one step.
        acting = evaluation.vertical_reaction * np.sqrt(1.0 + evaluation.slope**2)
        acting = np.where(load > 0.0, np.maximum(acting, 0.0), 0.0)
        axial, perpendicular = load_cell_forces(acting, evaluation.drawbar_pull, gamma, epsilon)
        x = evaluation.centres[:, 0]
        truth = RoverTruth(
            configuration=g.copy(),
            velocity=g_dot.copy(),
            acceleration=evaluation.g_ddot.copy(),
            pitch=pitch,
            pitch_rate=float(g_dot[2]),
            bogie_angle=float(g[3]),
            forward_velocity=forward,
            vertical_velocity=vertical,
            specific_force=specific,
            slip=evaluation.slip,
            normal_load=load,
            drawbar_pull=evaluation.drawbar_pull,
            resistive_torque=evaluation.resistive_torque,
            contact_angle=gamma,
            entry_angle=model.entry_angle.copy(),
            sinkage=model.sinkage_at(0.0)[0],
            carrier_angle=epsilon,
            wheel_rate=evaluation.wheel_rate,
            wheel_centre=evaluation.centres.copy(),
            wheel_centre_velocity=evaluation.centre_velocity,
            path_curvature=self.path.curvature(x),
            terrain_curvature=self.path.terrain_curvature(x, p.wheel_radius),
            constraint_residual=evaluation.residual,
            vertical_reaction=evaluation.vertical_reaction,
            load_axial=axial,
            load_perpendicular=perpendicular,
            wheel_torque=torque.copy(),
            soil_index=soil_index,
            substeps=substeps,
        )
        clean = {
            "bogie_angle": np.array(g[3]),
            "pitch_rate": np.array(g_dot[2]),
            "forward_velocity": np.array(forward),
            "acceleration": specific,
            "wheel_angle": g[4:7].copy(),
            "load_axial": axial,
            "load_perpendicular": perpendicular,
        }
        return RoverSample(t=t, sensors=self._measure(clean, torque), truth=truth)

    def _measure(self, clean: dict[str, Array], torque: Array) -> RoverSensors:
        """Delay, effects and Table IV noise on the noise-free channels."""
        self._history.append(clean)
        delayed = self._history[0]  # sample k − d once filled, the first sample before
        noise = self.scenario.sensors
        effects = self.scenario.effects
        crosstalk = effects.load_cell_crosstalk
        axial = delayed["load_axial"] + crosstalk * delayed["load_perpendicular"] + np.asarray(effects.load_cell_bias)
        perpendicular = delayed["load_perpendicular"] + crosstalk * delayed["load_axial"]
        bogie = float(delayed["bogie_angle"])
        wheel = delayed["wheel_angle"]
        if noise.quantise:
            bogie = math.floor(bogie / BOGIE_ENCODER_STEP) * BOGIE_ENCODER_STEP
            wheel = np.floor(wheel / WHEEL_ENCODER_STEP) * WHEEL_ENCODER_STEP
            axial = np.round(axial / LOAD_CELL_STEP) * LOAD_CELL_STEP
            perpendicular = np.round(perpendicular / LOAD_CELL_STEP) * LOAD_CELL_STEP
        else:
            bogie += noise.bogie_angle_std * float(self._bogie_rng.standard_normal())
            wheel = wheel + noise.wheel_angle_std * self._wheel_rng.standard_normal(3)
            axial = axial + noise.load_cell_std * self._axial_rng.standard_normal(3)
            perpendicular = perpendicular + noise.load_cell_std * self._perpendicular_rng.standard_normal(3)
        pitch_rate = (
            float(delayed["pitch_rate"])
            + effects.imu_gyro_bias
            + noise.pitch_rate_std * float(self._gyro_rng.standard_normal())
        )
        forward = float(delayed["forward_velocity"]) + noise.forward_velocity_std * float(
            self._velocity_rng.standard_normal()
        )
        acceleration = (
            delayed["acceleration"]
            + np.asarray(effects.imu_accel_bias)
            + noise.acceleration_std * self._accel_rng.standard_normal(2)
        )
        return RoverSensors(
            bogie_angle=bogie,
            pitch_rate=pitch_rate,
            forward_velocity=forward,
            acceleration=acceleration,
            wheel_angle=wheel,
            load_axial=axial,
            load_perpendicular=perpendicular,
            effort=torque.copy(),
        )


def simulate_rover(scenario: RoverScenario) -> RoverRun:
    """Run a :class:`RoverSimulator` to the end of the scenario and stack the samples."""
    simulator = RoverSimulator(scenario)
    samples: list[RoverSample] = []
    while not simulator.done:
        samples.append(simulator.step())

    return RoverRun(
        scenario=scenario,
        time=np.array([s.t for s in samples]),
        sensors=stack_fields(RoverSensors, [s.sensors for s in samples]),
        truth=stack_fields(RoverTruth, [s.truth for s in samples]),
    )
