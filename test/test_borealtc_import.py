"""BorealTC Husky importer: CSV → contract bag, exact conversion, clear errors; real data when present."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from terrain_estimation.bag import read_bag
from vehicle_sim.tools.borealtc import BorealRun, CsvError, convert_run, find_runs, read_csv, read_husky_config

REAL = Path(__file__).resolve().parents[2] / "shared" / "real_data" / "borealtc"


def _write_run(folder: Path, index: str = "00", n_imu: int = 300, n_pro: int = 20) -> BorealRun:
    folder.mkdir(parents=True, exist_ok=True)
    t_imu = np.arange(n_imu) * 0.01
    imu = folder / f"imu_{index}.csv"
    lines = ["time,wx,wy,wz,ax,ay,az"]
    lines += [f"{t},0.001,-0.002,{0.1 * np.sin(t)},0.05,{0.02 * t},9.81" for t in t_imu]
    imu.write_text("\n".join(lines) + "\n")
    t_pro = np.arange(n_pro) / 6.5
    pro = folder / f"pro_{index}.csv"
    lines = ["time,curL,curR,velL,velR"] + [f"{t},1.0,2.0,{0.2 + 0.01 * k},{0.3}" for k, t in enumerate(t_pro)]
    pro.write_text("\n".join(lines) + "\n")
    return BorealRun(folder.name, index, imu, pro)


def test_conversion_is_exact(tmp_path):
    run = _write_run(tmp_path / "ASPHALT")
    cfg = read_husky_config()
    radius, ratio = cfg["vehicle.wheel_radius"], cfg["vehicle.transmission_ratio"]
    bag = convert_run(run, tmp_path / "out", wheel_radius=radius, transmission_ratio=ratio, start_stamp=1.7e9)
    imu, joints = [], []
    for item in read_bag(bag):
        (imu if item.topic == "/husky/imu" else joints).append(item)
        assert item.log_time_ns == item.msg.header.stamp.sec * 10**9 + item.msg.header.stamp.nanosec
    assert len(imu) == 300 and len(joints) == 20
    assert imu[5].msg.linear_acceleration.z == 9.81
    assert imu[5].msg.angular_velocity.z == pytest.approx(0.1 * np.sin(0.05))
    assert imu[0].msg.orientation_covariance[0] == -1.0
    j = joints[3].msg
    assert list(j.name) == ["left_motor", "right_motor"]
    # Motor side = wheel speed (m/s) / R × i_g; the estimator's wheel = motor / i_g gives back v / R.
    assert j.velocity[0] / ratio * radius == pytest.approx(0.23)
    assert j.velocity[1] / ratio * radius == pytest.approx(0.3)
    assert len(j.effort) == 0  # currents are not torques
    assert j.position[1] == pytest.approx(0.3 / radius * ratio * 3 / 6.5)
    assert joints[3].log_time_ns == pytest.approx(1.7e18 + 3 / 6.5 * 1e9, abs=1)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("time,curL,curR,velL\n0,1,1,0.1\n0.1,1,1,0.1\n", r"column\(s\) \['velR'\] missing"),
        ("time,curL,curR,velL,velR\n0,1,1,0.1,0.2\n0.15,1,1,abc,0.2\n", r"row 3, column 'velL': value 'abc'"),
        (
            "time,curL,curR,velL,velR\n0,1,1,0.1,0.2\n0.15,1,1,0.1,nan\n",
            r"row 3, column 'velR': value 'nan' is not finite",
        ),
        ("time,curL,curR,velL,velR\n0.2,1,1,0.1,0.2\n0.1,1,1,0.1,0.2\n", r"column 'time': value 0.1 does not increase"),
    ],
)
def test_bad_csv_names_file_column_and_value(tmp_path, text, match):
    path = tmp_path / "pro_00.csv"
    path.write_text(text)
    with pytest.raises(CsvError, match=match) as info:
        read_csv(path, ("time", "curL", "curR", "velL", "velR"))
    assert str(path) in str(info.value)


def test_missing_partner_file_is_refused(tmp_path):
    run = _write_run(tmp_path / "ASPHALT")
    run.pro.unlink()
    with pytest.raises(CsvError, match="no matching pro_00.csv"):
        find_runs(tmp_path)


def test_real_borealtc_runs_import_and_replay(tmp_path):
    if not REAL.is_dir():
        pytest.skip(f"real data not present at {REAL} (../shared/real_data/borealtc)")
    from terrain_analysis.sim2real.husky import build_husky_model

    runs = find_runs(REAL)
    assert {r.terrain for r in runs} >= {"ASPHALT", "SANDY_LOAM"}
    run = next(r for r in runs if r.name == "ASPHALT/run_06")
    cfg = read_husky_config()
    bag = convert_run(
        run, tmp_path, wheel_radius=cfg["vehicle.wheel_radius"], transmission_ratio=cfg["vehicle.transmission_ratio"]
    )
    model = build_husky_model(bag)
    pred = model.predict({}, {p.name: p.off for p in model.nuisance})
    use = model.data.t >= model.warmup
    encoder = model.replay_vehicle.wheel_radius * (model.data.omega[:, 1] - model.data.omega[:, 0]) / 0.555
    gyro = model.data.yaw_rate[use]
    # The replay with slip is closer to the gyro than the no-slip encoder yaw rate (skid steering in turns).
    assert np.sqrt(np.mean((gyro - pred["yaw_rate"][use]) ** 2)) < np.sqrt(np.mean((gyro - encoder[use]) ** 2))
