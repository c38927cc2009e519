"""An output directory is never silently reused or written by two runs at once.

``slot run`` (and ``slot hardware``) with an explicit ``hydra.run.dir`` takes an
exclusive lock on the directory (``.slot-run.lock``, ``fcntl.flock``: released when
the process ends, however it ends) before Hydra writes anything there, and refuses
a directory that another run is writing or that holds another run's outputs
(``logs/*.mcap``, tables, metrics), unless ``overwrite=true``: then the earlier
outputs are removed first, so that no table mixes two runs. Timestamped default
directories are new and are not locked.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
from typing import IO

from .errors import UserError

LOCK = ".slot-run.lock"
TABLES = ("table1.csv", "table1.md", "metrics.json", "fig7_cost.png", "fig8_dcm.png")  # built from a run's logs
_held: list[IO[str]] = []  # locks this process holds until it ends


def earlier_outputs(run_dir: Path) -> list[Path]:
    """What ``run_dir`` holds of another run's outputs: its logs, then what was built from them."""
    return sorted(run_dir.glob("logs/*.mcap")) + [run_dir / name for name in TABLES if (run_dir / name).exists()]


def claim(run_dir: Path, overwrite: bool) -> None:
    """Lock ``run_dir`` for this process, and refuse (or, with ``overwrite``, clear) earlier outputs."""
    run_dir.mkdir(parents=True, exist_ok=True)
    handle = open(run_dir / LOCK, "a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        raise UserError(
            f"{run_dir} is in use by another slot run: wait for it to finish, or choose another hydra.run.dir"
        ) from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"{os.getpid()}\n")
    handle.flush()
    _held.append(handle)
    earlier = earlier_outputs(run_dir)
    if earlier and not overwrite:
        shown = ", ".join(p.name for p in earlier[:3]) + (", ..." if len(earlier) > 3 else "")
        raise UserError(
            f"{run_dir} holds another run's outputs ({shown}): choose another hydra.run.dir, or add overwrite=true "
            f"to replace them"
        )
    for path in earlier:
        path.unlink(missing_ok=True)
