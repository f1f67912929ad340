"""numba's ``njit`` with its on-disk cache, or without it where numba finds no place to write one.

The project compiles a few hot loops with numba: the soil-stiffness
estimator's SCKF step (``estimators.soil_stiffness_sckf``) and the
sim-to-real replays (``sim2real``). ``njit(cache=True)`` keeps the machine
code beside the module, else under the user's cache directory or
``NUMBA_CACHE_DIR``; with none of them writable (a read-only install and
home, as on some on-board computers) it raises at import. :func:`compiled`
then warns once per process and compiles without the cache: the functions
work, at the price of compiling them in every process (seconds each time).

numba keys a function's cached machine code on the source of the function's
own file only. A kernel that calls a compiled helper in another module (the
skid-steer and soil-stiffness steps call :mod:`terrain_estimation.filters.compiled_linalg`
and each other's kernels) would keep running the helper's old code after an
upgrade that changed only the helper's file. So the cache of every function
under this project's source trees is keyed on its own file *and* on every
module of those trees that compiles with :func:`compiled` (the text of the
modules that import it, read once per process): a change to any kernel
recompiles all kernels once (seconds), never runs stale code.
"""

from __future__ import annotations

import functools
import hashlib
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from numba import njit
from numba.core import caching

__all__ = ["compiled", "kernel_sources_digest"]

#: The project's source trees: the folder above this package holds ``terrain_estimation`` and
#: ``terrain_analysis``; ``vehicle_sim`` sits in a sibling folder of the source checkout, or beside
#: them in site-packages once installed.
_HERE = Path(__file__).resolve().parent
_MARKER = b"jit import compiled"


def _project_roots() -> tuple[Path, ...]:
    roots = [_HERE, _HERE.parent / "terrain_analysis"]
    for candidate in (_HERE.parent / "vehicle_sim", _HERE.parent.parent / "vehicle_sim" / "vehicle_sim"):
        if candidate.is_dir():
            roots.append(candidate)
    return tuple(r for r in roots if r.is_dir())


@functools.lru_cache(maxsize=1)
def kernel_sources_digest() -> bytes:
    """SHA-256 over the path and text of every module of the project that compiles with :func:`compiled`."""
    digest = hashlib.sha256()
    for root in _project_roots():
        for path in sorted(root.rglob("*.py")):
            try:
                text = path.read_bytes()
            except OSError:
                continue
            if _MARKER in text or path == Path(__file__).resolve():
                digest.update(str(path.relative_to(root.parent)).encode())
                digest.update(hashlib.sha256(text).digest())
    return digest.digest()


def _ours(py_file: str) -> bool:
    try:
        resolved = Path(py_file).resolve()
    except OSError:
        return False
    return any(resolved.is_relative_to(root) for root in _project_roots())


def _with_kernel_sources(base: type) -> type:
    """``base`` (one of numba's source-file cache locators), for this project's files only, with the
    source stamp extended by :func:`kernel_sources_digest`."""

    class Locator(base):
        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            if not _ours(py_file):
                return None
            return super().from_function(py_func, py_file)

        def get_source_stamp(self) -> Any:
            return (super().get_source_stamp(), kernel_sources_digest())

    Locator.__name__ = Locator.__qualname__ = f"Project{base.__name__}"
    return Locator


def _install_locators() -> None:
    classes = caching.CacheImpl._locator_classes
    if any(getattr(c, "__name__", "").startswith("Project") for c in classes):
        return
    ours: list[Any] = [
        _with_kernel_sources(c)
        for c in (caching.UserProvidedCacheLocator, caching.InTreeCacheLocator, caching.UserWideCacheLocator)
    ]
    classes[:0] = ours


if not os.environ.get("NUMBA_CACHE_LOCATOR_CLASSES"):
    _install_locators()

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
