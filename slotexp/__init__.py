"""slotexp: reproduce and extend the SLOT soft-quadruped convex-MPC paper."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__version__ = "0.1.0"


def _numba_cache_dir() -> str:
    """A numba cache directory keyed by the package's source.

    numba's ``cache=True`` checks only the timestamp of the file that defines a
    function, not of the functions it calls in other modules, so after an update a
    cached kernel could run stale callees. Keying the cache on a hash of every source
    file makes any change recompile, once.
    """
    root = Path(__file__).resolve().parent
    digest = hashlib.sha1()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "slotexp" / "numba"
    return str(base / digest.hexdigest()[:16])


if "NUMBA_CACHE_DIR" not in os.environ:
    os.environ["NUMBA_CACHE_DIR"] = _numba_cache_dir()
