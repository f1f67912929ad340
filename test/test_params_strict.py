"""Issue 19 items 9 and 10: unknown parameter names are refused with close matches, and parameter
files and ``--param`` values are bounded input (no alias expansion, bounded size and error text)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from terrain_estimation.params import (
    MAX_OVERRIDE_CHARS,
    ParameterError,
    ParamSpec,
    load_parameter_file,
    parse_override,
)
from terrain_estimation.ros.executable import build_node
from terrain_estimation.ros.framework import EstimatorNode
from terrain_estimation.vehicles import VEHICLES, estimator_parameters
from vehicle_sim.ros.registry import SIMULATORS, simulator_parameters

CONFIG = Path(__file__).resolve().parents[1] / "config"


def _write(path: Path, section: str, body: str) -> Path:
    path.write_text(f'"{section}":\n  ros__parameters:\n' + textwrap.indent(textwrap.dedent(body), "    "))
    return path


# (reader, section, YAML under ros__parameters, the name refused, a suggestion)
CASES = [
    ("estimator", "/**", "vehicle:\n  sprung_mas: 400.0\n", "vehicle.sprung_mas", "vehicle.sprung_mass"),
    ("estimator", "/**/soil_stiffness", "filter:\n  typ: ekf\n", "filter.typ", "filter.type"),
    ("simulator", "/**", "vehicle:\n  sprung_mas: 400.0\n", "vehicle.sprung_mas", "vehicle.sprung_mass"),
    ("simulator", "/**/quarter_car_sim", "sensors:\n  rat: 50.0\n", "sensors.rat", "sensors.rate"),
]


@pytest.mark.parametrize(("reader", "section", "body", "name", "suggestion"), CASES)
def test_unknown_name_in_a_config_file_is_refused_with_close_matches(tmp_path, reader, section, body, name, suggestion):
    path = _write(tmp_path / "typo.yaml", section, body)
    with pytest.raises(ParameterError) as info:
        if reader == "estimator":
            estimator_parameters(VEHICLES["quarter_car"], path)
        else:
            simulator_parameters(SIMULATORS["quarter_car"], path)
    text = str(info.value)
    assert f"unknown parameter '{name}'" in text and "typo.yaml" in text and f"section '{section}'" in text, text
    assert f"did you mean {suggestion}" in text, text


def test_shared_section_holds_only_names_every_reader_declares(tmp_path):
    """``/**`` applies to the estimator and the simulator alike: a simulator-only name there is refused by
    the estimator, with the rule in the message; in the simulator's own section it is accepted by both."""
    shared = _write(tmp_path / "shared.yaml", "/**", "seed: 7\n")
    assert simulator_parameters(SIMULATORS["quarter_car"], shared)["seed"] == 7
    with pytest.raises(ParameterError, match=r"'seed' in .*section '/\*\*'.*applies to every node"):
        estimator_parameters(VEHICLES["quarter_car"], shared)
    own = _write(tmp_path / "own.yaml", "/**/quarter_car_sim", "seed: 7\n")
    assert simulator_parameters(SIMULATORS["quarter_car"], own)["seed"] == 7
    estimator_parameters(VEHICLES["quarter_car"], own)


