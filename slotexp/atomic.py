"""Outputs a reader never sees half-written: each goes to a temporary file beside its target and is
renamed over it (``os.replace``, atomic on one file system) only once complete. A run stopped while
writing its tables leaves the previous file or none, never a torn one."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary path (same directory, same suffix) to write; it becomes ``path`` when the block ends."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text(path: str | Path, text: str) -> Path:
    with replacing(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_csv(frame: Any, path: str | Path, **options: Any) -> Path:
    """``frame.to_csv(path, **options)``, atomically (a pandas DataFrame)."""
    with replacing(path) as tmp:
        frame.to_csv(tmp, **options)
    return Path(path)
