"""The core's error types that more than one module raises (a leaf: it imports nothing of ours).

:class:`BagError` is raised by the bag reader and writer (:mod:`terrain_estimation.bag`)
and by the output-path checks (:mod:`terrain_estimation.outputs`), whose
:class:`~terrain_estimation.outputs.OutputPathError` derives from it; the command-line
runner (:func:`terrain_estimation.cli.run_cli`) turns it into a one-line message and exit 2.
"""

from __future__ import annotations

__all__ = ["BagError"]


class BagError(RuntimeError):
    """A bag that cannot be read or written; the message says what and where."""
