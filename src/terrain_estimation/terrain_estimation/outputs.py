"""Output paths that never destroy data (issue 19: "nothing destroyed, nothing silent").

Every tool that writes checks its output path here before any work:

* :func:`check_output_path` — for an output *bag* (or a single output file):
  refuses an existing path unless ``overwrite`` is set, and even then
  replaces only a previous output of the same kind (a rosbag2 directory
  holding ``metadata.yaml`` and its ``.mcap``/``.db3`` files and nothing
  else; for ``kind="file"`` a regular file), never a directory of other
  files, never a symlink, never one of the run's inputs.
  :class:`terrain_estimation.bag.AtomicBagWriter` calls it itself.
* :func:`prepare_output_dir` — for a directory of reports or figures that a
  tool writes its own named files into: creates it (with a marker file), and
  refuses an existing non-empty directory it did not create (no marker)
  unless ``overwrite`` is set. It never deletes anything.

Both refuse an output that resolves to one of ``inputs`` (the paths the run
reads), lies inside one or contains one, with or without ``overwrite``.

Wiring a tool (``terrain-estimate``, ``terrain-sim2real``, ...)::

    parser.add_argument("--overwrite", action="store_true", help="replace a previous output")
    ...
    check_output_path(args.output, overwrite=args.overwrite, inputs=[args.bag])  # before the long work
    ...
    with AtomicBagWriter(args.output, overwrite=args.overwrite, inputs=[args.bag]) as writer: ...
    # or, for a report directory:
    out = prepare_output_dir(args.output, overwrite=args.overwrite, inputs=[args.bag], tool="terrain-sim2real")

The errors are :class:`OutputPathError` (a :class:`~terrain_estimation.errors.BagError`,
so :func:`terrain_estimation.cli.run_cli` exits 2 with the message), which
names the path and says what to do.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Literal

from terrain_estimation.errors import BagError

__all__ = [
    "BAG_STORAGE_SUFFIXES",
    "MARKER",
    "OutputExistsError",
    "OutputIsInputError",
    "OutputPathError",
    "check_inputs",
    "check_output_dir",
    "check_output_path",
    "is_bag_directory",
    "prepare_output_dir",
]

#: The file a tool leaves in an output directory it created (:func:`prepare_output_dir`).
MARKER = ".terrain-estimation-output"
#: Storage files of a rosbag2 bag (besides its metadata.yaml).
BAG_STORAGE_SUFFIXES = (".mcap", ".db3")

PathLike = str | os.PathLike[str]


class OutputPathError(BagError):
    """An output path that would destroy data or an input; nothing was written."""


class OutputExistsError(OutputPathError):
    """Something is at the output path that this run may not replace."""


class OutputIsInputError(OutputPathError):
    """The output path is, is inside, or contains one of the run's inputs."""


def is_bag_directory(path: PathLike, *, require_metadata: bool = True) -> bool:
    """True for a directory holding only a rosbag2 bag's files.

    That is ``metadata.yaml`` (required unless ``require_metadata`` is false)
    and storage files (``.mcap``/``.db3``), no sub-directory, no symlink,
    nothing else.
    """
    p = Path(path)
    if p.is_symlink() or not p.is_dir():
        return False
    entries = list(p.iterdir())
    for entry in entries:
        if entry.is_symlink() or not entry.is_file():
            return False
        if entry.name != "metadata.yaml" and entry.suffix not in BAG_STORAGE_SUFFIXES:
            return False
    has_storage = any(e.suffix in BAG_STORAGE_SUFFIXES for e in entries)
    return has_storage and (not require_metadata or (p / "metadata.yaml").is_file())


def check_inputs(path: PathLike, inputs: Iterable[PathLike]) -> None:
    """Refuse an output ``path`` that is, is inside, or contains one of ``inputs``.

    Paths are compared resolved (symlinks followed, ``..`` removed).

    Raises:
        OutputIsInputError: naming the output and the input.
    """
    out = Path(path).resolve()
    for item in inputs:
        src = Path(item).resolve()
        if out == src:
            how = "is"
        elif src in out.parents:
            how = "is inside"
        elif out in src.parents:
            how = "contains"
        else:
            continue
        raise OutputIsInputError(
            f"output {str(path)!r} {how} the input {str(item)!r}: an output never replaces or mixes "
            "with what the run reads (not even with --overwrite); choose another output path"
        )


