"""The rover's sensor streams on one time grid, from a contract bag or a simulator run (rover replay)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import StampOrigin
from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.bag import bag_topics

__all__ = ["WHEELS", "RoverSeries", "read_rover_bag", "series_from_run"]

FloatArray = NDArray[np.float64]

#: The wheels in the order of every per-wheel array (the load-cell topics ``wheel/<name>/load``).
WHEELS = ("rear", "middle", "front")


@dataclass(frozen=True)
class RoverSeries:
    """The contract's rover sensor streams on one time grid (N samples).

    Attributes:
        t: sample times (s from the first sample), increasing.
        accel: body specific force (x, z) (m/s²), (N, 2).
        gyro: pitch rate (rad/s), (N,).
        bogie: bogie angle q1 (rad), (N,).
        wheel_angle: q2..q4 (rear, middle, front) (rad), (N, 3).
        effort: applied wheel torques (N·m), (N, 3).
        speed: velocimeter forward speed (m/s), (N,).
        load_axial: F_L per wheel (N), (N, 3).
        load_perpendicular: F_⊥ per wheel (N), (N, 3).
    """

    t: FloatArray
    accel: FloatArray
    gyro: FloatArray
    bogie: FloatArray
    wheel_angle: FloatArray
    effort: FloatArray
    speed: FloatArray
    load_axial: FloatArray
    load_perpendicular: FloatArray


def series_from_run(run: Any) -> RoverSeries:
    """The sensor streams of a :class:`vehicle_sim.plants.rover.RoverRun` (tests; no bag needed)."""
    s = run.sensors
    return RoverSeries(
        t=np.asarray(run.time, dtype=float) - float(run.time[0]),
        accel=np.asarray(s.acceleration, dtype=float),
        gyro=np.asarray(s.pitch_rate, dtype=float),
        bogie=np.asarray(s.bogie_angle, dtype=float),
        wheel_angle=np.asarray(s.wheel_angle, dtype=float),
        effort=np.asarray(s.effort, dtype=float),
        speed=np.asarray(s.forward_velocity, dtype=float),
        load_axial=np.asarray(s.load_axial, dtype=float),
        load_perpendicular=np.asarray(s.load_perpendicular, dtype=float),
    )


def read_rover_bag(
    bag: str | Path,
    *,
    namespace: str = "/rover",
    joints: Mapping[str, str] | None = None,
) -> RoverSeries:
    """Read the contract's rover topics of ``bag`` onto the joint_states time grid.

    Other streams are linearly interpolated to the joint_states stamps (on a
    simulator bag all stamps coincide). ``ground_truth/*`` is never read.

    Raises:
        Sim2RealError: a topic is missing or too short, a joint is missing, a
            value is not finite (the message names topic, field and value).
    """
    from terrain_estimation.bag import read_bag
    from terrain_estimation.tools.estimate import topic_name

    names = dict(joints or {"bogie": "bogie", "rear": "rear_wheel", "middle": "middle_wheel", "front": "front_wheel"})
    topics = {
        "imu": topic_name(namespace, "imu"),
        "joint_states": topic_name(namespace, "joint_states"),
        "velocimeter": topic_name(namespace, "velocimeter"),
        **{f"load_{w}": topic_name(namespace, f"wheel/{w}/load") for w in WHEELS},
    }
    by_topic = {v: k for k, v in topics.items()}
    present = bag_topics(bag)
    missing = [t for t in topics.values() if t not in present]
    if missing:
        raise Sim2RealError(
            f"bag {str(bag)!r} has no messages on {', '.join(missing)}, which the rover replay needs "
            f"(namespace {namespace!r}; pass --namespace if the bag was recorded under another one; "
            f"the bag has {', '.join(sorted(present)) or 'no topics'})"
        )
    rows: dict[str, list[tuple[float, ...]]] = {k: [] for k in topics}
    order = [names["bogie"], names["rear"], names["middle"], names["front"]]
    clock = StampOrigin()  # seconds from the first stamp (epoch stamps lose precision as floats)
    for item in read_bag(bag, list(by_topic)):
        key = by_topic[item.topic]
        msg = item.msg
        t = clock(msg)
        if key == "imu":
            a, w = msg.linear_acceleration, msg.angular_velocity
            rows[key].append((t, float(a.x), float(a.z), float(w.y)))
        elif key == "joint_states":
            joint_names = list(msg.name)
            missing_joints = [n for n in order if n not in joint_names]
            if missing_joints:
                raise Sim2RealError(
                    f"{item.topic}: joint(s) {missing_joints} missing (message has {joint_names}); "
                    "set joints.* in the config"
                )
            idx = [joint_names.index(n) for n in order]
            if len(msg.position) < len(joint_names):
                raise Sim2RealError(
                    f"{item.topic}: position has {len(msg.position)} values for {len(joint_names)} joints"
                )
            effort = list(msg.effort) if len(msg.effort) >= len(joint_names) else None
            if effort is None:
                raise Sim2RealError(
                    f"{item.topic}: field effort has {len(msg.effort)} values for {len(joint_names)} joints; "
                    "the rover replay needs the applied wheel torques"
                )
            rows[key].append((t, *(float(msg.position[i]) for i in idx), *(float(effort[i]) for i in idx[1:])))
        elif key == "velocimeter":
            rows[key].append((t, float(msg.twist.linear.x)))
        else:
            f = msg.wrench.force
            rows[key].append((t, float(f.z), float(f.x)))
    fields = {
        "imu": ("linear_acceleration.x", "linear_acceleration.z", "angular_velocity.y"),
        "joint_states": (
            "position[bogie]",
            "position[rear]",
            "position[middle]",
            "position[front]",
            "effort[rear]",
            "effort[middle]",
            "effort[front]",
        ),
        "velocimeter": ("twist.linear.x",),
        **{f"load_{w}": ("wrench.force.z", "wrench.force.x") for w in WHEELS},
    }
    arrays: dict[str, FloatArray] = {}
    for key, topic in topics.items():
        if len(rows[key]) < 10:
            raise Sim2RealError(
                f"bag {str(bag)!r} has {len(rows[key])} messages on {topic}; the rover replay needs it "
                f"(namespace {namespace!r}; pass --namespace if the bag was recorded under another one)"
            )
        a = np.array(rows[key], dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        bad = ~np.isfinite(a)
        if np.any(bad):
            r, c = np.argwhere(bad)[0]
            what = "header.stamp" if c == 0 else fields[key][c - 1]
            raise Sim2RealError(f"{topic}: field {what} is {float(a[r, c])} at message {r} (stamp {a[r, 0]:.9f} s)")
        keep = np.concatenate([[True], np.diff(a[:, 0]) > 0.0])
        arrays[key] = a[keep]
    grid = arrays["joint_states"][:, 0]
    t0 = float(grid[0])

    def on_grid(key: str, column: int) -> FloatArray:
        a = arrays[key]
        return np.interp(grid, a[:, 0], a[:, column])

    js = arrays["joint_states"]
    return RoverSeries(
        t=grid - t0,
        accel=np.column_stack([on_grid("imu", 1), on_grid("imu", 2)]),
        gyro=on_grid("imu", 3),
        bogie=js[:, 1].copy(),
        wheel_angle=js[:, 2:5].copy(),
        effort=js[:, 5:8].copy(),
        speed=on_grid("velocimeter", 1),
        load_axial=np.column_stack([on_grid(f"load_{w}", 1) for w in WHEELS]),
        load_perpendicular=np.column_stack([on_grid(f"load_{w}", 2) for w in WHEELS]),
    )
