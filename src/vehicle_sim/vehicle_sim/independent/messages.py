"""Contract messages and bags written with rosbags' own typestore (no rclpy, no project bag code).

A bag is written to ``<path>.partial`` and renamed when complete, so an
interrupted run leaves no half bag under the final name. Storage: MCAP,
rosbag2 metadata version 9 (the message definitions are stored with each
connection, so a reader needs no project code).
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

__all__ = ["BagOut", "imu", "joint_state", "point_stamped", "topic"]

_STORE = get_typestore(Stores.ROS2_JAZZY)
_T = _STORE.types
_Header = _T["std_msgs/msg/Header"]
_Time = _T["builtin_interfaces/msg/Time"]
_Vector3 = _T["geometry_msgs/msg/Vector3"]
_Point = _T["geometry_msgs/msg/Point"]
_Quaternion = _T["geometry_msgs/msg/Quaternion"]
IMU = "sensor_msgs/msg/Imu"
JOINT_STATE = "sensor_msgs/msg/JointState"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"


def topic(namespace: str, name: str) -> str:
    """``/<namespace>/<name>`` (CONTRACT.md: topics are relative to the vehicle's namespace)."""
    ns = namespace.strip("/")
    return f"/{ns}/{name}" if ns else f"/{name}"


def _header(stamp_ns: int, frame: str) -> Any:
    stamp = _Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))
    return _Header(stamp=stamp, frame_id=frame)


def _cov(diagonal: Sequence[float] | None) -> np.ndarray:
    """A 3×3 row-major covariance: the diagonal, or ``[-1, 0, …]`` (REP 145: not measured)."""
    out = np.zeros(9)
    if diagonal is None:
        out[0] = -1.0
    else:
        out[[0, 4, 8]] = diagonal
    return out


def imu(
    stamp_ns: int,
    frame: str,
    accel: Sequence[float],
    accel_variance: Sequence[float],
    gyro: Sequence[float] | None = None,
    gyro_variance: Sequence[float] | None = None,
) -> Any:
    """sensor_msgs/Imu: specific force (m/s², gravity included) and, if given, angular velocity (rad/s).

    Orientation is never measured (covariance[0] = -1); the angular velocity
    is marked not measured when ``gyro`` is None. An accelerometer axis with
    variance 0 is an axis the sensor does not have (its value 0).
    """
    return _T[IMU](
        header=_header(stamp_ns, frame),
        orientation=_Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=_cov(None),
        angular_velocity=_Vector3(*(float(v) for v in (gyro if gyro is not None else (0.0, 0.0, 0.0)))),
        angular_velocity_covariance=_cov(gyro_variance if gyro is not None else None),
        linear_acceleration=_Vector3(*(float(v) for v in accel)),
        linear_acceleration_covariance=_cov(accel_variance),
    )


def joint_state(
    stamp_ns: int,
    frame: str,
    names: Sequence[str],
    position: Sequence[float],
    velocity: Sequence[float],
    effort: Sequence[float] = (),
) -> Any:
    """sensor_msgs/JointState."""
    return _T[JOINT_STATE](
        header=_header(stamp_ns, frame),
        name=list(names),
        position=np.asarray(position, dtype=np.float64),
        velocity=np.asarray(velocity, dtype=np.float64),
        effort=np.asarray(effort, dtype=np.float64),
    )


def point_stamped(stamp_ns: int, frame: str, x: float, z: float) -> Any:
    """geometry_msgs/PointStamped (the road profile: x distance travelled, z elevation)."""
    return _T[POINT_STAMPED](header=_header(stamp_ns, frame), point=_Point(x=float(x), y=0.0, z=float(z)))


class BagOut:
    """A rosbag2 (MCAP) bag written to ``<path>.partial`` and renamed to ``path`` on success.

    ``path`` must not exist (the suite writer removes an old suite first).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._tmp = self.path.with_name(self.path.name + ".partial")
        self._writer: Writer | None = None
        self._connections: dict[str, Any] = {}
        self.count = 0

    def __enter__(self) -> BagOut:
        if self.path.exists():
            raise FileExistsError(f"bag {str(self.path)!r} exists: not overwritten")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(self._tmp, ignore_errors=True)
        self._writer = Writer(self._tmp, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        return self

    def write(self, name: str, msgtype: str, msg: Any, log_time_ns: int) -> None:
        """Append ``msg`` (a typestore message of ``msgtype``) on topic ``name``."""
        if self._writer is None:
            raise RuntimeError("BagOut is used outside its with-block")
        conn = self._connections.get(name)
        if conn is None:
            conn = self._connections[name] = self._writer.add_connection(name, msgtype, typestore=_STORE)
        self._writer.write(conn, int(log_time_ns), _STORE.serialize_cdr(msg, msgtype))
        self.count += 1

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        writer, self._writer = self._writer, None
        if exc_type is not None:
            del writer
            shutil.rmtree(self._tmp, ignore_errors=True)
            return
        assert writer is not None
        writer.close()
        storage = self._tmp / f"{self._tmp.name}.mcap"
        if storage.exists():  # rosbags names the file after the directory: name it after the final one
            storage.rename(self._tmp / f"{self.path.name}.mcap")
            meta = self._tmp / "metadata.yaml"
            meta.write_text(meta.read_text().replace(f"{self._tmp.name}.mcap", f"{self.path.name}.mcap"))
        self._tmp.rename(self.path)