def _listing(path: Path, limit: int = 5) -> str:
    names = sorted(p.name for p in path.iterdir())
    shown = ", ".join(names[:limit]) + (f", ... ({len(names)} entries)" if len(names) > limit else "")
    return shown or "nothing"


def check_output_path(
    path: PathLike,
    *,
    overwrite: bool = False,
    inputs: Iterable[PathLike] = (),
    kind: Literal["bag", "file"] = "bag",
) -> Path:
    """Check that writing ``path`` destroys nothing; return it as a Path. Changes nothing on disk.

    Args:
        path: the output bag directory (``kind="bag"``) or file (``kind="file"``).
        overwrite: the user's ``--overwrite``: a previous output of the same
            kind at ``path`` may be replaced. Without it any existing path is
            refused.
        inputs: every path the run reads (bags, CSV folders, parameter files).
        kind: ``"bag"``: only a rosbag2 directory (``metadata.yaml`` plus its
            ``.mcap``/``.db3`` files and nothing else) is replaceable;
            ``"file"``: only a regular file is.

    Raises:
        OutputIsInputError: the output is, is inside, or contains an input.
        OutputExistsError: the path exists and is not replaceable (the
            message says whether ``--overwrite`` would help).
    """
    p = Path(path)
    check_inputs(p, inputs)
    if not p.exists() and not p.is_symlink():
        return p
    what = "a rosbag2 bag" if kind == "bag" else "a regular file"
    if p.is_symlink():
        found = "a symlink"
    elif kind == "bag" and is_bag_directory(p):
        found = ""
    elif kind == "file" and p.is_file():
        found = ""
    elif p.is_dir():
        found = f"a directory holding {_listing(p)}"
    else:
        found = "a file" if p.is_file() else "not a regular file or directory"
    if found:
        raise OutputExistsError(
            f"output {str(p)!r} exists and is {found}, not {what} written earlier: it is never replaced "
            "(not even with --overwrite); choose another output path"
        )
    if not overwrite:
        raise OutputExistsError(
            f"output {str(p)!r} exists ({what}); pass --overwrite to replace it or choose another path"
        )
    return p


def check_output_dir(path: PathLike, *, overwrite: bool = False, inputs: Iterable[PathLike] = ()) -> Path:
    """What :func:`prepare_output_dir` refuses, refused without creating anything (before a long run).

    Raises:
        OutputIsInputError: the directory is, is inside, or contains an input.
        OutputExistsError: the path is a file, or a non-empty directory a project tool did not
            create (no :data:`MARKER`) and ``overwrite`` is not set.
    """
    p = Path(path)
    check_inputs(p, inputs)
    if p.exists() and not p.is_dir():
        raise OutputExistsError(
            f"output directory {str(p)!r} exists and is not a directory: it is never replaced; choose another path"
        )
    if p.is_dir() and not (p / MARKER).is_file() and any(p.iterdir()) and not overwrite:
        raise OutputExistsError(
            f"output directory {str(p)!r} exists, holds {_listing(p)} and was not created by a "
            "terrain-estimation tool; pass --overwrite to write into it anyway (files of the same "
            "names are replaced, nothing else is touched) or choose another path"
        )
    return p


def prepare_output_dir(
    path: PathLike,
    *,
    overwrite: bool = False,
    inputs: Iterable[PathLike] = (),
    tool: str = "terrain-estimation",
) -> Path:
    """Make ``path`` ready for a tool to write its own named files into; return it.

    A missing or empty directory is created and marked (:data:`MARKER`, a
    small text file naming ``tool``); a directory holding the marker (made
    by an earlier run of a project tool) is used as it is. A non-empty
    directory without the marker is refused unless ``overwrite``
    (:func:`check_output_dir`): then the tool's files are written among the
    others, replacing only same-named ones, and the directory is not marked.
    Nothing is ever deleted here: a tool that uses this must write only its
    own named files.

    Raises:
        OutputIsInputError, OutputExistsError: as :func:`check_output_dir`.
    """
    p = check_output_dir(path, overwrite=overwrite, inputs=inputs)
    p.mkdir(parents=True, exist_ok=True)
    if not (p / MARKER).is_file() and not any(p.iterdir()):
        (p / MARKER).write_text(f"created by {tool}: an output directory of the terrain-estimation project\n")
    return p
