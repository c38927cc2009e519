"""``njit``: numba's cached compilation, with the cache keyed on the kernels a kernel calls.

numba's ``cache=True`` stamps a cached kernel with its own file's source only. A
kernel that calls a kernel in another module (``coupled_steps`` calls the leg
step, which calls the rod's forces) would then run a stale callee after the
callee's module changes. Functions compiled through :func:`njit` get a stamp that
also covers every module their kernels take a name from (functions and constants
alike, found by reading the import statements and the kernels' bodies), and so on
through those modules' kernels. So:

- an edit to a kernel or to anything a kernel uses recompiles exactly the kernels
  that depend on it, once;
- an edit anywhere else (a docstring in ``figures/``, the CLI, a config schema)
  recompiles nothing;
- the cache stays where numba keeps it (``__pycache__`` beside the source, or
  numba's user-wide cache, or ``NUMBA_CACHE_DIR`` when set), and other libraries'
  kernels are left alone: the locator below only takes functions compiled here;
- where none of those can be written (a read-only install and home), the kernels are
  cached under the system's temporary directory instead of failing to compile.

The locators extend numba's own (``numba.core.caching``), inserted ahead of them in
its list of locator classes; nothing is set in the environment.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
from numba.core.caching import CacheImpl, InTreeCacheLocator, UserProvidedCacheLocator, UserWideCacheLocator

__all__ = ["njit", "kernel_dependencies"]

_MARK = "_slotexp_keyed_cache"
_DECORATORS = {"njit", "jit", "vectorize", "guvectorize", "stencil"}


def njit(fn: Callable | None = None, *, allocates: bool = True, **options: Any) -> Any:
    """``numba.njit`` with ``cache=True`` (unless told otherwise) and the dependency-keyed stamp.

    Use as ``@njit`` or ``@njit(fastmath=True, ...)``.

    ``allocates=False`` compiles a kernel that creates no array (and returns none) without numba's runtime:
    the arrays it unpacks from a tuple, slices or passes on are then borrowed, where the runtime counts a
    reference to each with an atomic add and takes it back at the end. In the soft plant's step that
    counting was a third of the kernels' time (``perf``: numba's ``NRT_incref``/``NRT_decref``), and the
    step's own arithmetic is unchanged by it, bit for bit. A kernel so compiled that allocates (``np.empty``,
    a slice copied onto a slice, ``np.linalg``) does not compile, nor does one that calls a kernel that
    allocates: every kernel it calls must be ``allocates=False`` too. (numba's option for it is ``_nrt``.)
    """
    options.setdefault("cache", True)
    if not allocates:
        options["_nrt"] = False

    def compile_(function: Callable) -> Any:
        setattr(function, _MARK, True)
        return numba.njit(**options)(function)

    return compile_ if fn is None else compile_(fn)


# --------------------------------------------------------------------------- what a module's kernels use
def _package_root(path: Path) -> Path:
    """The top directory of the package ``path`` belongs to (the last parent with an ``__init__.py``)."""
    root = path.parent
    while (root.parent / "__init__.py").is_file():
        root = root.parent
    return root


def _module_file(base: Path, dotted: str) -> Path | None:
    target = base.joinpath(*dotted.split(".")) if dotted else base
    for candidate in (target.with_suffix(".py"), target / "__init__.py"):
        if candidate.is_file():
            return candidate.resolve()
    return None


def _is_kernel(node: ast.AST) -> bool:
    if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
        return False
    for dec in node.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in _DECORATORS:
            return True
    return False


@functools.cache
def _direct_dependencies(path: Path, mtime_ns: int, size: int) -> frozenset[Path]:
    """Files of the package that this module's kernels take a name from (mtime/size key the memo)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    root = _package_root(path)
    here = path.parent
    imported: dict[str, Path] = {}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from .a import b / from .. import c
                base = here
                for _ in range(node.level - 1):
                    base = base.parent
                module = node.module or ""
            elif node.module and node.module.split(".")[0] == root.name:  # absolute, inside the package
                base, module = root.parent, node.module
            else:
                continue
            for alias in node.names:
                local = alias.asname or alias.name
                as_module = _module_file(base, f"{module}.{alias.name}" if module else alias.name)
                found = as_module or _module_file(base, module)
                if found is not None:
                    imported[local] = found
    used: set[str] = set()
    for node in ast.walk(tree):
        if _is_kernel(node):  # names in the body (the decorator itself is not a dependency)
            used.update(n.id for stmt in node.body for n in ast.walk(stmt) if isinstance(n, ast.Name))
    return frozenset(imported[name] for name in used if name in imported and imported[name] != path.resolve())


def kernel_dependencies(path: str | Path) -> list[Path]:
    """Every file the kernels of module ``path`` depend on, transitively (``path`` itself excluded)."""
    start = Path(path).resolve()
    seen: set[Path] = set()
    todo = [start]
    while todo:
        current = todo.pop()
        st = current.stat()
        for dep in _direct_dependencies(current, st.st_mtime_ns, st.st_size):
            if dep not in seen and dep != start:
                seen.add(dep)
                todo.append(dep)
    return sorted(seen)


def _dependency_digest(py_file: str) -> str:
    digest = hashlib.sha256()
    for dep in kernel_dependencies(py_file):
        digest.update(dep.name.encode())
        digest.update(dep.read_bytes())
    return digest.hexdigest()


# --------------------------------------------------------------------------- numba's locators, restamped
class _KeyedStamp:
    """A locator whose source stamp also covers the kernels' dependencies."""

    _py_file: str

    def get_source_stamp(self) -> Any:
        return super().get_source_stamp(), _dependency_digest(self._py_file)  # type: ignore[misc]

    @classmethod
    def from_function(cls, py_func: Callable, py_file: str) -> Any:
        if not getattr(py_func, _MARK, False):
            return None
        return super().from_function(py_func, py_file)  # type: ignore[misc]


class _UserProvided(_KeyedStamp, UserProvidedCacheLocator):
    pass


class _InTree(_KeyedStamp, InTreeCacheLocator):
    pass


class _UserWide(_KeyedStamp, UserWideCacheLocator):
    pass


class _TempDir(_UserWide):
    """The last resort, where neither the source's ``__pycache__`` nor numba's user-wide cache can be written
    (a read-only install and a read-only home): the system's temporary directory, per user. Without it numba
    refuses to compile a cached kernel at all ("no locator available")."""

    def __init__(self, py_func: Callable, py_file: str) -> None:
        super().__init__(py_func, py_file)
        root = Path(tempfile.gettempdir()) / f"slotexp-numba-{os.getuid() if hasattr(os, 'getuid') else 'user'}"
        self._cache_path = str(root / self.get_suitable_cache_subpath(py_file))


def _install() -> None:
    locators = CacheImpl._locator_classes
    if _InTree not in locators:
        # numba's own order (NUMBA_CACHE_DIR first), then the temporary directory
        locators[0:0] = [_UserProvided, _InTree, _UserWide, _TempDir]


_install()
