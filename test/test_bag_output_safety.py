"""Nothing destroyed (issue 19): output paths are checked before anything is written.

An output bag never replaces a directory of other files, a file, or an input
of the run; ``--overwrite`` replaces only a previous bag. Partial bags of a
writer killed with SIGKILL are removed by the next writer of the same path,
and only those. Report directories are never emptied. The CLIs say so and
exit 2.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from std_msgs.msg import Float64

from terrain_estimation.bag import AtomicBagWriter, StalePartialWarning, read_bag
from terrain_estimation.cli import EXIT_INPUT, EXIT_OK
from terrain_estimation.outputs import (
    MARKER,
    OutputExistsError,
    OutputIsInputError,
    check_output_path,
    prepare_output_dir,
)
from vehicle_sim.tools import borealtc, simulate


def _tree(root: Path) -> dict[str, str]:
    """Every file and directory under ``root`` with the sha256 of its bytes."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
        for p in sorted(root.rglob("*"))
    }


def _bag(path: Path, values: list[float], overwrite: bool = False) -> Path:
    with AtomicBagWriter(path, overwrite=overwrite) as writer:
        for i, value in enumerate(values):
            writer.write("/x", Float64(data=value), 1_000 + i)
    return path


def _values(path: Path) -> list[float]:
    return [m.msg.data for m in read_bag(path)]


def _foreign_dir(path: Path) -> Path:
    (path / "sub").mkdir(parents=True)
    (path / "notes.txt").write_text("mine")
    (path / "sub" / "data.bin").write_bytes(os.urandom(64))
    return path


@pytest.mark.parametrize("overwrite", [False, True])
def test_directory_that_is_not_a_bag_is_refused_and_untouched(tmp_path: Path, overwrite: bool) -> None:
    out = _foreign_dir(tmp_path / "results")
    before = _tree(tmp_path)
    with pytest.raises(OutputExistsError, match=r"results.*not a rosbag2 bag.*never replaced.*choose another"):
        AtomicBagWriter(out, overwrite=overwrite)  # refused before anything is written
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("overwrite", [False, True])
def test_file_at_the_output_path_is_refused(tmp_path: Path, overwrite: bool) -> None:
    out = tmp_path / "estimates"
    out.write_text("not a bag")
    with pytest.raises(OutputExistsError, match=r"estimates.*is a file.*never replaced"):
        AtomicBagWriter(out, overwrite=overwrite)
    assert out.read_text() == "not a bag"
    assert [p.name for p in tmp_path.iterdir()] == ["estimates"]


@pytest.mark.parametrize("overwrite", [False, True])
def test_input_bag_as_output_is_refused_and_untouched(tmp_path: Path, overwrite: bool) -> None:
    bag = _bag(tmp_path / "input", [1.0, 2.0])
    before = _tree(tmp_path)
    for out, how in [(bag, "is"), (bag / "estimates", "is inside"), (tmp_path, "contains")]:
        with pytest.raises(OutputIsInputError, match=rf"{how} the input .*input"):
            AtomicBagWriter(out, overwrite=overwrite, inputs=[bag])
    # through a symlink or a '..' detour it is the same directory
    (tmp_path / "link").symlink_to(bag)
    with pytest.raises(OutputIsInputError):
        AtomicBagWriter(tmp_path / "link", overwrite=overwrite, inputs=[tmp_path / "x" / ".." / "input"])
    (tmp_path / "link").unlink()
    assert _tree(tmp_path) == before


def test_existing_bag_needs_overwrite_and_then_is_replaced(tmp_path: Path) -> None:
    out = _bag(tmp_path / "estimates", [1.0, 2.0])
    with pytest.raises(OutputExistsError, match=r"estimates.*exists.*pass --overwrite"):
        _bag(out, [3.0])
    assert _values(out) == [1.0, 2.0]
    _bag(out, [3.0], overwrite=True)
    assert _values(out) == [3.0]
    assert [p.name for p in tmp_path.iterdir()] == ["estimates"]  # no scratch directory left


def test_directory_appearing_while_writing_is_not_replaced(tmp_path: Path) -> None:
    out = tmp_path / "estimates"
    with pytest.raises(OutputExistsError, match="not a rosbag2 bag"):
        with AtomicBagWriter(out, overwrite=True) as writer:
            writer.write("/x", Float64(data=1.0), 1)
            _foreign_dir(out)  # e.g. another program, between the check at the start and the end
            before = _tree(out)
    assert _tree(out) == before  # the directory untouched
    assert [p.name for p in tmp_path.iterdir()] == ["estimates"]  # the partial bag gone


