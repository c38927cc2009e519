"""Outputs a reader never sees half-written: each goes to a temporary file beside its target and is
renamed over it (``os.replace``, atomic on one file system) only once complete. A run stopped while
writing its tables leaves the previous file or none, never a torn one. Outputs get the mode an ordinary
``open`` would give them (0666 less the umask), so colleagues on a shared machine can read them; JSON
is strict (``NaN`` and infinities are written ``null``), so every JSON reader parses it."""

from __future__ import annotations

import errno
import json
import math
import os
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_MODE = 0o666 & ~_umask()  # what open() would create; mkstemp makes its files 0600


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary path (same directory, same suffix) to write; it becomes ``path`` when the block ends.

    Only a regular file (or a link) is replaced: renaming over ``/dev/null`` or a named pipe would put a file
    where the device or the pipe was, for every other program on the machine."""
    path = Path(path)
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        mode = stat.S_IFREG  # a new file
    if not (stat.S_ISREG(mode) or stat.S_ISLNK(mode)):
        raise OSError(errno.EINVAL, "not a regular file (a device, a pipe or a socket): give a file name", str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.fchmod(fd, _MODE)
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


def finite_json(value: Any) -> Any:
    """``value`` with every non-finite float (numpy's included) as None, containers walked."""
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):  # numpy scalars and arrays
        return finite_json(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: str | Path, value: Any) -> Path:
    """``value`` as strict, indented JSON (non-finite numbers as null), atomically."""
    return write_text(path, json.dumps(finite_json(value), indent=2, allow_nan=False, default=float) + "\n")
