"""The benchmarks never write over a user's file: ``--json`` to an existing path is refused before any work
(exit 2, the file unchanged) unless ``--overwrite``; ``--keep`` takes only a new, empty or own directory."""

from __future__ import annotations

from pathlib import Path

import pytest

from terrain_analysis.tools import bench, bench_sim2real
from terrain_analysis.tools.bench_common import write_json
from terrain_analysis.tools.bench_sim2real import KEEP_MARKER, keep_directory
from terrain_estimation.outputs import OutputExistsError


@pytest.mark.parametrize("main", [bench.main, bench_sim2real.main])
def test_json_to_an_existing_file_is_refused_before_the_run(tmp_path: Path, main, capsys) -> None:
    user = tmp_path / "figures.json"
    user.write_text("the user's own file")
    assert main(["--quick", "--json", str(user)]) == 2
    assert user.read_text() == "the user's own file"
    assert "exists" in capsys.readouterr().err


def test_write_json_replaces_a_file_only_with_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "figures.json"
    write_json(out, {"a": 1})
    with pytest.raises(OutputExistsError):
        write_json(out, {"a": 2})
    assert out.read_text() == '{\n  "a": 1\n}\n'
    write_json(out, {"a": 2}, overwrite=True)
    assert out.read_text() == '{\n  "a": 2\n}\n'
    with pytest.raises(OutputExistsError):
        write_json(tmp_path, {"a": 3}, overwrite=True)  # a directory is never replaced


def test_keep_takes_a_new_empty_or_own_directory_only(tmp_path: Path) -> None:
    new = keep_directory(tmp_path / "new")
    assert (new / KEEP_MARKER).is_file()
    assert keep_directory(new) == new  # its own, again
    empty = tmp_path / "empty"
    empty.mkdir()
    assert keep_directory(empty) == empty
    user = tmp_path / "user"
    user.mkdir()
    (user / "quarter_car_15s.json").write_text("a user's file")
    with pytest.raises(FileExistsError):
        keep_directory(user)
    assert sorted(p.name for p in user.iterdir()) == ["quarter_car_15s.json"]
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    with pytest.raises(FileExistsError):
        keep_directory(a_file)
    assert a_file.read_text() == "x"