def test_bag_with_a_foreign_file_is_no_longer_replaceable(tmp_path: Path) -> None:
    out = _bag(tmp_path / "estimates", [1.0])
    (out / "README").write_text("added by hand")
    with pytest.raises(OutputExistsError, match="never replaced"):
        check_output_path(out, overwrite=True)


# A writer that writes a few messages and then waits to be killed.
SLOW_WRITER = textwrap.dedent(
    """
    import sys, time
    from std_msgs.msg import Float64
    from terrain_estimation.bag import AtomicBagWriter

    with AtomicBagWriter(sys.argv[1]) as writer:
        for i in range(500):
            writer.write("/x", Float64(data=float(i)), 1_000 + i)
        print("writing", flush=True)
        time.sleep(120)
    """
)


def _killed_writer(out: Path) -> int:
    proc = subprocess.Popen([sys.executable, "-c", SLOW_WRITER, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "writing"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    return proc.pid


def test_partial_bag_of_a_killed_writer_is_removed_by_the_next_one(tmp_path: Path) -> None:
    out = tmp_path / "estimates"
    pid = _killed_writer(out)
    (partial,) = [p for p in tmp_path.iterdir()]
    assert partial.name.startswith(f".estimates.partial-{pid}@") and not out.exists()
    assert any(partial.glob("*.mcap"))
    # Kept: a partial of a running process (this one), a dead writer's partial holding
    # something else, and directories that only look alike.
    host = partial.name.split("@", 1)[1].rsplit("-", 1)[0]
    running = tmp_path / f".estimates.partial-{os.getpid()}@{host}-0123abcd"
    running.mkdir()
    mixed = tmp_path / f".estimates.partial-{pid}@{host}-4567abcd"
    mixed.mkdir()
    (mixed / "notes.txt").write_text("keep me")
    other_target = tmp_path / f".estimates2.partial-{pid}@{host}-89abcdef"
    other_target.mkdir()
    unrelated = tmp_path / ".estimates.partial-deadbeef"
    unrelated.mkdir()
    with pytest.warns(StalePartialWarning) as warned:
        writer = AtomicBagWriter(out)
        with writer:
            writer.write("/x", Float64(data=7.0), 1)
    assert writer.removed_partials == [partial]
    message = str(warned[0].message)
    assert str(running) in message and "still running" in message
    assert str(mixed) in message and "other than a bag" in message
    assert str(partial) not in message and str(other_target) not in message
    assert _values(out) == [7.0]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["estimates", running.name, mixed.name, other_target.name, unrelated.name]
    )
    assert (mixed / "notes.txt").read_text() == "keep me"


def test_report_directory_is_made_marked_and_never_emptied(tmp_path: Path) -> None:
    fresh = prepare_output_dir(tmp_path / "report", tool="test")
    assert (fresh / MARKER).is_file()
    (fresh / "plot.png").write_bytes(b"png")
    assert prepare_output_dir(fresh) == fresh  # a directory a project tool made: used again
    foreign = _foreign_dir(tmp_path / "mine")
    before = _tree(foreign)
    with pytest.raises(OutputExistsError, match=r"mine.*notes.txt.*pass --overwrite"):
        prepare_output_dir(foreign)
    assert prepare_output_dir(foreign, overwrite=True) == foreign
    assert _tree(foreign) == before  # nothing deleted, no marker added
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputExistsError, match="not a directory"):
        prepare_output_dir(tmp_path / "file", overwrite=True)
    with pytest.raises(OutputIsInputError):
        prepare_output_dir(fresh / "sub", inputs=[fresh])


def test_demo_refuses_a_foreign_out_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from terrain_analysis.tools import demo

    foreign = _foreign_dir(tmp_path / "mine")
    before = _tree(foreign)
    assert demo.main(["--out", str(foreign)]) == EXIT_INPUT
    assert "terrain-demo: error:" in capsys.readouterr().err
    assert _tree(foreign) == before


SIM = ["--vehicle", "lrv", "--duration", "0.05"]


