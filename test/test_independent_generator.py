"""The independent bag generator (issue 22, item 7): bags decode, labels match, and the code paths stay apart."""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from vehicle_sim.independent import suite
from vehicle_sim.independent.quarter_car import SOILS, QuarterCarVehicle, _Chain

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "vehicle_sim" / "vehicle_sim" / "independent"
START_MIN_NS = int(1.6e9 * 1e9)

CONTRACT = {
    "quarter_car": {
        "/quarter_car/imu/body": "sensor_msgs/msg/Imu",
        "/quarter_car/imu/wheel": "sensor_msgs/msg/Imu",
        "/quarter_car/joint_states": "sensor_msgs/msg/JointState",
        "/quarter_car/terrain/profile": "geometry_msgs/msg/PointStamped",
    },
    "skid_steer": {
        "/skid_steer/imu": "sensor_msgs/msg/Imu",
        "/skid_steer/joint_states": "sensor_msgs/msg/JointState",
    },
}


def _read(bag: Path) -> dict[str, list[tuple[int, Any]]]:
    out: dict[str, list[tuple[int, Any]]] = {}
    with AnyReader([bag]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, _, raw in reader.messages():
            msg: Any = reader.deserialize(raw, conn.msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            out.setdefault(conn.topic, []).append((stamp, msg))
    out["__types__"] = [(0, types)]
    return out


@pytest.fixture(scope="module")
def tiny_suite(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[suite.Plan]]:
    plans = suite.plan_suite(
        7,
        per_effect=1,
        controls=1,
        structure_controls=0,
        out_of_catalogue=0,
        effects=["accel_bias"],
        duration=3.0,
    )
    out = tmp_path_factory.mktemp("independent")
    suite.generate(out, plans, jobs=1, signatures=True)
    return out, plans


def test_bags_decode_with_the_contract_topics_and_sane_values(tiny_suite: tuple[Path, list[suite.Plan]]) -> None:
    out, plans = tiny_suite
    assert {(p.vehicle, p.kind) for p in plans} == {
        ("quarter_car", "effect"),
        ("quarter_car", "control"),
        ("skid_steer", "effect"),
        ("skid_steer", "control"),
    }
    for plan in plans:
        data = _read(out / plan.path)
        types = data.pop("__types__")[0][1]
        assert types == CONTRACT[plan.vehicle], plan.vehicle
        stamps = [s for rows in data.values() for s, _ in rows]
        assert min(stamps) >= plan.start_time_ns >= START_MIN_NS
        assert max(stamps) <= plan.start_time_ns + int(plan.duration * 1e9) + 1
        if plan.vehicle == "quarter_car":
            body = np.array([m.linear_acceleration.z for _, m in data["/quarter_car/imu/body"]])
            assert len(body) == pytest.approx(100 * plan.duration, abs=2)
            assert abs(float(np.mean(body)) - 9.80665) < 1.0  # specific force, gravity included (REP 145)
            x = np.array([m.point.x for _, m in data["/quarter_car/terrain/profile"]])
            assert len(x) == pytest.approx(1000 * plan.duration, abs=2)
            assert np.all(np.diff(x) > 0)
            speed = float(plan.scenario["speed"])
            assert np.diff(x).mean() == pytest.approx(speed / 1000.0, rel=1e-6)
            rate = [m.velocity[0] for _, m in data["/quarter_car/joint_states"]]
            assert rate == pytest.approx([speed / QuarterCarVehicle().wheel_radius] * len(rate))
            imu = data["/quarter_car/imu/body"][0][1]
            assert imu.orientation_covariance[0] == -1.0 and imu.angular_velocity_covariance[0] == -1.0
            assert imu.linear_acceleration_covariance[8] == pytest.approx(0.5)
        else:
            rows = data["/skid_steer/imu"]
            acc = np.array([[getattr(m.linear_acceleration, a) for a in "xyz"] for _, m in rows])
            assert len(acc) == pytest.approx(100 * plan.duration, abs=2)
            assert np.all(np.isfinite(acc))
            assert abs(float(np.mean(acc[:, 2])) - 9.80665) < 1.0
            assert np.max(np.abs(acc[:, :2])) < 9.0  # a 3 t vehicle on tires: under μ g
            joints = data["/skid_steer/joint_states"]
            assert list(joints[0][1].name) == ["left_motor", "right_motor"]
            position = np.array([m.position for _, m in joints])
            step = 2.0 * math.pi / 4096
            assert np.allclose(np.round(position / step) * step, position)  # quantised encoder counts
            assert position[-1].min() > position[0].max()  # both sides drove forward


def test_labels_and_manifest_match_the_bags(tiny_suite: tuple[Path, list[suite.Plan]]) -> None:
    out, plans = tiny_suite
    manifest = json.loads((out / "manifest.json").read_text())
    labels = json.loads((out / "labels.json").read_text())["labels"]
    ids = sorted(p.id for p in plans)
    assert [b["id"] for b in manifest["bags"]] == ids
    assert sorted(labels) == ids
    for entry in manifest["bags"]:
        assert set(entry) == {"id", "vehicle", "bag"}  # nothing about the effect
        assert (out / entry["bag"] / "metadata.yaml").is_file()
        assert labels[entry["id"]]["vehicle"] == entry["vehicle"]
    for plan in plans:
        label = labels[plan.id]
        assert label["kind"] == plan.kind
        if plan.kind == "control":
            assert "signature" not in label and label["effect"] is None
            continue
        assert label["effect"] == "accel_bias"
        sigma = math.sqrt(0.5) if plan.vehicle == "quarter_car" else 0.05
        # The bag and its twin share the noise: bag − twin is the bias exactly, so the signature is
        # sqrt(Σ_channels N b²)/σ with N the samples compared.
        n = int(round(plan.duration * 100)) + 1
        expected = math.sqrt(sum(n * b * b for b in label["parameters"].values())) / sigma
        assert label["signature"]["snr"] == pytest.approx(expected, rel=2e-3)


def test_plans_hold_structure_controls_and_new_out_of_catalogue_effects() -> None:
    plans = suite.plan_suite(11, per_effect=0, controls=0, structure_controls=2, out_of_catalogue=3)
    kinds = {(p.vehicle, p.kind) for p in plans}
    assert kinds == {(v, k) for v in suite.VEHICLES for k in ("structure_control", "out_of_catalogue")}
    for p in plans:
        if p.kind == "structure_control":
            assert p.label()["expected"] == "structure differs"
            assert p.effect is None and p.parameters == {}
            assert p.structure.get("soil_law") == "zener" or p.structure.get("tire_law") == "dugoff"
    from vehicle_sim.tools import withheld  # the other generator's list (a test may import it)

    assert len(set(suite.OUT_OF_CATALOGUE) - set(withheld.OUT_OF_CATALOGUE)) >= 2
    with pytest.raises(ValueError, match="unknown vehicle"):
        suite.plan_suite(1, ["rover"], per_effect=1, controls=0)


def test_soil_laws_share_the_stated_linear_equivalent_stiffness() -> None:
    load = (455.0 + 45.5) * 9.80665
    k_s, k_t = SOILS["graneville_loam"], 175e3
    k_tot = k_s * k_t / (k_s + k_t)
    for law, shape, sign in (("hyperbolic", {"load_ratio": 0.4}, -1.0), ("hard_layer", {"depth_ratio": 0.4}, 1.0)):
        chain = _Chain(law, shape, k_s, k_t, load)
        eps = 1e-7
        assert chain.force(0.0) == pytest.approx(0.0, abs=1e-6)
        assert (chain.force(eps) - chain.force(-eps)) / (2 * eps) == pytest.approx(k_tot, rel=1e-5)
        curvature = chain.force(0.005) + chain.force(-0.005)  # > 0 stiffening, < 0 softening
        assert math.copysign(1.0, curvature) == sign, law


def _imports(path: Path) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found |= {f"{node.module}.{a.name}" for a in node.names}
    return found


def test_the_generator_and_the_diagnosis_do_not_import_each_other() -> None:
    forbidden = (
        "vehicle_sim.plants",
        "vehicle_sim.effects",
        "vehicle_sim.terrain",
        "vehicle_sim.tools",
        "vehicle_sim.ros",
        "terrain_estimation",
        "terrain_analysis",
    )
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) >= 5
    for path in files:
        bad = sorted(m for m in _imports(path) if m.startswith(forbidden))
        assert not bad, f"{path.name} imports {bad}"
    for package in ("terrain_estimation", "terrain_analysis"):
        for path in sorted((ROOT / "src" / "terrain_estimation" / package).rglob("*.py")):
            bad = sorted(m for m in _imports(path) if m.startswith("vehicle_sim.independent"))
            assert not bad, f"{path} imports {bad}"


def test_the_checker_sees_a_forbidden_import(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from vehicle_sim.plants.quarter_car import QuarterCarSimulator\n")
    assert "vehicle_sim.plants.quarter_car" in _imports(module)


def test_the_quarter_car_integrator_matches_scipy_on_the_linear_model() -> None:
    """The RK4 plant (linear soil) against scipy.signal.lsim of the same linear system on the same road."""
    from scipy import signal

    from vehicle_sim.independent import quarter_car as qc
    from vehicle_sim.independent.road import iso8608_road

    run = qc.QuarterCarRun(duration=3.0, speed=10.0, road_class="D", road_seed=3, soil="graneville_loam", seed=1)
    out = qc.simulate(run, noise=False)
    v = run.vehicle
    k_s, k_t = qc.SOILS[run.soil], v.tire_stiffness
    k_tot = k_s * k_t / (k_s + k_t)
    ms, mu, k, c = v.sprung_mass, v.unsprung_mass, v.suspension_stiffness, v.suspension_damping
    a = np.array(
        [[0, 1, 0, 0], [-k / ms, -c / ms, k / ms, c / ms], [0, 0, 0, 1], [k / mu, c / mu, -(k + k_tot) / mu, -c / mu]]
    )
    b = np.array([[0.0], [0.0], [0.0], [k_tot / mu]])
    points = 2 * int(round(run.duration / qc.STEP)) + 1
    size = int(math.ceil((points + 64) / 4096.0) * 4096)
    road = iso8608_road("D", np.random.default_rng(3), size, run.speed * qc.STEP / 2)
    t = np.arange(points) * qc.STEP / 2
    h0 = road.h[0]
    _, y, _ = signal.lsim((a, b, a[[1, 3], :], b[[1, 3], :]), road.h[:points], t, X0=[h0, 0.0, h0, 0.0])
    every = int(round(0.01 / (qc.STEP / 2)))
    body, wheel = y[::every, 0] + qc.GRAVITY, y[::every, 1] + qc.GRAVITY
    assert np.std(out.wheel) > 5.0  # a real ride signal on an ISO D road
    assert np.sqrt(np.mean((out.body - body) ** 2)) < 1e-3
    assert np.sqrt(np.mean((out.wheel - wheel) ** 2)) < 1e-2


def test_the_skid_steer_holds_on_a_slope_with_the_stated_signs() -> None:
    """At rest on a plane with grade γ and bank β the IMU reads (g sin γ, g cos γ sin β, g cos γ cos β)."""
    from vehicle_sim.independent import skid_steer as ss

    grade, bank = -0.05, 0.1
    run = ss.SkidSteerRun(
        duration=3.0,
        manoeuvre={"kind": "turn", "ramp": 1.0, "speed": 0.0, "difference": 0.0},
        rolling_resistance=0.02,
        seed=1,
        effects={"terrain_grade": grade, "terrain_bank": bank},
    )
    acc = ss.simulate(run, noise=False).accel[-50:].mean(axis=0)
    g = 9.80665
    expected = [g * math.sin(grade), g * math.cos(grade) * math.sin(bank), g * math.cos(grade) * math.cos(bank)]
    assert acc == pytest.approx(expected, rel=1e-3)


def test_the_validation_scores_structure_controls_as_right_only_when_structural(tmp_path: Path) -> None:
    from terrain_analysis.tools.validate_sim2real import GENERATORS, score, score_markdown

    assert GENERATORS["independent"] == "vehicle_sim.independent"
    labels: dict[str, dict[str, Any]] = {
        "a": {"vehicle": "skid_steer", "kind": "structure_control", "effect": None, "parameters": {}},
        "b": {"vehicle": "skid_steer", "kind": "structure_control", "effect": None, "parameters": {}},
        "c": {"vehicle": "skid_steer", "kind": "control", "effect": None, "parameters": {}, "scenario": {}},
    }
    (tmp_path / "labels.json").write_text(json.dumps({"labels": labels}))

    def result(bag_id: str, kind: str, explained: list[str]) -> dict[str, Any]:
        return {
            "id": bag_id,
            "vehicle": "skid_steer",
            "verdict": kind,
            "kind": kind,
            "explained_by": explained,
            "indistinguishable": [],
            "ranking": explained,
            "best": None,
            "seconds": 1.0,
        }

    results = [
        result("a", "structure_differs", []),
        result("b", "explained", ["cornering_stiffness_change"]),
        result("c", "no_gap", []),
    ]
    s = score(tmp_path, results)["skid_steer"]
    assert s["structure_controls"] == 2
    assert s["structure_structural"] == pytest.approx(0.5)
    assert s["confusion"]["structure control"] == {"structure differs": 1, "cornering_stiffness_change": 1}
    assert [m["id"] for m in s["misses"]] == ["b"]
    context = {"seed": 1, "command": "x", "date": "d", "wall": 60.0, "jobs": 1, "per_effect": 1}
    text = score_markdown({"skid_steer": s}, {**context, "generator": "independent"})
    assert "independent generator" in text and '"structure differs"' in text and "50.0 % of 2" in text
