"""The on-disk numba cache of a kernel follows the compiled helpers it calls in other modules.

numba keys a cached function on its own file's source only: a kernel whose
helper (in another module) changed would run the helper's old machine code
from the cache. :mod:`terrain_estimation.jit` extends the key with every
module of the project that compiles with ``compiled``. Checked end to end:
two fresh processes, the helper's file changed in between, the kernel's not.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

SCRIPT = textwrap.dedent(
    """
    import sys
    from pathlib import Path

    root = Path(sys.argv[1])
    sys.path.insert(0, str(root.parent))
    import terrain_estimation.jit as jit

    jit._project_roots = lambda: (root,)  # the temporary package stands for the project's trees
    clear = getattr(getattr(jit, "kernel_sources_digest", None), "cache_clear", None)
    if clear is not None:
        clear()
    from kernels_under_test import kernel

    print(kernel.outer(1.0))
    """
)


def _write(path: Path, text: str) -> None:
    path.write_text(textwrap.dedent(text))


def _run(root: Path) -> float:
    env = dict(os.environ)
    env.pop("NUMBA_CACHE_DIR", None)  # the cache beside the source, in root/__pycache__
    env.pop("NUMBA_DISABLE_JIT", None)
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(root)], capture_output=True, text=True, env=env, timeout=300, check=True
    )
    return float(out.stdout.strip().splitlines()[-1])


def test_a_kernel_recompiles_when_only_its_helper_module_changes(tmp_path: Path) -> None:
    root = tmp_path / "kernels_under_test"
    root.mkdir()
    (root / "__init__.py").write_text("")
    helper = """
        from terrain_estimation.jit import compiled


        @compiled
        def inner(x):
            return x + {value}
        """
    _write(root / "helper.py", helper.format(value="1.0"))
    _write(
        root / "kernel.py",
        """
        from terrain_estimation.jit import compiled
        from kernels_under_test.helper import inner


        @compiled
        def outer(x):
            return inner(x) * 10.0
        """,
    )
    assert _run(root) == 20.0
    assert any((root / "__pycache__").glob("kernel.outer-*.nbi")), "the kernel was not cached"
    _write(root / "helper.py", helper.format(value="2.0"))  # the kernel's own file is unchanged
    assert _run(root) == 30.0, "the kernel ran its helper's old machine code from the cache"


def test_the_key_covers_the_simulator_and_analysis_kernels() -> None:
    import terrain_estimation.jit as jit

    names = {root.name for root in jit._project_roots()}
    assert {"terrain_estimation", "terrain_analysis", "vehicle_sim"} <= names
