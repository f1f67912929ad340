"""The skid-steer bag on the IMU time base: IMU and wheel speeds (:mod:`terrain_analysis.sim2real.skid_steer`).

``joint_states`` velocity is motor side; the wheel speed at an IMU stamp follows the drive's reporting
convention (``wheel_speed_timing``: the docstring of :mod:`terrain_analysis.sim2real.skid_steer`, "Wheel speeds").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import StampOrigin
from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.bag import bag_topics

__all__ = ["SkidSteerBagData", "bag_data_from_arrays", "read_skid_steer_bag", "wheel_speeds_at"]

FloatArray = NDArray[np.float64]


@dataclass
class SkidSteerBagData:
    """The bag's signals on the IMU time base (s from the first IMU stamp).

    Attributes:
        t: IMU sample times (M,).
        accel: specific force (M, 3) (m/s²).
        yaw_rate: gyro z (M,) (rad/s).
        body_rates: gyro x, y (M, 2) (rad/s: roll and pitch rate), or None when
            the IMU does not measure them (angular_velocity_covariance[0] or [4]
            is −1, REP 145).
        omega: wheel-side speeds (left, right) at ``t`` (M, 2) (rad/s).
        joint_t: joint-state times (K,), and ``motor_velocity`` (K, 2) as reported.
        start_stamp: the first IMU stamp (s, bag clock).
        source: description for the report.
    """

    t: FloatArray
    accel: FloatArray
    yaw_rate: FloatArray
    omega: FloatArray
    joint_t: FloatArray
    motor_velocity: FloatArray
    start_stamp: float
    source: str
    body_rates: FloatArray | None = None
    transmission_ratio: float = 1.0
    timing: str = "period_mean"
    notes: list[str] = field(default_factory=list)


def wheel_speeds_at(
    imu_t: FloatArray,
    joint_t: FloatArray,
    motor_velocity: FloatArray,
    transmission_ratio: float,
    timing: str,
) -> FloatArray:
    """Wheel-side speeds (M, 2) at the IMU times from the joint reports (module docstring, "Wheel speeds")."""
    wheel = np.asarray(motor_velocity, dtype=float) / transmission_ratio
    jt = np.asarray(joint_t, dtype=float)
    if timing == "period_mean":
        # A report at t_j is the mean over (t_{j-1}, t_j]: it belongs to the middle of that interval.
        period = np.diff(jt)
        mid = jt.copy()
        mid[1:] -= 0.5 * period
        mid[0] -= 0.5 * (period[0] if len(period) else 0.0)
        jt = mid
    elif timing != "instantaneous":
        raise ValueError(f"wheel_speed_timing must be 'period_mean' or 'instantaneous', got {timing!r}")
    return np.column_stack([np.interp(imu_t, jt, wheel[:, i]) for i in range(2)])


def read_skid_steer_bag(
    bag: str | Path,
    *,
    namespace: str = "/skid_steer",
    joints: tuple[str, str] = ("left_motor", "right_motor"),
    transmission_ratio: float = 27.13,
    wheel_speed_timing: str = "period_mean",
) -> SkidSteerBagData:
    """Read ``imu`` and ``joint_states`` of a skid-steer contract bag (CONTRACT.md).

    Raises:
        Sim2RealError: a topic is missing or too short, a joint is absent, a
            value is not finite (the message names topic, field and value).
    """
    from terrain_estimation.bag import read_bag
    from terrain_estimation.tools.estimate import topic_name

    imu_topic = topic_name(namespace, "imu")
    joint_topic = topic_name(namespace, "joint_states")
    present = bag_topics(bag)
    for topic in (imu_topic, joint_topic):
        if topic not in present:
            raise Sim2RealError(
                f"bag {str(bag)!r} has no messages on {topic}, which the skid-steer diagnosis needs "
                f"(namespace {namespace!r}; the bag has {sorted(present)}; pass --namespace if it was recorded "
                f"under another one)"
            )
    imu_rows: list[tuple[float, float, float, float, float]] = []
    rate_rows: list[tuple[float, float]] = []
    rates_measured = True
    joint_rows: list[tuple[float, float, float]] = []
    clock = StampOrigin()  # seconds from the first stamp (epoch stamps lose precision as floats)
    for item in read_bag(bag, [imu_topic, joint_topic]):
        msg = item.msg
        stamp = clock(msg)
        if item.topic == imu_topic:
            a, w = msg.linear_acceleration, msg.angular_velocity
            row = (stamp, float(a.x), float(a.y), float(a.z), float(w.z))
            for name, value in zip(
                (
                    "header.stamp",
                    "linear_acceleration.x",
                    "linear_acceleration.y",
                    "linear_acceleration.z",
                    "angular_velocity.z",
                ),
                row,
                strict=True,
            ):
                if not math.isfinite(value):
                    raise Sim2RealError(f"bag {str(bag)!r}: {imu_topic} field {name} is {value} at stamp {stamp:.6f}")
            imu_rows.append(row)
            cov = msg.angular_velocity_covariance
            rates = (float(w.x), float(w.y))
            if cov[0] < 0.0 or cov[4] < 0.0 or not all(math.isfinite(v) for v in rates):
                rates_measured = False  # REP 145: −1 means "not measured"; one such message disables both
            rate_rows.append(rates)
        else:
            names = list(msg.name)
            velocity = list(msg.velocity)
            values = []
            for joint in joints:
                if joint not in names:
                    raise Sim2RealError(
                        f"bag {str(bag)!r}: {joint_topic} has no joint {joint!r} (names {names}) at stamp {stamp:.6f}"
                    )
                index = names.index(joint)
                if index >= len(velocity):
                    raise Sim2RealError(
                        f"bag {str(bag)!r}: {joint_topic} field velocity has {len(velocity)} values, no entry for "
                        f"joint {joint!r} at stamp {stamp:.6f}"
                    )
                value = float(velocity[index])
                if not math.isfinite(value):
                    raise Sim2RealError(
                        f"bag {str(bag)!r}: {joint_topic} field velocity[{joint}] is {value} at stamp {stamp:.6f}"
                    )
                values.append(value)
            joint_rows.append((stamp, values[0], values[1]))
    for topic, rows in ((imu_topic, imu_rows), (joint_topic, joint_rows)):
        if len(rows) < 10:
            raise Sim2RealError(
                f"bag {str(bag)!r} has {len(rows)} messages on {topic}; the skid-steer diagnosis needs at least 10 "
                f"(namespace {namespace!r}; pass --namespace if the bag was recorded under another one)"
            )
    imu = np.array(imu_rows, dtype=float)
    order = np.argsort(imu[:, 0], kind="stable")
    imu = imu[order]
    body_rates = np.array(rate_rows, dtype=float)[order] if rates_measured else None
    jnt = np.array(joint_rows, dtype=float)
    jnt = jnt[np.argsort(jnt[:, 0], kind="stable")]
    return bag_data_from_arrays(
        imu[:, 0],
        imu[:, 1:4],
        imu[:, 4],
        jnt[:, 0],
        jnt[:, 1:3],
        transmission_ratio=transmission_ratio,
        wheel_speed_timing=wheel_speed_timing,
        source=str(bag),
        stamp_origin=clock.origin,
        body_rates=body_rates,
    )


def bag_data_from_arrays(
    imu_stamp: FloatArray,
    accel: FloatArray,
    yaw_rate: FloatArray,
    joint_stamp: FloatArray,
    motor_velocity: FloatArray,
    *,
    transmission_ratio: float,
    wheel_speed_timing: str = "period_mean",
    source: str = "arrays",
    stamp_origin: float = 0.0,
    body_rates: FloatArray | None = None,
) -> SkidSteerBagData:
    """:class:`SkidSteerBagData` from arrays (stamps in s on any common clock, best relative to
    ``stamp_origin`` on the bag clock); keeps the IMU samples inside the span of the joint reports
    (no extrapolation of the inputs)."""
    imu_stamp = np.asarray(imu_stamp, dtype=float)
    joint_stamp = np.asarray(joint_stamp, dtype=float)
    if np.any(np.diff(imu_stamp) <= 0.0):
        raise Sim2RealError(f"{source}: IMU stamps are not strictly increasing (duplicate stamps)")
    if np.any(np.diff(joint_stamp) <= 0.0):
        raise Sim2RealError(f"{source}: joint_states stamps are not strictly increasing (duplicate stamps)")
    lo, hi = joint_stamp[0], joint_stamp[-1]
    keep = (imu_stamp >= lo - 1e-9) & (imu_stamp <= hi + 1e-9)
    if int(np.sum(keep)) < 10:
        raise Sim2RealError(
            f"{source}: only {int(np.sum(keep))} IMU samples lie within the joint_states span "
            f"[{lo:.3f}, {hi:.3f}] s; the stamps of imu and joint_states do not overlap"
        )
    t_abs = imu_stamp[keep]
    start = float(t_abs[0])
    omega = wheel_speeds_at(t_abs - start, joint_stamp - start, motor_velocity, transmission_ratio, wheel_speed_timing)
    return SkidSteerBagData(
        t=t_abs - start,
        accel=np.asarray(accel, dtype=float)[keep],
        yaw_rate=np.asarray(yaw_rate, dtype=float)[keep],
        omega=omega,
        joint_t=joint_stamp - start,
        motor_velocity=np.asarray(motor_velocity, dtype=float),
        start_stamp=start + stamp_origin,
        source=source,
        body_rates=None if body_rates is None else np.asarray(body_rates, dtype=float)[keep],
        transmission_ratio=transmission_ratio,
        timing=wheel_speed_timing,
    )
