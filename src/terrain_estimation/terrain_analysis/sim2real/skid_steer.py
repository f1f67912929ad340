"""Replay model of a skid-steered vehicle for the sim-to-real attribution (issue 6).

This module builds the model of a bag (:func:`build_model`); its parts: the vehicle
(:mod:`~terrain_analysis.sim2real.skid_steer_vehicle`), the replay dynamics
(:mod:`~terrain_analysis.sim2real.skid_steer_kernel`), the bag reader
(:mod:`~terrain_analysis.sim2real.skid_steer_bag`) and the replay model
(:mod:`~terrain_analysis.sim2real.skid_steer_replay`); their public names are importable from here too.

Open-loop replay on the bag's inputs
    A dynamic replay driven by the motor torques drifts (the wheel/ground
    traction balance is integrated open loop). Instead the body is driven by
    the *measured wheel speeds*: the planar body states vx, vy, r (and, with
    ``load_transfer_dynamics``, the sprung-mass roll and pitch; with
    ``tire_relaxation``, the per-wheel tire forces) integrate under the brush
    tire forces (MODELS.md B.4) that the slips implied by the measured wheel
    speeds and the replayed body state give. These are exactly the equations
    of the truth plant (:class:`vehicle_sim.plants.skid_steer._EquationsOfMotion`)
    without its wheel-side rotational dynamics (their output, the wheel speed,
    is measured)::

        m (v̇x − vy r) = Σ (F_x − F_rr) + m g_bx(ψ)          (ground slope, effect terrain_grade)
        m (v̇y + vx r) = Σ (F_y + F_b) + m g_by(ψ)          (F_b: effect turning_resistance)
        I_z ṙ         = Σ x_i (F_y,i + F_b,i) − y_i (F_x,i − F_rr,i)
        ψ̇ = r
        σ_x = (R ω − v_x,i)/V_r,  σ_y = −v_y,i/V_r,  V_r = max(R|ω|, ε)     (B.4)
        F_rr,i = f_rr F_z,i tanh(v_x,i / v_rr)                             (motion resistance)
        F_z = quasi-static equal-spring loads (B.5) from the specific force
              of the previous RK4 stage (the plant's one-step hold), or, with
              load-transfer dynamics, static loads ∓ suspension roll/pitch
              moments (K φ + C φ̇) plus the link and unsprung-mass parts
        Ḟ = (V/L)(F_ss − F)   (tire relaxation only)

    Predicted channels: what the IMU at the centre reads, noise free
    (specific force x, y, z in m/s², yaw rate in rad/s; with load-transfer
    dynamics rotated into the tilted body frame with the lever-arm terms of
    the plant's ``_measure``). The roll and pitch gyros (angular_velocity.x,
    .y) are compared too when the IMU measures them (covariance not −1) and
    the vehicle has a suspension: the nominal rigid body predicts 0, the
    sprung mass of ``load_transfer_dynamics`` its roll and pitch rates, the
    effect's most direct signature (without these channels it showed only
    through the tilt of the specific force, and 5 of 6 withheld bags read
    "no significant gap"). Integration: classical RK4, ``substeps`` per
    sensor period (2 ms as the plant; the diagnosis's :func:`build_model`
    uses :data:`DIAGNOSIS_STEP`, 5 ms), raised where the slip dynamics are
    stiff (λ_max Δt ≤ 2 as the plant), the wheel speed linear in time between
    samples.

Wheel speeds
    ``joint_states`` velocity is motor side (rad/s); wheel = motor / i_g.
    A drive that reports the speed as the difference of encoder positions
    over the last period gives the mean over that period, i.e. the speed half
    a period earlier: the speed at an IMU stamp t_k is the mean of the reports
    at t_k and t_k + T (``wheel_speed_timing = "period_mean"``, the
    simulator's and most drives' convention), or the report itself
    (``"instantaneous"``). Joint reports are interpolated linearly to the
    IMU stamps, then (:func:`build_model`) low-passed zero phase above the
    band where their noise, differentiated by the replay, outweighs the
    accelerometer noise (:mod:`~terrain_analysis.sim2real.skid_steer_input`,
    ≈ 13.7 Hz for the simulated drive): from rest the replay's specific
    force is practically R dω/dt, and a fit of the slip stiffness on raw
    reports prefers a softer tire that filters their noise (errors in the
    input variables; every straight-acceleration bag of the withheld suite
    at f1210f7 fitted C_x × 0.6–0.87 and f_rr → 0).

Effects (all of :data:`vehicle_sim.effects.CATALOGUE` ``["skid_steer"]``,
the same physics as :class:`vehicle_sim.plants.skid_steer.SkidSteerEffects`,
written separately)
    Sensors (post-processing of the replayed IMU, :class:`Sensing`; cached
    replays, so fitting them costs almost nothing): ``gyro_bias`` per axis
    (z; x, y where the roll/pitch gyros are compared), ``accel_bias`` and
    ``accel_scale`` per axis, ``gyro_scale`` (yaw), reading = (1 + s) × true
    + b. Stream delays: ``sensor_delay`` (IMU stream: its reading stamped t
    is the replay's at t − d) and ``wheel_speed_delay`` (encoder stream: the
    replay driven by counts of t − d predicts at t what belongs at t + d):
    both shift the prediction (linear interpolation), by d_imu − d_wheel;
    a bag shows only that difference, each effect names the stream that is
    late. With ``wheel_speed_delay`` offered, the last 0.3 s (its upper
    bound) are left out of every fit and score (:attr:`SkidSteerReplay.valid`):
    no model can predict IMU samples whose wheel speeds the bag lacks.
    Physics (a re-run of the replay): ``wheel_radius_error`` (R(1 + e) in
    the slips), ``friction_change`` (μ × factor),
    ``cornering_stiffness_change`` (C_α × factor), ``load_transfer_dynamics``
    (switch), ``tire_relaxation`` (relaxation lengths L_x, L_y, 0: no lag on
    that axis, and the lag's speed law, :data:`RELAXATION_CANDIDATE`),
    ``terrain_grade`` (a ground plane fixed in the world, grade γ and bank β at the start heading: gravity in
    the plane's axes g_p = −g (sin γ, cos γ sin β, ·), turned into the body
    frame by the replay's own heading ψ = ∫ r dt, g_bx = g_px cos ψ +
    g_py sin ψ, g_by = −g_px sin ψ + g_py cos ψ; loads and IMU z carry
    g_n = g cos γ cos β), ``turning_resistance`` (lateral soil resistance
    F_b,i = −c_b F_z,i tanh(v_y,i / 0.05 m/s) added to each wheel's lateral
    force: a resistive yaw moment in skid-steer turns).

    A bank and an accelerometer bias (y, z) read the same at the IMU when
    the heading does not change: g sin β on y and g (cos β − 1) on z. The
    bank also needs lateral tire forces and shifts the loads across the
    track, but at the simulator's stiffnesses that changes the yaw rate by
    less than the gyro noise; on a straight run the two are indistinguishable
    (the engine says so). Once the vehicle turns, a world-fixed slope turns
    in the body frame (g sin β cos ψ on y, g sin β sin ψ on x) and a bias
    does not: the bank is identified.

Nuisance parameters
    None by default: the initial state comes from the first wheel speeds
    (vx = R(ω_l + ω_r)/2, r = R(ω_r − ω_l)/B, vy = 0, forces and attitude 0)
    and the first ``warmup`` seconds are left out. A vehicle whose tire
    parameters are not known (the Husky) passes ``nuisance`` names of
    :data:`NUISANCE` (scale factors of C_x, C_α, μ, f_rr, I_z).

Noise budget σ per channel
    Sensor noise from the config (``sensors.accel_noise_std``,
    ``sensors.gyro_noise_std``) plus what the wheel-speed errors do through
    the replay: the replay is re-run with the joint reports perturbed as a
    drive reports them (a difference of positions quantised to the encoder
    step over the report period, (u_k − u_(k−1))/T with u ~ U(0, step), plus
    ``sensors.motor_velocity_noise_std``; or a quantised speed), at the
    reports' own times and through the same interpolation, and the RMS change
    of each channel is added in quadrature (through the same input low-pass:
    ax 0.0022 m/s² RMS on a straight run where raw reports give 0.0089). Measured on the simulator
    (noise-free sensors, real quantisation): the quantisation costs ax
    0.016–0.019 m/s² RMS on the straight run where this estimate gives 0.011
    (the actual error is a speed-dependent pattern, not white noise, and the
    replay's gain rises with frequency), i.e. the ax budget is ≈ 2–4 % low in
    σ on the straight run and the turn; the noise tests' power floor (1.25)
    covers it.
    The replay's own error (linear wheel speed within a period instead of the
    plant's wheel dynamics) is 0.006–0.007 m/s² RMS on ax and below 1e-4 rad/s
    on the yaw rate (test_sim2real_skid_steer).

Units SI throughout (m, s, rad, N, kg).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from terrain_analysis.sim2real import skid_steer_replay
from terrain_analysis.sim2real.skid_steer_bag import (
    SkidSteerBagData,
    bag_data_from_arrays,
    read_skid_steer_bag,
    wheel_speeds_at,
)
from terrain_analysis.sim2real.skid_steer_input import input_bandwidth, smooth_wheel_speeds
from terrain_analysis.sim2real.skid_steer_kernel import Physics, Sensing, replay_imu
from terrain_analysis.sim2real.skid_steer_replay import DIAGNOSIS_STEP, NUISANCE, SkidSteerReplay
from terrain_analysis.sim2real.skid_steer_vehicle import (
    ReplayVehicle,
    Suspension,
    equal_spring_loads,
    vehicle_from_config,
    with_vehicle,
)
from terrain_analysis.sim2real.where import Sim2RealError

__all__ = [
    "DIAGNOSIS_STEP",
    "NUISANCE",
    "Physics",
    "ReplayVehicle",
    "Sensing",
    "SkidSteerBagData",
    "SkidSteerReplay",
    "Suspension",
    "bag_data_from_arrays",
    "build_model",
    "equal_spring_loads",
    "input_bandwidth",
    "read_skid_steer_bag",
    "replay_imu",
    "smooth_wheel_speeds",
    "vehicle_from_config",
    "wheel_speeds_at",
    "with_vehicle",
]

Progress = Callable[[str], None] | None


def _config_kind(config: str | Path) -> str:
    from terrain_estimation.params import load_parameter_file

    return str(load_parameter_file(config).get("vehicle.kind", "skid_steer"))


def build_model(
    bag: str | Path,
    *,
    config: str | Path | None = None,
    namespace: str | None = None,
    progress: Progress = None,
    vehicle: ReplayVehicle | None = None,
    nuisance: Sequence[str] = (),
    warmup: float = 1.0,
    wheel_speed_timing: str = "period_mean",
    joints: tuple[str, str] | None = None,
    integration_step: float | None = None,
    smooth_inputs: bool = True,
) -> SkidSteerReplay:
    """The replay model of a skid-steer bag for :func:`terrain_analysis.sim2real.attribution.attribute`.

    Args:
        bag: the bag (CONTRACT.md skid-steer topics ``imu``, ``joint_states``).
        config: the vehicle's config (default ``config/skid_steer.yaml``); a config with
            ``vehicle.kind: husky`` (``config/husky.yaml``) gives the 4-wheel Husky model of
            :func:`terrain_analysis.sim2real.husky.build_husky_model` (default namespace ``/husky``).
        namespace: the bag's namespace (default ``/skid_steer``).
        progress: called with progress lines.
        vehicle: a ready :class:`ReplayVehicle` instead of the config (e.g. the Husky).
        nuisance: names of :data:`NUISANCE` to fit in every model.
        warmup: seconds left out at the start.
        wheel_speed_timing: ``period_mean`` or ``instantaneous`` (module docstring).
        joints: (left, right) joint names (default: the config's ``joints.*``).
        integration_step: largest RK4 step of the replay (s; default :data:`DIAGNOSIS_STEP`, read at the call).
        smooth_inputs: low-pass the wheel speeds above the band where their noise, through the replay, outweighs
            the accelerometer noise (:mod:`~terrain_analysis.sim2real.skid_steer_input`); False: as read.
    """
    if vehicle is None and config is not None and _config_kind(config) == "husky":
        from terrain_analysis.sim2real.husky_model import build_husky_model

        if progress is not None:
            progress(f"reading {bag} (Husky config {config})")
        return build_husky_model(bag, config, namespace=namespace or "/husky", warmup=warmup)
    if vehicle is None:
        vehicle = vehicle_from_config(config)
        if joints is None:
            from vehicle_sim.ros.registry import get_simulator, simulator_parameters

            values = simulator_parameters(get_simulator("skid_steer"), config)
            joints = (str(values["joints.left_motor"]), str(values["joints.right_motor"]))
    if progress is not None:
        progress(f"reading {bag}")
    data = read_skid_steer_bag(
        bag,
        namespace=namespace or "/skid_steer",
        joints=joints or ("left_motor", "right_motor"),
        transmission_ratio=vehicle.transmission_ratio,
        wheel_speed_timing=wheel_speed_timing,
    )
    if data.t[-1] < warmup + 2.0:
        raise Sim2RealError(
            f"bag {str(bag)!r}: {data.t[-1]:.2f} s of overlapping imu and joint_states data; the diagnosis needs "
            f"at least the {warmup:g} s warm-up plus 2 s"
        )
    step = skid_steer_replay.DIAGNOSIS_STEP if integration_step is None else float(integration_step)
    bandwidth = None
    if smooth_inputs and len(data.joint_t) > 1 and len(data.t) > 1:
        periods = float(np.median(np.diff(data.joint_t))), float(np.median(np.diff(data.t)))
        bandwidth = input_bandwidth(vehicle, *periods)
    model = SkidSteerReplay(
        data, vehicle, nuisance=nuisance, warmup=warmup, integration_step=step, wheel_speed_bandwidth=bandwidth
    )
    if bandwidth is not None:
        model.notes.append(
            f"wheel speeds low-passed (zero phase) above {bandwidth:.1f} Hz, where the reports' noise through the "
            "replay from rest outweighs the accelerometer noise"
        )
    if progress is not None:
        progress(
            f"replay model: {len(data.t)} IMU samples over {data.t[-1]:.1f} s; noise budget "
            + ", ".join(f"{c.name} {c.noise_std:.3g} {c.unit}" for c in model.channels)
        )
    return model
