"""Every command-line tool ends in the documented exit statuses (``terrain_estimation.cli``).

0 ok, 1 a result-level finding, 2 the input cannot be used, 3 an internal
error, 130 Ctrl-C: an internal error must never read as 1 ("a gap found") nor
escape as Python's own status 1 with a traceback, and bad input is 2 in every
tool.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from terrain_estimation.bag import BagError
from terrain_estimation.cli import (
    EXIT_BROKEN_PIPE,
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    InputError,
    run_cli,
)
from terrain_estimation.params import ParameterError

BAGS = Path(__file__).resolve().parents[1] / "bags"


def _raise(exc: BaseException) -> Callable[[], int]:
    def body() -> int:
        raise exc

    return body


@pytest.mark.parametrize(
    ("exc", "status"),
    [
        (InputError("bad"), EXIT_INPUT),
        (BagError("bad bag"), EXIT_INPUT),
        (ParameterError("bad parameter"), EXIT_INPUT),
        (FileExistsError("exists"), EXIT_INPUT),
        (KeyboardInterrupt(), EXIT_INTERRUPTED),
        (RuntimeError("a bug"), EXIT_INTERNAL),
        (AttributeError("'Vector3Stamped' object has no attribute 'linear_acceleration'"), EXIT_INTERNAL),
        (ZeroDivisionError(), EXIT_INTERNAL),
    ],
)
def test_run_cli_maps_exceptions_to_statuses(
    exc: BaseException, status: int, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run_cli("tool", _raise(exc)) == status
    err = capsys.readouterr().err
    if status == EXIT_INTERNAL:
        assert "Traceback" in err and "internal error" in err
    elif status == EXIT_INPUT:
        assert err.startswith("tool: error: ")


def test_run_cli_passes_the_tools_own_status() -> None:
    assert run_cli("tool", lambda: EXIT_OK) == EXIT_OK
    assert run_cli("tool", lambda: 1) == 1


def test_a_closed_pipe_is_quiet(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_cli("tool", _raise(BrokenPipeError())) == EXIT_BROKEN_PIPE
    assert "Traceback" not in capsys.readouterr().err


# Tools whose whole main goes through cli_main: an error anywhere, even in argument parsing, is status 3.
DECORATED = [
    "terrain_analysis.tools.bench",
    "terrain_analysis.tools.bench_load",
    "terrain_analysis.tools.reproduce_qc",
    "terrain_analysis.tools.reproduce_rover",
    "terrain_analysis.tools.reproduce_skid",
    "terrain_analysis.tools.sim2real_results",
    "terrain_analysis.tools.validate_sim2real",
    "terrain_analysis.sim2real.husky",
    "terrain_analysis.sim2real.single_wheel",
    "vehicle_sim.tools.withheld",
]


@pytest.mark.parametrize("module", DECORATED)
def test_an_internal_error_is_status_3_in_every_tool(module: str, monkeypatch: pytest.MonkeyPatch) -> None:
    def boom(*_args: Any, **_kwargs: Any) -> Any:
        raise RuntimeError("injected")

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", boom)
    assert importlib.import_module(module).main([]) == EXIT_INTERNAL


@pytest.mark.parametrize(
    ("module", "target", "argv"),
    [
        (
            "terrain_estimation.tools.estimate",
            "estimate_bag",
            [str(BAGS / "quarter_car_graneville_iso_d_10ms"), "--vehicle", "quarter_car", "-o", "{tmp}/out"],
        ),
        ("vehicle_sim.tools.simulate", "record", ["--vehicle", "quarter_car", "--duration", "1", "-o", "{tmp}/out"]),
        (
            "terrain_analysis.tools.sim2real",
            "diagnose",
            [str(BAGS / "quarter_car_graneville_iso_d_10ms"), "--vehicle", "quarter_car", "-q"],
        ),
    ],
)
def test_an_internal_error_in_the_work_is_status_3(
    module: str, target: str, argv: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    mod = importlib.import_module(module)

    def boom(*_args: Any, **_kwargs: Any) -> Any:
        raise AttributeError("injected")

    monkeypatch.setattr(mod, target, boom)
    assert mod.main([a.format(tmp=tmp_path) for a in argv]) == EXIT_INTERNAL
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("module", "argv"),
    [
        ("terrain_estimation.tools.estimate", ["{tmp}/no_such_bag", "--vehicle", "quarter_car", "-o", "{tmp}/out"]),
        ("terrain_analysis.tools.sim2real", ["{tmp}/no_such_bag", "--vehicle", "quarter_car", "-q"]),
        ("vehicle_sim.tools.simulate", ["--vehicle", "quarter_car", "--duration", "-1", "-o", "{tmp}/out"]),
        ("vehicle_sim.tools.borealtc", ["--data", "{tmp}/no_such_data", "--out", "{tmp}/out"]),
    ],
)
def test_unusable_input_is_status_2(
    module: str, argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mod = importlib.import_module(module)
    assert mod.main([a.format(tmp=tmp_path) for a in argv]) == EXIT_INPUT
    assert "error:" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
