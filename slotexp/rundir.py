"""An output directory is never silently reused, written by two runs at once, or lost to an overwrite.

Every command that writes a run's outputs claims its directory first (:func:`claim`), the one
Hydra would resolve (``slot run``: its default ``experiments/<experiment>/<time>`` or
``hydra.run.dir`` with its interpolations, made explicit for Hydra): it takes an exclusive
lock (``.slot-run.lock``, ``fcntl.flock``: released when the process ends, however it ends),
refuses a directory another process holds, and refuses one that holds anything else (another
run's outputs, or unrelated files) unless ``overwrite=true``. An overwrite deletes nothing: the
earlier contents move aside into ``.replaced/`` and are removed only when the new run
succeeds (:func:`finish`); a run that fails leaves them there, and says so. ``slot run -m``
does the same for its sweep directory. A default directory that is
taken (two runs started in the same second) gets a suffix (:func:`unique`).
"""

from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path
from typing import IO

from .errors import UserError

LOCK = ".slot-run.lock"
REPLACED = ".replaced"  # an overwritten run's outputs, until the new run succeeds
TABLES = ("table1.csv", "table1.md", "metrics.json", "fig7_cost.png", "fig8_dcm.png")  # built from a run's logs
_held: list[IO[str]] = []  # locks this process holds until it ends
_made: set[Path] = set()  # directories this process's claims created
BOOKKEEPING = (".hydra", "slot.log", LOCK)  # what a run writes into its directory before any output


def earlier_outputs(run_dir: Path) -> list[Path]:
    """What ``run_dir`` holds of another run's outputs: its logs, then what was built from them."""
    return sorted(run_dir.glob("logs/*.mcap")) + [run_dir / name for name in TABLES if (run_dir / name).exists()]


def _lock(directory: Path, key: str) -> None:
    """Take ``directory``'s lock for the rest of this process, or say that another run holds it."""
    try:
        if not directory.exists():
            _made.add(directory.resolve())
        directory.mkdir(parents=True, exist_ok=True)
        handle = open(directory / LOCK, "a+")
    except OSError as exc:  # a file in the way, a read-only file system, a name too long
        raise UserError(
            f"cannot write the output directory {directory} ({exc.strerror or exc}): choose another {key}"
        ) from None
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


def held_by_another(directory: Path) -> bool:
    """Whether a live process holds ``directory``'s lock (a run still writing there)."""
    lock = directory / LOCK
    if not lock.is_file():
        return False
    with open(lock) as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return True
        fcntl.flock(handle, fcntl.LOCK_UN)
    return False


def unique(directory: Path) -> Path:
    """``directory``, or with ``_2``, ``_3``, ... added where it is taken: for a default (timestamped) directory,
    which two runs started in the same second would share."""
    candidate, n = directory, 1
    while candidate.exists() and any(p.name != LOCK for p in candidate.iterdir()) or held_by_another(candidate):
        n += 1
        candidate = directory.with_name(f"{directory.name}_{n}")
    return candidate


def _contents(directory: Path) -> list[Path]:
    """Everything in ``directory`` but its lock and what an earlier overwrite set aside."""
    return sorted(p for p in directory.iterdir() if p.name not in (LOCK, REPLACED)) if directory.is_dir() else []


def _refuse_or_set_aside(directory: Path, earlier: list[Path], overwrite: bool, what: str, key: str) -> None:
    if earlier and not overwrite:
        shown = ", ".join(p.name for p in earlier[:3]) + (", ..." if len(earlier) > 3 else "")
        raise UserError(
            f"{directory} holds another {what} ({shown}): choose another {key}, or add overwrite=true to replace them"
        )
    if not earlier:
        return
    aside = directory / REPLACED
    if aside.exists():  # an earlier overwrite that failed: its outputs are the ones to keep
        shutil.rmtree(aside / "newer", ignore_errors=True)
        target = aside / "newer"
    else:
        target = aside
    target.mkdir(parents=True)
    for path in earlier:
        path.rename(target / path.name)


def finish(directory: Path) -> None:
    """The run in ``directory`` succeeded: what it replaced can go."""
    shutil.rmtree(directory / REPLACED, ignore_errors=True)


def drop_if_unused(directory: Path) -> bool:
    """Remove ``directory`` if this process's claim created it and it holds only what a run writes before its
    first output (Hydra's ``.hydra/``, ``slot.log``, the lock): a run that failed at once (``slot hardware``
    with no serial port) leaves nothing behind. A directory that existed before, or holds anything else (a
    log, outputs set aside by an overwrite), stays. Returns whether it went."""
    if directory.resolve() not in _made or not directory.is_dir():
        return False
    if any(p.name not in BOOKKEEPING for p in directory.iterdir()):
        return False
    shutil.rmtree(directory, ignore_errors=True)
    return not directory.exists()


def replaced(directory: Path) -> Path | None:
    """Where an overwritten run's outputs wait (``None``: nothing was replaced)."""
    aside = directory / REPLACED
    return aside if aside.exists() else None


def claim(directory: Path, overwrite: bool, key: str = "hydra.run.dir", what: str = "run's outputs") -> None:
    """Lock ``directory`` for this process, and refuse (or, with ``overwrite``, set aside) what it holds: another
    run's outputs, or with ``slot run -m`` another sweep's (its jobs would mix with this one's in ``slot
    summarize``)."""
    _lock(directory, key)
    _refuse_or_set_aside(directory, _contents(directory), overwrite, what, key)
