"""Sim-to-real 'where' diagnosis (issue 6) on short simulated bags."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from terrain_analysis.sim2real import Sim2RealError, diagnose_where
from terrain_analysis.sim2real.report import write_report
from terrain_estimation.bag import AtomicBagWriter, read_bag
from vehicle_sim.tools.simulate import record

DURATION = 4.0


def _bag(tmp: Path, name: str, **overrides: object) -> Path:
    out = tmp / name
    record("quarter_car", DURATION, out, overrides={"seed": 3, "scenario.road_seed": 4, **overrides})
    return out


@pytest.fixture(scope="module")
def nominal_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _bag(tmp_path_factory.mktemp("s2r"), "nominal")


def test_nominal_has_no_significant_gap(nominal_bag: Path, tmp_path: Path) -> None:
    report = diagnose_where(nominal_bag, "quarter_car")
    assert report.verdict == "no significant gap", report.gaps
    assert {ch.name for ch in report.channels} == {"body", "wheel"}
    for ch in report.channels:
        assert abs(ch.bias) < ch.bias_threshold
        assert 0.7 < ch.rms_ratio < 1.25
    assert report.nis is not None and report.nis.in_band
    assert "estimator" in report.k_s_source
    paths = write_report(report, tmp_path / "out")
    assert {p.name for p in paths} >= {"where.md", "where.json", "psd_ratio_per_band.png", "residual_per_window.png"}
    data = json.loads((tmp_path / "out" / "where.json").read_text())
    assert data["verdict"] == "no significant gap"


def test_body_accelerometer_bias_shows_on_the_body_mean(tmp_path: Path) -> None:
    report = diagnose_where(_bag(tmp_path, "bias", **{"effects.accel_bias_body": 0.3}), "quarter_car")
    body, wheel = report.channel("body"), report.channel("wheel")
    assert body.bias == pytest.approx(0.3, abs=0.06)
    assert abs(body.bias) > body.bias_threshold
    assert abs(wheel.bias) < wheel.bias_threshold
    assert any(g.startswith("body: bias") for g in report.gaps)
    assert not any(b.gap for b in body.bands)


def test_tire_enveloping_shows_in_the_high_band_of_the_wheel(tmp_path: Path) -> None:
    report = diagnose_where(_bag(tmp_path, "envelope", **{"effects.tire_contact_length": 0.3}), "quarter_car")
    wheel = report.channel("wheel")
    high = [b for b in wheel.bands if b.f_low >= 16.0]
    assert high and all(b.gap for b in high)
    assert high[-1].measured_to_simulated < 0.5  # the tire filters the short wavelengths out
    assert report.significant_gap


def test_missing_topic_is_named(nominal_bag: Path, tmp_path: Path) -> None:
    cut = tmp_path / "no_wheel_imu"
    with AtomicBagWriter(cut) as writer:
        for item in read_bag(nominal_bag):
            if item.topic != "/quarter_car/imu/wheel":
                writer.write(item.topic, item.msg, item.log_time_ns)
    with pytest.raises(Sim2RealError, match="/quarter_car/imu/wheel"):
        diagnose_where(cut, "quarter_car")


def test_unsupported_vehicle() -> None:
    with pytest.raises(Sim2RealError, match="skid_steer"):
        diagnose_where("nowhere", "skid_steer")


def test_noise_tests_false_alarm_rate_on_white_noise() -> None:
    """The bias, power and band tests of one channel hold their share of α on pure sensor noise.

    With two channels and α = 0.01 each channel may flag white noise in 0.5 % of bags; Welch
    bins are correlated, so counting them as independent (the old band dof) gave 1-4 %.
    """
    import numpy as np

    from terrain_analysis.sim2real.where import WhereSettings, _channel

    rng = np.random.default_rng(11)
    trials, flagged = 400, 0
    for _ in range(trials):
        noise = 0.3 * rng.standard_normal(2000)  # 20 s at 100 Hz, σ = 0.3 (any unit)
        rep = _channel("x", "/x", noise, np.zeros_like(noise), 100.0, 0.09, WhereSettings(), 2, unit="rad/s")
        flagged += bool(rep.gaps)
    assert flagged / trials <= 0.015  # expected ≤ 0.005; binomial 99.9 % bound for 400 trials ≈ 0.015


def test_bias_floor_scales_with_the_channel_noise() -> None:
    """A bias far below the sensor noise is model-error allowance in any unit; one above the floor is a gap."""
    import numpy as np

    from terrain_analysis.sim2real.where import WhereSettings, _channel

    rng = np.random.default_rng(2)
    sigma = 0.002  # rad/s: a gyro, where an absolute 0.05 floor would hide any bias
    noise = sigma * rng.standard_normal(20000)
    clean = _channel("yaw", "/yaw", noise, np.zeros_like(noise), 100.0, sigma**2, WhereSettings(), 1, unit="rad/s")
    biased = _channel("yaw", "/yaw", noise + 0.002, np.zeros_like(noise), 100.0, sigma**2, WhereSettings(), 1, "rad/s")
    assert not clean.gaps
    assert any("bias" in g and "rad/s" in g for g in biased.gaps)


def test_one_bad_sample_costs_one_sample() -> None:
    """An isolated 14-sigma sample (a glitch, a message one period late on a rough road) is no gap;
    a burst of them, or an excursion over consecutive samples, stays in the statistics."""
    import numpy as np

    from terrain_analysis.sim2real.where import WhereSettings, _channel, despike

    rng = np.random.default_rng(5)
    sigma = 0.3
    noise = sigma * rng.standard_normal(400)  # 4 s at 100 Hz: one sample is 0.25 % of it
    spiked = noise.copy()
    spiked[200] += 14 * sigma
    zeros = np.zeros_like(noise)
    assert _channel("x", "/x", spiked, zeros, 100.0, sigma**2, WhereSettings(spike_sigma=0.0), 1).gaps
    rep = _channel("x", "/x", spiked, zeros, 100.0, sigma**2, WhereSettings(), 1)
    assert not rep.gaps and rep.spikes == 1
    cleaned, count = despike(spiked, zeros, WhereSettings())
    assert count == 1 and abs(cleaned[200] - 0.5 * (noise[199] + noise[201])) < 1e-12
    assert np.array_equal(cleaned[:200], noise[:200]) and np.array_equal(cleaned[201:], noise[201:])
    # Two consecutive samples: an impact, not a glitch.
    pair = noise.copy()
    pair[200:202] += 14 * sigma
    assert despike(pair, zeros, WhereSettings())[1] == 0
    # Many isolated excursions are the data's behaviour.
    many = noise.copy()
    many[10:400:40] += 14 * sigma
    assert despike(many, zeros, WhereSettings())[1] == 0
    assert _channel("x", "/x", many, zeros, 100.0, sigma**2, WhereSettings(), 1).gaps


def test_epoch_stamps_keep_their_spacing(tmp_path: Path) -> None:
    """Real bags carry epoch stamps (~1.7e9 s): read as float seconds they resolve only 2.4e-7 s.

    The replays take stamps relative to the first one, in integer nanoseconds, so a 1 kHz
    profile keeps a 1 ms period exactly (float seconds gave 0.99993 ms: a 1.3 ms drift of the
    replay over an 18 s bag, which the validation suite's LRV controls showed as a gap).
    """
    import numpy as np
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import Imu, JointState

    from terrain_analysis.sim2real.model import StampOrigin
    from terrain_analysis.sim2real.open_loop import _read
    from terrain_estimation.ros.time import ns_to_stamp

    start = 1_732_760_302_708_794_534
    bag = tmp_path / "epoch"
    with AtomicBagWriter(bag) as writer:
        for k in range(2000):
            t = start + k * 1_000_000
            p = PointStamped()
            p.header.stamp = ns_to_stamp(t)
            p.point.x, p.point.z = 0.01 * k, 0.0
            writer.write("/lrv/terrain/profile", p, t)
            if k % 10 == 0:
                imu = Imu()
                imu.header.stamp = ns_to_stamp(t)
                imu.linear_acceleration.z = 9.81
                writer.write("/lrv/imu/body", imu, t)
                js = JointState()
                js.header.stamp = ns_to_stamp(t)
                js.name, js.position, js.velocity = ["wheel"], [0.0], [10.0]
                writer.write("/lrv/joint_states", js, t)
    data = _read(bag, "/lrv", False, 0.4)
    assert np.max(np.abs(np.diff(data.profile_t) - 1e-3)) < 1e-12
    assert data.profile_t[0] == 0.0 and np.max(np.abs(np.diff(data.body_t) - 1e-2)) < 1e-12
    clock = StampOrigin()
    first = Imu()
    first.header.stamp = ns_to_stamp(start)
    assert clock(first) == 0.0 and abs(clock.origin - start * 1e-9) < 1e-6
