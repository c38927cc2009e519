"""An output directory is never silently reused or written by two runs at once.

``slot run`` (and ``slot hardware``) with an explicit ``hydra.run.dir`` takes an
exclusive lock on the directory (``.slot-run.lock``, ``fcntl.flock``: released when
the process ends, however it ends) before Hydra writes anything there, and refuses
a directory that another run is writing or that holds another run's outputs
(``logs/*.mcap``, tables, metrics), unless ``overwrite=true``: then the earlier
outputs are removed first, so that no table mixes two runs. ``slot run -m`` does
the same for an explicit ``hydra.sweep.dir`` (another sweep: its ``multirun.yaml``
and job directories). Timestamped default directories are new and are not locked.
"""

from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path
from typing import IO

from .errors import UserError

LOCK = ".slot-run.lock"
TABLES = ("table1.csv", "table1.md", "metrics.json", "fig7_cost.png", "fig8_dcm.png")  # built from a run's logs
_held: list[IO[str]] = []  # locks this process holds until it ends


def earlier_outputs(run_dir: Path) -> list[Path]:
    """What ``run_dir`` holds of another run's outputs: its logs, then what was built from them."""
    return sorted(run_dir.glob("logs/*.mcap")) + [run_dir / name for name in TABLES if (run_dir / name).exists()]


def _lock(directory: Path, key: str) -> None:
    """Take ``directory``'s lock for the rest of this process, or say that another run holds it."""
    directory.mkdir(parents=True, exist_ok=True)
    handle = open(directory / LOCK, "a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        raise UserError(
            f"{directory} is in use by another slot run: wait for it to finish, or choose another {key}"
        ) from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"{os.getpid()}\n")
    handle.flush()
    _held.append(handle)


def _refuse_or_clear(directory: Path, earlier: list[Path], overwrite: bool, what: str, key: str) -> None:
    if earlier and not overwrite:
        shown = ", ".join(p.name for p in earlier[:3]) + (", ..." if len(earlier) > 3 else "")
        raise UserError(
            f"{directory} holds another {what} ({shown}): choose another {key}, or add overwrite=true to replace them"
        )
    for path in earlier:
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)


def claim(run_dir: Path, overwrite: bool) -> None:
    """Lock ``run_dir`` for this process, and refuse (or, with ``overwrite``, clear) earlier outputs."""
    _lock(run_dir, "hydra.run.dir")
    _refuse_or_clear(run_dir, earlier_outputs(run_dir), overwrite, "run's outputs", "hydra.run.dir")


def earlier_sweep(sweep_dir: Path) -> list[Path]:
    """What ``sweep_dir`` holds of another sweep: its ``multirun.yaml`` and its jobs' directories."""
    jobs = sorted(p for p in sweep_dir.iterdir() if (p / ".hydra").is_dir()) if sweep_dir.is_dir() else []
    marker = sweep_dir / "multirun.yaml"
    return ([marker] if marker.exists() else []) + jobs


def claim_sweep(sweep_dir: Path, overwrite: bool) -> None:
    """:func:`claim` for ``slot run -m``'s ``hydra.sweep.dir``: a second sweep into it at the same time, or
    afterwards, would mix its jobs with the first's (``slot summarize`` reads every job directory)."""
    _lock(sweep_dir, "hydra.sweep.dir")
    _refuse_or_clear(sweep_dir, earlier_sweep(sweep_dir), overwrite, "sweep", "hydra.sweep.dir")
