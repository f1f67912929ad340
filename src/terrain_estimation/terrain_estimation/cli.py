"""Exit statuses and error handling shared by every command-line tool of the project.

Every CLI (``terrain-estimate``, ``terrain-simulate``, ``terrain-sim2real``,
``terrain-import-borealtc``, the reproductions and benchmarks) ends with one of
these statuses, so that a script driving them can tell a finding from bad
input from a bug:

====  =====================  ==============================================================
code  name                   meaning
====  =====================  ==============================================================
0     ``EXIT_OK``            the run did what was asked and found nothing to report
1     ``EXIT_FINDING``       a result-level finding (``terrain-sim2real``: a gap was found)
2     ``EXIT_INPUT``         the input cannot be used: a missing or unreadable bag, a topic
                             of the wrong type, no usable message, a bad parameter, an
                             output path that would destroy data; nothing was written
3     ``EXIT_INTERNAL``      an internal error (a bug): the traceback is printed
130   ``EXIT_INTERRUPTED``   Ctrl-C; nothing half-written is left behind
141   ``EXIT_BROKEN_PIPE``   whoever read the output stopped reading (``| head``): quietly, as
                             a shell command killed by SIGPIPE
====  =====================  ==============================================================

:func:`run_cli` maps exceptions to these statuses, so that each tool's
``main`` holds only its own logic.
"""

from __future__ import annotations

import functools
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import Protocol

__all__ = [
    "EXIT_OK",
    "EXIT_FINDING",
    "EXIT_INPUT",
    "EXIT_INTERNAL",
    "EXIT_INTERRUPTED",
    "EXIT_BROKEN_PIPE",
    "InputError",
    "cli_main",
    "input_errors",
    "run_cli",
]

EXIT_OK = 0
EXIT_FINDING = 1
EXIT_INPUT = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141


class InputError(ValueError):
    """The user's input cannot be used (exit status 2); the message says what, where and why."""


def input_errors() -> tuple[type[BaseException], ...]:
    """The exception types that mean "the input cannot be used" (exit status 2)."""
    from terrain_estimation.bag import BagError
    from terrain_estimation.params import ParameterError

    return (InputError, BagError, ParameterError, ValueError, FileExistsError, FileNotFoundError)


def run_cli(prog: str, body: Callable[[], int], *, interrupted: str = "interrupted") -> int:
    """Run a tool's ``body`` and turn what it raises into the project's exit statuses.

    Args:
        prog: the tool's name, the prefix of its error lines.
        body: the tool's work; returns ``EXIT_OK`` or ``EXIT_FINDING``.
        interrupted: what the tool says on Ctrl-C (e.g. "no output bag written").
    """
    try:
        return body()
    except input_errors() as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print(f"{prog}: {interrupted}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # stdout's reader has gone: point stdout at nothing so that the interpreter's final flush is quiet too
        import contextlib
        import os

        with contextlib.suppress(OSError, ValueError):  # not a real file (captured): nothing to flush
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except Exception:  # a bug: say so, with the traceback, and never exit 1 (a "finding")
        traceback.print_exc()
        print(f"{prog}: internal error (a bug: please report it with the traceback above)", file=sys.stderr)
        return EXIT_INTERNAL


class Main(Protocol):
    """A tool's entry point: ``main(argv=None) -> exit status``."""

    def __call__(self, argv: Sequence[str] | None = None, /) -> int: ...


def cli_main(prog: str) -> Callable[[Main], Main]:
    """Decorate a tool's ``main(argv)`` so that what it raises ends in the project's exit statuses (:func:`run_cli`)."""

    def decorate(main: Main) -> Main:
        @functools.wraps(main)
        def wrapped(argv: Sequence[str] | None = None, /) -> int:
            return run_cli(prog, lambda: main(argv))

        return wrapped

    return decorate
