"""The skid-steer replay's input: wheel speeds band-limited where their noise would outweigh the accelerometer's.

Why (measured on the withheld suite at f1210f7, issue 22)
    The replay is driven by the reported wheel speeds. At low speed its slip
    dynamics are fast (time constant m V / (n C_x): 8 ms at 0.5 m/s for the
    simulated 6-wheeler), so the replayed specific force is practically the
    derivative of the reported speed, R dω/dt: the reports' noise (position
    quantisation differenced over the report period, plus white noise) comes
    out of the replay amplified by (2π f)². A slip stiffness C_x lower than
    the vehicle's slows the slip dynamics and filters that noise away, so a
    fitted C_x is biased low wherever the bag starts from rest (errors in the
    input variables): on all 28 straight-acceleration bags of the suite the
    nominal fit went to C_x × 0.61–0.87 and f_rr → 0, and the held-out
    ramp-end transient, which C_x dominates, then read as a gap (5 of 5
    controls failed there).

What
    The wheel speeds at the IMU stamps are low-passed, zero phase (forward and
    backward second-order Butterworth: no delay, so stream-delay effects are
    untouched), above the frequency ``f_q`` from which the reports' noise,
    through the replay at rest, has more power than the accelerometer's own
    noise (:func:`input_bandwidth`)::

        S_v(f) = (2/f_r) (R/i_g)² [ (q²/12)/T² (2 − 2 cos 2π f T) + σ_m² ] + (2/f_r) R² (s²/12)
        |H(f)|² S_v(f_q) = 2 σ_a² / f_s,   |H|² = (2πf)² G²/(G² + (2πf)²),  G = n C_x/(m V)

    with q the motor encoder quantum, T = 1/f_r the report period, σ_m the
    motor-velocity noise, s the wheel-speed quantum, σ_a the accelerometer
    noise, f_s the IMU rate and H the replay's linearised gain from the tread
    speed R ω to the specific force (a differentiator below G/2π). At rest
    (V at the rolling-speed floor) H is a differentiator over the whole band
    and ``f_q`` is lowest: for the simulated 6-wheeler (4096 counts/rev,
    100 Hz reports, σ 0.02 rad/s motor side, σ_a 0.05 m/s²) 13.7 Hz, above
    the drive's wheel–tire mode (≈ 7 Hz) and the sprung mass's modes. The
    same cutoff holds at every speed. A cutoff rising with speed (where H
    turns into the gain G and the noise stays below the accelerometer's) was
    tried and brought the bias back (C_x × 0.72–0.84 on the five straight
    controls): the bias comes from every band whose replayed noise depends on
    C_x, not only from the bands above the accelerometer noise. The price at
    speed: the wheel speed's own content above 13.7 Hz, which the replay
    passes with gain G, is lost; on the straight runs' ramp end (8.3 m/s) the
    held-out ax residual grew by ≈ 4 % in power. The noise budget of the
    replay goes through the same filter
    (:meth:`~terrain_analysis.sim2real.skid_steer_replay.SkidSteerReplay._input_noise`).

Units SI (m, s, rad, Hz).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from terrain_analysis.sim2real.skid_steer_vehicle import ReplayVehicle

__all__ = ["input_bandwidth", "smooth_wheel_speeds"]

FloatArray = NDArray[np.float64]


def _report_noise_psd(vehicle: ReplayVehicle, report_period: float, f: FloatArray) -> FloatArray:
    """One-sided PSD ((m/s)²/Hz) of the reported tread speed R ω's noise at the frequencies ``f`` (Hz)."""
    rate = 1.0 / report_period
    ratio, radius = vehicle.transmission_ratio, vehicle.wheel_radius
    quantum = (
        vehicle.encoder_step**2 / 12.0 / report_period**2 * (2.0 - 2.0 * np.cos(2.0 * math.pi * f * report_period))
    )
    motor = (vehicle.wheel_speed_noise_std * ratio) ** 2
    wheel = (2.0 / rate) * (radius / ratio) ** 2 * (quantum + motor)
    return np.asarray(wheel + (2.0 / rate) * radius**2 * vehicle.speed_step**2 / 12.0, dtype=float)


def _replay_gain2(vehicle: ReplayVehicle, f: FloatArray, speed: float) -> FloatArray:
    """|H(f)|² of the replay from the tread speed R ω to the specific force at the tread speed ``speed`` (m/s).

    Linearised about steady rolling: m δv̇ = n C_x (δ(Rω) − δv)/V gives δa = s G/(s + G) δ(Rω) with
    G = n C_x/(m V): a differentiator below G/2π, a gain G above it.
    """
    n = 2 * len(vehicle.axle_x)
    g = n * vehicle.longitudinal_stiffness / (vehicle.mass * max(speed, vehicle.rolling_speed_floor))
    w2 = (2.0 * math.pi * f) ** 2
    return np.asarray(w2 * g**2 / (g**2 + w2), dtype=float)


def input_bandwidth(
    vehicle: ReplayVehicle, report_period: float, imu_period: float, speed: float = 0.0
) -> float | None:
    """``f_q`` (Hz, module docstring) at the tread speed ``speed`` (m/s): the lowest frequency at which the
    reports' noise through the replay outweighs the accelerometer noise, or None when it never does below the
    reports' Nyquist frequency (no filtering)."""
    if not (report_period > 0.0 and imu_period > 0.0 and vehicle.accel_noise_std > 0.0):
        return None
    nyquist = 0.5 / max(report_period, imu_period)
    f = np.linspace(nyquist / 2000.0, nyquist, 2000)
    replayed = _replay_gain2(vehicle, f, speed) * _report_noise_psd(vehicle, report_period, f)
    excess = replayed > 2.0 * vehicle.accel_noise_std**2 * imu_period
    if not np.any(excess):
        return None
    return float(f[int(np.argmax(excess))])


def smooth_wheel_speeds(t: FloatArray, omega: FloatArray, bandwidth: float | None) -> FloatArray:
    """``omega`` (M, 2) at the times ``t`` low-passed zero phase at ``bandwidth`` (Hz; None or ≥ Nyquist: as is)."""
    omega = np.asarray(omega, dtype=float)
    if bandwidth is None or omega.shape[0] < 16:
        return omega
    rate = 1.0 / float(np.median(np.diff(t)))
    if not bandwidth < 0.5 * rate:
        return omega
    sos = signal.butter(2, bandwidth, fs=rate, output="sos")
    return np.ascontiguousarray(signal.sosfiltfilt(sos, omega, axis=0))
