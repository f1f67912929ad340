"""BorealTC Husky runs → contract bags (CONTRACT.md, skid-steer topics).

``python -m vehicle_sim.tools.borealtc --data /work/shared/real_data/borealtc --out DIR [--namespace /husky]``

BorealTC (LaRocque et al. 2024, CC0) recorded a Clearpath Husky A200 on real
terrain. Each run is two CSV files per terrain folder:

* ``imu_XX.csv``: ``time, wx, wy, wz, ax, ay, az`` at 100 Hz (rad/s, m/s²,
  gravity included; axes as REP 103: the yaw rate follows the right-minus-left
  wheel speed with a positive sign and a vehicle at rest reads az ≈ +9.8);
* ``pro_XX.csv``: ``time, curL, curR, velL, velR`` at ≈ 6.5 Hz: motor
  currents (A) and side wheel speeds (m/s, rim speed R ω).

Each run becomes ``DIR/<TERRAIN>/run_XX/`` (rosbag2, MCAP, through
:class:`terrain_estimation.bag.AtomicBagWriter`), with the messages a robot
following the contract records:

* ``<ns>/imu`` (sensor_msgs/Imu, every IMU row): ``linear_acceleration``,
  ``angular_velocity``; orientation not measured (covariance[0] = −1);
  covariances unknown (0).
* ``<ns>/joint_states`` (sensor_msgs/JointState, every ``pro`` row): joints
  ``left_motor``, ``right_motor``; ``velocity`` = motor side
  ``v / R × i_g`` (rad/s) with the config's wheel radius R and transmission
  ratio i_g (``config/husky.yaml``); ``position`` = its trapezoidal integral
  from 0 (motor side, rad); ``effort`` left empty: the CSV gives motor
  *currents* and the contract's effort is a torque, which needs the motor's
  torque constant (not in the data set).

Stamps: the CSV time (s from the run start, the same clock for both files)
plus ``--start-stamp`` (default 0), whole nanoseconds; log time = stamp.
A bad CSV (missing column, non-numeric or non-finite value, time not
increasing) is refused with the file, row, column and value.

Outputs: every run's bag path is checked before any is written. An existing
``run_XX`` is refused (exit 2) unless ``--overwrite``, which replaces only a
previous bag there; nothing else under ``DIR`` is ever touched, and ``DIR``
may not be inside the data folder (:mod:`terrain_estimation.outputs`).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.cli import EXIT_OK, InputError, run_cli

__all__ = ["BorealRun", "CsvError", "convert_run", "find_runs", "main", "read_csv", "read_husky_config", "run_path"]

FloatArray = NDArray[np.float64]

IMU_COLUMNS = ("time", "wx", "wy", "wz", "ax", "ay", "az")
PRO_COLUMNS = ("time", "curL", "curR", "velL", "velR")


class CsvError(ValueError):
    """A BorealTC CSV file that cannot be converted; the message names file, row, column and value."""


@dataclass(frozen=True)
class BorealRun:
    """One run: terrain, index and its two files."""

    terrain: str
    index: str
    imu: Path
    pro: Path

    @property
    def name(self) -> str:
        return f"{self.terrain}/run_{self.index}"


def read_csv(path: Path, columns: Sequence[str]) -> dict[str, FloatArray]:
    """The named columns of a CSV file as float arrays (time strictly increasing).

    Raises:
        CsvError: file missing, a column missing, a value not a finite number,
            fewer than 2 rows, or time not strictly increasing.
    """
    try:
        with open(path, newline="") as handle:
            reader = csv.reader(handle)
            header = next(reader, None)
            if header is None:
                raise CsvError(f"{path}: empty file (expected header {', '.join(columns)})")
            header = [h.strip() for h in header]
            missing = [c for c in columns if c not in header]
            if missing:
                raise CsvError(f"{path}: column(s) {missing} missing; header is {header}")
            index = [header.index(c) for c in columns]
            rows: list[list[float]] = []
            for line_no, row in enumerate(reader, start=2):
                if not row or all(not cell.strip() for cell in row):
                    continue
                values = []
                for column, i in zip(columns, index, strict=True):
                    cell = row[i].strip() if i < len(row) else ""
                    try:
                        value = float(cell)
                    except ValueError:
                        raise CsvError(
                            f"{path}: row {line_no}, column {column!r}: value {cell!r} is not a number"
                        ) from None
                    if not math.isfinite(value):
                        raise CsvError(f"{path}: row {line_no}, column {column!r}: value {cell!r} is not finite")
                    values.append(value)
                rows.append(values)
    except FileNotFoundError:
        raise CsvError(f"{path}: file does not exist") from None
    if len(rows) < 2:
        raise CsvError(f"{path}: {len(rows)} data row(s); at least 2 needed")
    data = np.array(rows, dtype=float)
    out = {c: data[:, j] for j, c in enumerate(columns)}
    dt = np.diff(out["time"])
    if np.any(dt <= 0.0):
        k = int(np.flatnonzero(dt <= 0.0)[0])
        raise CsvError(
            f"{path}: row {k + 3}, column 'time': value {float(out['time'][k + 1])!r} does not increase "
            f"(previous {float(out['time'][k])!r})"
        )
    return out


def read_husky_config(config: str | Path | None = None) -> dict[str, float]:
    """Wheel radius and transmission ratio (and the rest of ``vehicle.*``) from ``config/husky.yaml``."""
    from terrain_estimation.params import default_config_path, load_parameter_file

    values = load_parameter_file(Path(config) if config is not None else default_config_path("husky"))
    out: dict[str, float] = {}
    for key, value in values.items():
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            out[key] = float(value)
    for needed in ("vehicle.wheel_radius", "vehicle.transmission_ratio"):
        if needed not in out or not out[needed] > 0.0:
            raise ValueError(f"husky config: {needed} must be a positive number, got {values.get(needed)!r}")
    return out


def find_runs(data: str | Path) -> list[BorealRun]:
    """Every ``<TERRAIN>/imu_XX.csv`` with its ``pro_XX.csv``, sorted by terrain and index."""
    root = Path(data)
    if not root.is_dir():
        raise CsvError(f"{root}: data directory does not exist")
    runs = []
    for imu in sorted(root.glob("*/imu_*.csv")):
        index = imu.stem.split("_", 1)[1]
        pro = imu.with_name(f"pro_{index}.csv")
        if not pro.exists():
            raise CsvError(f"{imu}: no matching {pro.name}")
        runs.append(BorealRun(imu.parent.name, index, imu, pro))
    if not runs:
        raise CsvError(f"{root}: no <TERRAIN>/imu_XX.csv files")
    return runs


def run_path(run: BorealRun, out: str | Path) -> Path:
    """Where :func:`convert_run` writes ``run``'s bag: ``out/<TERRAIN>/run_XX``."""
    return Path(out) / run.terrain / f"run_{run.index}"


