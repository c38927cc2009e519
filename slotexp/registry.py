"""One registry per kind of variant (QP backend, plant, experiment): a new variant is one module plus its YAML.

A variant is a module of the registry's package named after the variant
(``slotexp/backends/daqp.py`` is ``solver=daqp``); importing it registers its
object with :meth:`Registry.register`. Modules whose names start with ``_`` hold
shared code, not variants. Names are read from the package listing without
importing anything, so checking a config stays cheap; a variant's module (and
its heavy dependencies: CVXPY, numba kernels) is imported only when it is used.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from typing import Generic, TypeVar

from .errors import ConfigError

T = TypeVar("T")


class Registry(Generic[T]):
    """Variants of one kind, keyed by the name of the module that defines each."""

    def __init__(self, package: str, kind: str) -> None:
        self.package = package
        self.kind = kind
        self._entries: dict[str, T] = {}

    def names(self) -> tuple[str, ...]:
        """Every variant's name, from the package's modules (nothing is imported)."""
        path = importlib.import_module(self.package).__path__
        return tuple(sorted(m.name for m in pkgutil.iter_modules(path) if not m.name.startswith("_")))

    def register(self, name: str | None = None) -> Callable[[T], T]:
        """Decorator: register ``obj`` under ``name`` (default: the defining module's name)."""

        def wrap(obj: T) -> T:
            key = name or obj.__module__.rsplit(".", 1)[-1]
            self._entries[key] = obj
            return obj

        return wrap

    def add(self, name: str, obj: T) -> T:
        """Register ``obj`` under ``name`` (for objects a decorator cannot reach)."""
        self._entries[name] = obj
        return obj

    def get(self, name: str) -> T:
        """The variant ``name``, importing its module on first use."""
        if name not in self._entries:
            if name not in self.names():
                raise ConfigError(f"unknown {self.kind} {name!r}: choose one of {', '.join(self.names())}")
            importlib.import_module(f"{self.package}.{name}")
        if name not in self._entries:  # pragma: no cover - a module that forgot to register
            raise ConfigError(f"{self.package}.{name} defines no {self.kind}: it must register one")
        return self._entries[name]

    def load_all(self) -> dict[str, T]:
        """Import every variant (for listings that need the objects themselves)."""
        for name in self.names():
            self.get(name)
        return {name: self._entries[name] for name in self.names()}