def test_simulate_cli_refuses_and_overwrites(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    foreign = _foreign_dir(tmp_path / "results")
    before = _tree(foreign)
    assert simulate.main([*SIM, "-o", str(foreign), "--overwrite"]) == EXIT_INPUT
    err = capsys.readouterr().err
    assert "terrain-simulate: error:" in err and "not a rosbag2 bag" in err and str(foreign) in err
    assert _tree(foreign) == before

    out = tmp_path / "lrv"
    assert simulate.main([*SIM, "-o", str(out)]) == EXIT_OK
    first = _tree(out)
    assert simulate.main([*SIM, "-o", str(out), "--param", "seed=99"]) == EXIT_INPUT
    assert "pass --overwrite" in capsys.readouterr().err
    assert _tree(out) == first
    assert simulate.main([*SIM, "-o", str(out), "--param", "seed=99", "--overwrite"]) == EXIT_OK
    assert _tree(out) != first and len(list(read_bag(out))) > 0


def _boreal_data(root: Path) -> Path:
    folder = root / "data" / "ASPHALT"
    folder.mkdir(parents=True)
    for index in ("00", "01"):
        (folder / f"imu_{index}.csv").write_text("time,wx,wy,wz,ax,ay,az\n0,0,0,0,0,0,9.8\n0.01,0,0,0,0,0,9.8\n")
        (folder / f"pro_{index}.csv").write_text("time,curL,curR,velL,velR\n0,1,1,0.1,0.1\n0.15,1,1,0.1,0.1\n")
    return root / "data"


def test_borealtc_cli_refuses_existing_runs_and_inputs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = _boreal_data(tmp_path)
    out = tmp_path / "out"
    (out / "ASPHALT").mkdir(parents=True)
    (out / "ASPHALT" / "notes.txt").write_text("mine")
    assert borealtc.main(["--data", str(data), "--out", str(out)]) == EXIT_OK
    before = _tree(tmp_path)
    assert borealtc.main(["--data", str(data), "--out", str(out)]) == EXIT_INPUT
    err = capsys.readouterr().err
    assert "borealtc: error:" in err and "run_00" in err and "pass --overwrite" in err
    assert _tree(tmp_path) == before
    assert borealtc.main(["--data", str(data), "--out", str(out), "--overwrite"]) == EXIT_OK
    assert (out / "ASPHALT" / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in (out / "ASPHALT").iterdir()) == ["notes.txt", "run_00", "run_01"]
    # every run's output is checked before the first is written: all or nothing
    shutil.rmtree(out / "ASPHALT" / "run_00")
    assert borealtc.main(["--data", str(data), "--out", str(out)]) == EXIT_INPUT
    assert "run_01" in capsys.readouterr().err
    assert not (out / "ASPHALT" / "run_00").exists()
    # an output tree inside the data folder would mix bags into the input
    assert borealtc.main(["--data", str(data), "--out", str(data), "--overwrite"]) == EXIT_INPUT
    assert "the input" in capsys.readouterr().err
    assert not (data / "ASPHALT" / "run_00").exists()


def test_withheld_generator_replaces_only_its_own_suite(tmp_path: Path) -> None:
    """The withheld-suite generator removes ``bags/`` only in a directory it created itself."""
    from terrain_estimation.outputs import OutputExistsError, prepare_output_dir
    from vehicle_sim.tools.withheld import generate

    foreign = tmp_path / "foreign"  # a user's directory
    (foreign / "bags").mkdir(parents=True)
    (foreign / "bags" / "mine.txt").write_text("a user's file\n")
    with pytest.raises(OutputExistsError):
        generate(foreign, [], progress=False, signatures=False)
    other = prepare_output_dir(tmp_path / "other", tool="terrain-sim2real")  # another project tool's
    (other / "bags").mkdir()
    (other / "bags" / "mine.txt").write_text("kept\n")
    with pytest.raises(OutputExistsError):
        generate(other, [], progress=False, signatures=False)
    assert (foreign / "bags" / "mine.txt").read_text() == "a user's file\n"
    assert (other / "bags" / "mine.txt").read_text() == "kept\n"
    own = tmp_path / "own"
    generate(own, [], progress=False, signatures=False)
    (own / "bags").mkdir(exist_ok=True)
    (own / "bags" / "old.mcap").write_text("")
    generate(own, [], progress=False, signatures=False)  # its own previous suite: replaced
    assert not (own / "bags" / "old.mcap").exists()