def convert_run(
    run: BorealRun,
    out: str | Path,
    *,
    namespace: str = "/husky",
    wheel_radius: float,
    transmission_ratio: float,
    start_stamp: float = 0.0,
    frame_prefix: str = "husky",
    overwrite: bool = False,
    inputs: Sequence[str | Path] = (),
) -> Path:
    """Write one run's contract bag to ``out/<TERRAIN>/run_XX``; returns its path.

    ``overwrite`` and ``inputs`` (besides the run's two CSV files) go to
    :class:`~terrain_estimation.bag.AtomicBagWriter`: an existing bag is
    replaced only with ``overwrite``, anything else never.
    """
    from sensor_msgs.msg import Imu, JointState

    from terrain_estimation.bag import AtomicBagWriter
    from terrain_estimation.ros.time import ns_to_stamp
    from terrain_estimation.tools.estimate import topic_name

    imu = read_csv(run.imu, IMU_COLUMNS)
    pro = read_csv(run.pro, PRO_COLUMNS)
    to_motor = transmission_ratio / wheel_radius
    motor_velocity = np.column_stack([pro["velL"], pro["velR"]]) * to_motor
    dt = np.diff(pro["time"])[:, None]
    motor_position = np.vstack([np.zeros((1, 2)), np.cumsum(0.5 * (motor_velocity[1:] + motor_velocity[:-1]) * dt, 0)])
    imu_topic = topic_name(namespace, "imu")
    joint_topic = topic_name(namespace, "joint_states")
    offset_ns = int(round(start_stamp * 1e9))
    messages: list[tuple[int, str, object]] = []
    for k in range(len(imu["time"])):
        msg = Imu()
        stamp = offset_ns + int(round(imu["time"][k] * 1e9))
        msg.header.stamp = ns_to_stamp(stamp)
        msg.header.frame_id = f"{frame_prefix}/imu_link"
        msg.orientation_covariance[0] = -1.0
        msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (
            float(imu["wx"][k]),
            float(imu["wy"][k]),
            float(imu["wz"][k]),
        )
        msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = (
            float(imu["ax"][k]),
            float(imu["ay"][k]),
            float(imu["az"][k]),
        )
        messages.append((stamp, imu_topic, msg))
    for k in range(len(pro["time"])):
        joints = JointState()
        stamp = offset_ns + int(round(pro["time"][k] * 1e9))
        joints.header.stamp = ns_to_stamp(stamp)
        joints.header.frame_id = f"{frame_prefix}/base_link"
        joints.name = ["left_motor", "right_motor"]
        joints.position = [float(v) for v in motor_position[k]]
        joints.velocity = [float(v) for v in motor_velocity[k]]
        messages.append((stamp, joint_topic, joints))
    messages.sort(key=lambda m: m[0])
    path = run_path(run, out)
    with AtomicBagWriter(path, overwrite=overwrite, inputs=[run.imu, run.pro, *inputs]) as writer:
        for stamp, topic, msg in messages:
            writer.write(topic, msg, stamp)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m vehicle_sim.tools.borealtc", description=(__doc__ or "").splitlines()[0]
    )
    parser.add_argument("--data", required=True, help="BorealTC folder with <TERRAIN>/imu_XX.csv, pro_XX.csv")
    parser.add_argument("--out", required=True, help="output directory (one bag per run: <TERRAIN>/run_XX)")
    parser.add_argument("--namespace", default="/husky", help="namespace of the topics (default /husky)")
    parser.add_argument("--config", help="Husky config (default config/husky.yaml): wheel radius, transmission ratio")
    parser.add_argument("--start-stamp", type=float, default=0.0, help="stamp of CSV time 0 (s, default 0)")
    parser.add_argument("--terrain", action="append", help="only these terrains (folder names)")
    parser.add_argument("--overwrite", action="store_true", help="replace previous run bags (never other files)")
    args = parser.parse_args(argv)

    def body() -> int:
        from terrain_estimation.outputs import check_output_path

        cfg = read_husky_config(args.config)
        runs = [r for r in find_runs(args.data) if not args.terrain or r.terrain in args.terrain]
        inputs = [args.data] + ([args.config] if args.config else [])
        for run in runs:  # every output checked before the first is written
            check_output_path(run_path(run, args.out), overwrite=args.overwrite, inputs=inputs)
        try:
            for run in runs:
                path = convert_run(
                    run,
                    args.out,
                    namespace=args.namespace,
                    wheel_radius=cfg["vehicle.wheel_radius"],
                    transmission_ratio=cfg["vehicle.transmission_ratio"],
                    start_stamp=args.start_stamp,
                    overwrite=args.overwrite,
                    inputs=inputs,
                )
                print(f"{run.name}: {path}", file=sys.stderr)
        except OSError as exc:  # an output directory that cannot be created or written
            raise InputError(f"cannot write under {args.out!r}: {exc}") from exc
        print(f"wrote {len(runs)} bags to {args.out}")
        return EXIT_OK

    return run_cli("borealtc", body, interrupted="interrupted; the bags written so far are complete, no partial one")


if __name__ == "__main__":
    sys.exit(main())
