"""numba's ``njit`` with its on-disk cache, or without it where numba finds no place to write one.

The project compiles a few hot loops with numba: the soil-stiffness
estimator's SCKF step (``estimators.soil_stiffness_sckf``) and the
sim-to-real replays (``sim2real``). ``njit(cache=True)`` keeps the machine
code beside the module, else under the user's cache directory or
``NUMBA_CACHE_DIR``; with none of them writable (a read-only install and
home, as on some on-board computers) it raises at import. :func:`compiled`
then warns once per process and compiles without the cache: the functions
work, at the price of compiling them in every process (seconds each time).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

from numba import njit

__all__ = ["compiled"]

_uncached = False  # numba found no place for its cache in this process


def compiled(fn: Callable[..., Any] | None = None, **options: Any) -> Any:
    """``njit(cache=True, **options)(fn)``, or ``njit(**options)(fn)`` (with one warning per process) where numba
    has no cache location.

    Used bare (``@compiled``) or with numba's options (``@compiled(error_model="numpy")``: a float division by
    zero gives inf or NaN as in numpy instead of raising, and the division needs no zero test).
    """
    if fn is None:
        return lambda f: compiled(f, **options)
    global _uncached
    if not _uncached:
        try:
            return njit(cache=True, **options)(fn)
        except RuntimeError as exc:
            _uncached = True
            warnings.warn(
                f"{exc}; numba-compiled functions (the soil-stiffness filter step, the sim-to-real replays) "
                "are compiled in every process, seconds each time: set NUMBA_CACHE_DIR to a writable "
                "directory to keep them",
                RuntimeWarning,
                stacklevel=2,
            )
    return njit(**options)(fn)
