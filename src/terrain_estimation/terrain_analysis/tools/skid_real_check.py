"""The skid-steer estimator on real bags: divergence, limits, stationary speed, yaw rate against the gyro (issue 20).

``python -m terrain_analysis.tools.skid_real_check BAGS_DIR [--config config/husky.yaml] [--namespace /husky]
[--out FILE]``

Runs the estimator's ROS adapter (what the node runs) over every rosbag2
directory under ``BAGS_DIR`` (e.g. the BorealTC runs imported by
``vehicle_sim.tools.borealtc``) and checks, per run, what a user of a real
vehicle can check without a ground truth:

* no divergence, limit reset or recovery (the estimator's counters);
* every published estimate inside the vehicle's stated limits
  (``vehicle.max_speed``, ``vehicle.max_yaw_rate``);
* at rest, the estimated planar speed below :data:`REST_SPEED` (0.05 m/s).
  "At rest" needs both witnesses: every wheel's rim speed of the last second
  below the estimator's ``zupt.wheel_speed`` (0.01 m/s) and the accelerometers
  quiet over that second (x and y spread below :data:`REST_ACCEL_STD`; the
  BorealTC Husky reads 0.12-0.14 m/s² at rest, and 2-4.5 m/s² where its
  encoders read zero while the body moves, e.g. ASPHALT run_03 at 86 s);
* the yaw rate consistent with the gyro within its covariance: the share of
  ``|r̂ − ω_z| ≤ 2 sqrt(σ_r² + R_gyro)`` (95 % when consistent) and the mean
  of the squared normalised difference (1 when consistent).

Exit status 1 when a run breaks the first three (a finding), 2 when the
directory holds no bag.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from terrain_estimation.cli import EXIT_FINDING, EXIT_OK, InputError, cli_main

__all__ = ["REST_ACCEL_STD", "REST_SPEED", "RunCheck", "check_bag", "main"]

#: [m/s] largest planar speed estimate accepted while the vehicle is at rest.
REST_SPEED = 0.05
#: [m/s²] the accelerometers (x, y) count as quiet below this spread over the last second.
REST_ACCEL_STD = 0.5


@dataclass(frozen=True)
class RunCheck:
    """The figures of one bag (module docstring)."""

    bag: str
    imu_samples: int
    estimates: int
    divergences: int
    limit_resets: int
    recoveries: int
    max_speed: float
    max_yaw_rate: float
    rest_estimates: int
    max_rest_speed: float
    yaw_within_2sigma: float
    yaw_normalised: float
    zero_velocity_updates: int
    seconds: float

    def failures(self, speed_limit: float, yaw_limit: float) -> list[str]:
        """What this run breaks (empty: nothing)."""
        out = []
        if self.divergences or self.limit_resets or self.recoveries:
            out.append(
                f"{self.divergences} divergences, {self.limit_resets} limit resets, {self.recoveries} recoveries"
            )
        if self.max_speed > speed_limit or self.max_yaw_rate > yaw_limit:
            out.append(f"beyond the limits: {self.max_speed:.3f} m/s, {self.max_yaw_rate:.3f} rad/s")
        if self.rest_estimates and self.max_rest_speed >= REST_SPEED:
            out.append(f"at rest it reads {self.max_rest_speed:.3f} m/s (>= {REST_SPEED})")
        return out


def check_bag(bag: Path, values: dict[str, object], namespace: str) -> RunCheck:
    """Run the estimator over ``bag`` with parameter ``values`` and measure it (module docstring)."""
    from terrain_estimation.bag import read_bag
    from terrain_estimation.vehicles import get_vehicle

    entry = get_vehicle("skid_steer")
    adapter = entry.make_adapter(dict(values), namespace)
    ns = namespace.rstrip("/")
    topics = {f"{ns}/{s.topic}": s.key for s in adapter.inputs}
    states = []
    gyro: dict[int, float] = {}
    accel: list[tuple[float, float, float]] = []
    wheels: list[tuple[float, float]] = []
    started = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for item in read_bag(bag, list(topics)):
            key = topics[item.topic]
            stamp = item.msg.header.stamp
            t = stamp.sec + 1e-9 * stamp.nanosec
            if key == "imu":
                gyro[stamp.sec * 1_000_000_000 + stamp.nanosec] = float(item.msg.angular_velocity.z)
                accel.append((t, float(item.msg.linear_acceleration.x), float(item.msg.linear_acceleration.y)))
            elif key == "joint_states":
                wheels.append((t, max((abs(float(v)) for v in item.msg.velocity), default=math.nan)))
            states += [m for k, m in adapter.handle(key, item.msg) if k == "state"]
    seconds = time.process_time() - started
    est = adapter.estimator
    c = est.counters
    if not states:
        raise InputError(f"{bag}: the estimator produced no estimate ({c})")
    stamps = np.array([s.header.stamp.sec * 1_000_000_000 + s.header.stamp.nanosec for s in states], dtype=np.int64)
    t = stamps * 1e-9
    v = np.array([[s.vx, s.vy, s.yaw_rate, s.yaw_rate_variance] for s in states])
    speed = np.hypot(v[:, 0], v[:, 1])
    g = np.array([gyro.get(int(k), math.nan) for k in stamps])
    have = np.isfinite(g)
    r_gyro = float(values["filter.r0_diag"][2])  # type: ignore[index]
    z = (v[have, 2] - g[have]) / np.sqrt(v[have, 3] + r_gyro)
    # Wheels still: every motor speed below the rim speed zupt.wheel_speed (the estimator's own threshold).
    still_motor = (
        float(values["zupt.wheel_speed"])  # type: ignore[arg-type]
        / float(values["vehicle.wheel_radius"])  # type: ignore[arg-type]
        * float(values["vehicle.transmission_ratio"])  # type: ignore[arg-type]
    )
    wt = np.array([w[0] for w in wheels])
    wv = np.array([w[1] for w in wheels])
    acc = np.array(accel)
    rest = np.zeros(len(t), dtype=bool)
    for i, x in enumerate(t):
        w = (wt > x - 1.0) & (wt <= x)
        if np.count_nonzero(w) < 3 or not np.all(wv[w] < still_motor):
            continue
        a = (acc[:, 0] > x - 1.0) & (acc[:, 0] <= x)
        rest[i] = np.count_nonzero(a) >= 10 and max(np.std(acc[a, 1]), np.std(acc[a, 2])) < REST_ACCEL_STD
    return RunCheck(
        bag=str(bag),
        imu_samples=int(c.imu_samples),
        estimates=len(states),
        divergences=int(c.divergences),
        limit_resets=int(c.limit_resets),
        recoveries=int(c.recoveries),
        max_speed=float(speed.max()),
        max_yaw_rate=float(np.abs(v[:, 2]).max()),
        rest_estimates=int(rest.sum()),
        max_rest_speed=float(speed[rest].max()) if rest.any() else math.nan,
        yaw_within_2sigma=float(np.mean(np.abs(z) <= 2.0)) if z.size else math.nan,
        yaw_normalised=float(np.mean(z**2)) if z.size else math.nan,
        zero_velocity_updates=int(c.zero_velocity_updates),
        seconds=seconds,
    )


@cli_main("skid_real_check")
def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    from terrain_analysis.reporting import git_revision, write_section
    from terrain_estimation.tools.estimate import config_values
    from terrain_estimation.vehicles import get_vehicle

    parser = argparse.ArgumentParser(prog="skid_real_check", description=(__doc__ or "").splitlines()[0])
    parser.add_argument("bags", help="directory holding rosbag2 directories (searched recursively)")
    parser.add_argument("--config", default="config/husky.yaml", help="parameter file (default config/husky.yaml)")
    parser.add_argument("--namespace", default="/husky", help="namespace of the topics (default /husky)")
    parser.add_argument("--out", default=None, help="Markdown file to write the section 'real-runs' into")
    args = parser.parse_args(argv)
    root = Path(args.bags)
    bags = sorted(p.parent for p in root.rglob("metadata.yaml")) if root.is_dir() else []
    if not bags:
        raise InputError(f"{root}: no rosbag2 directory (metadata.yaml) found")
    values = dict(config_values(get_vehicle("skid_steer"), args.config))
    speed_limit, yaw_limit = float(values["vehicle.max_speed"]), float(values["vehicle.max_yaw_rate"])
    lines = [
        f"| run | IMU samples | estimates | divergences, limit resets, recoveries | max speed (m/s, limit "
        f"{speed_limit:g}) | max yaw rate (rad/s, limit {yaw_limit:g}) | estimates at rest | max speed at rest "
        "(m/s) | zero-velocity updates | yaw rate within 2 sigma of the gyro | mean z^2 | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    broken = 0
    for i, bag in enumerate(bags):
        r = check_bag(bag, values, args.namespace)
        fails = r.failures(speed_limit, yaw_limit)
        broken += bool(fails)
        name = str(bag.relative_to(root))
        print(f"[{i + 1}/{len(bags)}] {name}: {'; '.join(fails) or 'ok'} ({r.seconds:.1f} s CPU)", file=sys.stderr)
        lines.append(
            f"| {name} | {r.imu_samples} | {r.estimates} | {r.divergences}, {r.limit_resets}, {r.recoveries} | "
            f"{r.max_speed:.3f} | {r.max_yaw_rate:.3f} | {r.rest_estimates} | "
            f"{f'{r.max_rest_speed:.4f}' if r.rest_estimates else '-'} | "
            f"{r.zero_velocity_updates} | {100 * r.yaw_within_2sigma:.1f} % | {r.yaw_normalised:.2f} | "
            f"{'; '.join(fails) or 'ok'} |"
        )
    text = (
        f"Produced by `python -m terrain_analysis.tools.skid_real_check {args.bags} --config {args.config}` at "
        f"revision {git_revision()}: {len(bags) - broken} of {len(bags)} runs hold. At rest = every rim speed of "
        f"the last second below zupt.wheel_speed and the accelerometers' x, y spread below {REST_ACCEL_STD} "
        "m/s2; z = (yaw rate - gyro) / sqrt(sigma_r^2 + R_gyro).\n\n" + "\n".join(lines)
    )
    print(text)
    if args.out:
        write_section(args.out, "real-runs", text)
    return EXIT_FINDING if broken else EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