def test_live_node_refuses_an_unknown_name_before_rcl_ignores_it(tmp_path, capsys):
    """node_main checks the config file before handing it to rcl; build_node also the overrides' names."""
    from terrain_estimation.nodes import main

    path = _write(tmp_path / "live.yaml", "/**/soil_stiffness", "filter:\n  typ: ekf\n")
    assert main(["--vehicle", "quarter_car", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert "unknown parameter 'filter.typ'" in err and "live.yaml" in err and "filter.type" in err, err
    assert main(["--vehicle", "quarter_car", "--config", str(tmp_path / "missing.yaml")]) == 2
    assert "does not exist" in capsys.readouterr().err
    entry = VEHICLES["quarter_car"]
    with pytest.raises(ParameterError, match="live.yaml.*did you mean filter.type"):
        build_node(EstimatorNode, entry, config=str(path))
    with pytest.raises(ParameterError, match=r"'diagnostics.perio' in overrides; did you mean diagnostics.period"):
        build_node(EstimatorNode, entry, overrides={"diagnostics.perio": 1.0})


def test_live_node_accepts_rclpys_own_parameters(tmp_path, rclpy_context):
    """use_sim_time is declared by rclpy, not by the specs: valid in the config file and in the overrides."""
    path = _write(tmp_path / "sim_time.yaml", "/**", "use_sim_time: true\n")
    assert estimator_parameters(VEHICLES["quarter_car"], path)["filter.type"] == "sckf"
    node = build_node(
        EstimatorNode,
        VEHICLES["quarter_car"],
        config=str(path),
        overrides={"use_sim_time": True},
        context=rclpy_context,
    )
    try:
        assert node.get_parameter("use_sim_time").value is True
    finally:
        node.destroy_node()


def test_live_node_reads_a_file_describing_another_vehicle_kind(rclpy_context):
    """config/husky.yaml: '/**' is the 4-wheel Husky of the importer, its estimator section the node's view.

    The node takes the declared '/**' names and its own section over them, as rcl applies the file; the
    Husky's other names (vehicle.wheelbase, ...) belong to the other readers and are no error."""
    node = build_node(EstimatorNode, VEHICLES["skid_steer"], config=str(CONFIG / "husky.yaml"), context=rclpy_context)
    try:
        assert list(node.get_parameter("vehicle.axle_x").value) == [0.256, -0.256]
        assert node.get_parameter("vehicle.mass").value == 50.0  # from '/**'
    finally:
        node.destroy_node()


def test_param_typo_is_exit_status_2_with_the_suggestion(tmp_path, capsys):
    from terrain_estimation.tools import estimate
    from vehicle_sim.tools import simulate

    out = str(tmp_path / "out")
    argv = ["missing_bag", "--vehicle", "quarter_car", "-o", out, "--param", "filter.typ=ekf"]
    assert estimate.main(argv) == 2
    err = capsys.readouterr().err
    assert "unknown parameter 'filter.typ' in --param; did you mean filter.type?" in err, err
    argv = ["--vehicle", "quarter_car", "--duration", "1", "-o", out, "--param", "sensors.rat=50"]
    assert simulate.main(argv) == 2
    err = capsys.readouterr().err
    assert "unknown parameter 'sensors.rat' in --param; did you mean sensors.rate?" in err, err
    assert simulate.main(["--vehicle", "rover", "--duration", "1", "-o", out, "--param", "no.such=3"]) == 2
    assert "unknown parameter 'no.such' in --param" in capsys.readouterr().err
    assert not Path(out).exists()


def test_every_shipped_config_loads_strictly_for_every_reader():
    """Each vehicle's config for its estimator and simulator; husky.yaml (no node) for its importer."""
    from vehicle_sim.tools.borealtc import read_husky_config

    configs = {p.stem for p in CONFIG.glob("*.yaml")}
    assert configs == set(VEHICLES) | {"husky"} and set(SIMULATORS) == set(VEHICLES)
    for vehicle in VEHICLES:
        path = CONFIG / f"{vehicle}.yaml"
        assert estimator_parameters(VEHICLES[vehicle], path)["vehicle.kind"] == vehicle
        assert simulator_parameters(SIMULATORS[vehicle], path)["vehicle.kind"] == vehicle
    assert read_husky_config(CONFIG / "husky.yaml")["vehicle.transmission_ratio"] == 78.71


BILLION_LAUGHS = '"/**":\n  ros__parameters:\n    l0: &l0 [' + ", ".join(['"lol"'] * 9) + "]\n"
BILLION_LAUGHS += "".join(f"    l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]\n" for i in range(1, 9))
BILLION_LAUGHS += "    vehicle:\n      sprung_mass: *l8\n"  # 9**9 strings if expanded


def test_billion_laughs_file_gives_a_short_error_in_little_memory(tmp_path):
    path = tmp_path / "lol.yaml"
    path.write_text(BILLION_LAUGHS)
    assert len(BILLION_LAUGHS) < 1000
    probe = f"""
import tracemalloc
from terrain_estimation.params import ParameterError
from terrain_estimation.vehicles import VEHICLES, estimator_parameters
estimator_parameters(VEHICLES["quarter_car"], None)  # the imports, not measured
tracemalloc.start()
try:
    estimator_parameters(VEHICLES["quarter_car"], {str(path)!r})
    message = "accepted"
except ParameterError as exc:
    message = str(exc)
print(tracemalloc.get_traced_memory()[1])
print(message)
"""
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, check=True)
    peak, message = run.stdout.split("\n", 1)
    assert len(message) < 1000, len(message)
    assert int(peak) < 50e6, f"peak {int(peak) / 1e6:.0f} MB"
    assert "lol.yaml': line 3" in message and "aliases" in message, message


def test_oversized_and_deep_files_are_refused(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_text("#" * 1_000_001)
    with pytest.raises(ParameterError, match="big.yaml' is larger than 1000000 bytes"):
        load_parameter_file(big)
    deep = tmp_path / "deep.yaml"
    deep.write_text("[" * 100_000)
    with pytest.raises(ParameterError, match="deep.yaml': line 1, column 33: nested more than 32"):
        load_parameter_file(deep)


def test_param_values_are_parsed_with_bounds(capsys, tmp_path):
    assert parse_override(" filter.q_diag = [1.0, 2]") == ("filter.q_diag", [1.0, 2])
    assert parse_override("filter.type=ekf") == ("filter.type", "ekf")
    with pytest.raises(ParameterError, match="expected NAME=VALUE"):
        parse_override("=3")
    with pytest.raises(ParameterError, match=r"--param 'x': line 1, column 2: YAML anchors and aliases"):
        parse_override("x=[&a 1, *a]")
    with pytest.raises(ParameterError) as info:
        parse_override("filter.type=" + "x" * (MAX_OVERRIDE_CHARS + 1))
    assert len(str(info.value)) < 200 and f"at most {MAX_OVERRIDE_CHARS}" in str(info.value)

    from terrain_estimation.tools import estimate

    argv = ["missing_bag", "--vehicle", "quarter_car", "-o", str(tmp_path / "o"), "--param"]
    assert estimate.main([*argv, "filter.type=" + "x" * 100_000]) == 2
    err = capsys.readouterr().err
    assert "filter.type" in err and len(err) < 1000, err[:2000]


def test_validation_errors_quote_a_huge_value_briefly():
    """Also an integer too long for str() or float(): a ParameterError, not a ValueError or OverflowError."""
    spec = ParamSpec("gain", 1.0, "[-] gain", 0.0, 2.0)
    for value in ("x" * 10**6, [[1.0] * 10**5] * 10, 10**5000, 10**400):
        with pytest.raises(ParameterError) as info:
            spec.validate(value)
        assert len(str(info.value)) < 300, str(info.value)[:1000]


def test_an_empty_list_in_a_params_file_reaches_the_node(tmp_path):
    """rcl gives 'name: []' of a --params-file as NOT_SET (None); the node reads it as the empty list it is
    (the shipped config/skid_steer.yaml has ground.patch_* = [] for the simulator: make demo broke on it)."""
    import rclpy

    from terrain_estimation.ros.framework import SimulatorNode

    path = _write(tmp_path / "empty.yaml", "/**", "ground:\n  patch_friction: []\n  patch_x_min: []\n")
    context = rclpy.Context()
    rclpy.init(args=["test", "--ros-args", "--params-file", str(path)], context=context)
    try:
        node = build_node(SimulatorNode, SIMULATORS["skid_steer"], use_config=False, context=context)
        try:
            assert node.values["ground.patch_friction"] == [] and node.values["ground.patch_x_min"] == []
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
