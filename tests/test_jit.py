"""The kernel cache follows the kernels a kernel calls (slotexp.jit), and nothing else.

Plain ``numba.njit(cache=True)`` stamps a cached kernel with its own file only, so
after a change to a callee in another module it keeps running the stale callee.
These tests build a throw-away package whose kernel in ``b.py`` calls one in
``a.py``, compile it in one process, edit ``a.py``, and call it again in a new
process: through :func:`slotexp.jit.njit` the new result comes back.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from slotexp.jit import kernel_dependencies

REPO = Path(__file__).resolve().parents[1]


def _package(root: Path, decorator_import: str, value: int) -> None:
    pkg = root / "pkgx"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text(
        textwrap.dedent(f"""
        {decorator_import}

        SCALE = 10


        @njit(cache=True)
        def callee(x):
            return x + {value}
        """)
    )
    (pkg / "b.py").write_text(
        textwrap.dedent(f"""
        {decorator_import}
        from .a import SCALE, callee


        @njit(cache=True)
        def caller(x):
            return SCALE * callee(x)
        """)
    )
    (pkg / "c.py").write_text('"""Not a kernel module: editing it must not touch the cache."""\nNOTE = 1\n')


def _call(root: Path) -> int:
    code = "from pkgx.b import caller; print(caller(1))"
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=300,
        env={"PYTHONPATH": f"{root}:{REPO}", "PATH": "/usr/bin:/bin"},
    )
    assert out.returncode == 0, out.stderr
    return int(out.stdout.strip())


def test_a_changed_callee_in_another_module_is_recompiled(tmp_path: Path) -> None:
    _package(tmp_path, "from slotexp.jit import njit", 1)
    assert _call(tmp_path) == 20
    assert _call(tmp_path) == 20  # served from the cache
    _package(tmp_path, "from slotexp.jit import njit", 2)  # only a.py's callee changes
    assert _call(tmp_path) == 30


def test_plain_numba_cache_keeps_the_stale_callee(tmp_path: Path) -> None:
    """The failure the keyed stamp exists for (if numba ever fixes it, this test says so)."""
    _package(tmp_path, "from numba import njit", 1)
    assert _call(tmp_path) == 20
    _package(tmp_path, "from numba import njit", 2)
    assert _call(tmp_path) == 20


def test_dependencies_are_what_the_kernels_use(tmp_path: Path) -> None:
    _package(tmp_path, "from slotexp.jit import njit", 1)
    pkg = tmp_path / "pkgx"
    assert kernel_dependencies(pkg / "b.py") == [(pkg / "a.py").resolve()]
    assert kernel_dependencies(pkg / "a.py") == []
    # the project's own: the coupled kernel depends on the rigid-body and leg kernels, not on the config
    deps = {p.name for p in kernel_dependencies(REPO / "slotexp" / "soft" / "coupled.py")}
    assert {"body.py", "integrators.py", "loads.py"} <= deps and "config.py" not in deps and "cli.py" not in deps


def test_a_kernel_compiles_and_caches_in_the_temporary_directory_when_nothing_else_is_writable(
    tmp_path: Path,
) -> None:
    # A read-only install and a read-only home: the in-tree and user-wide caches cannot be written (made so
    # here by numba's writability check failing there, since the tests may run as root, whom file modes do
    # not stop). numba alone then refuses to compile a cached kernel ("no locator available"); slotexp's last
    # locator caches it under the temporary directory.
    _package(tmp_path, "from slotexp.jit import njit", 1)
    script = textwrap.dedent("""
        import sys, tempfile
        tempfile.tempdir = sys.argv[1]
        from numba.core import caching
        import slotexp.jit
        writable = caching._CacheLocator.ensure_cache_path
        def ensure(self):  # nothing can be written but the temporary directory
            if not self.get_cache_path().startswith(sys.argv[1]):
                raise OSError(30, "Read-only file system")
            writable(self)
        caching._CacheLocator.ensure_cache_path = ensure
        from pkgx.b import caller
        print(caller(1))
        """)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    for _ in range(2):  # compiled and cached, then loaded from the cache
        proc = subprocess.run(
            [sys.executable, "-c", script, str(tmp)], cwd=tmp_path, capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.split() == ["20"] and "NumbaWarning" not in proc.stderr
    cached = list(tmp.glob("slotexp-numba-*/**/*.nbi"))
    assert {p.name.split(".")[0] for p in cached} == {"a", "b"}
    assert not list((tmp_path / "pkgx").glob("__pycache__/*.nbi"))  # nothing in the tree


def test_a_kernel_without_the_runtime_borrows_views_and_gives_the_same_numbers() -> None:
    """``allocates=False`` kernels (the soft plant's step) take array views and tuples of arrays without
    counting references; what they compute is their Python function's."""
    import numpy as np

    from slotexp.jit import njit

    def axpy_rows(pair, a, out):
        x, y = pair
        for i in range(x.shape[0]):
            row = x[i]  # a view, borrowed
            for j in range(row.shape[0]):
                out[i, j] = a * row[j] + y[i, j]
        return out[0, 0]

    kernel = njit(cache=False, allocates=False)(axpy_rows)
    rng = np.random.default_rng(3)
    x, y = rng.normal(size=(5, 4)), rng.normal(size=(5, 4))
    got, want = np.zeros((5, 4)), np.zeros((5, 4))
    assert kernel((x[1:], y[1:]), 0.7, got[1:]) == axpy_rows((x[1:], y[1:]), 0.7, want[1:])
    assert np.array_equal(got, want)


def test_a_kernel_that_claims_not_to_allocate_but_does_is_refused() -> None:
    """It does not compile (rather than leak or free what it was lent)."""
    import numpy as np
    import pytest
    from numba.core.errors import NumbaError

    from slotexp.jit import njit

    @njit(cache=False, allocates=False)
    def copies(x):
        y = np.empty_like(x)
        y[:] = x
        return y[0]

    with pytest.raises(NumbaError):
        copies(np.ones(3))
