"""A stopped sweep closes every job's log before its launcher kills the job processes.

``slot run -m`` runs its jobs in the joblib launcher's worker processes. When the
parent takes SIGINT or SIGTERM, joblib ends its workers with SIGKILL at once, so a
job's MCAP log would be cut off wherever the job was. Instead the parent passes the
signal on to its child processes (each job stops at its next MPC step, closes its
log and exits: :func:`is_sweep_worker`), waits for them, and only then unwinds.
Children that ignore the signal (joblib's resource tracker) are not waited for.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from pathlib import Path

from .simulation import STOP_SIGNALS, Interrupted

PARENT_ENV = "SLOT_SWEEP_PARENT"  # the sweep's parent PID, inherited by its job processes
GRACE_S = 20.0  # longest wait for the jobs to close their logs; then the launcher kills what is left


def child_processes(pid: int) -> list[int]:
    """Direct child processes of ``pid``, zombies left out (Linux ``/proc``; elsewhere none are found)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = stat.read_text().rpartition(")")[2].split()
            if int(fields[1]) == pid and fields[0] != "Z":
                out.append(int(stat.parent.name))
    return out


def _takes(pid: int, signum: int) -> bool:
    """Whether process ``pid`` is alive, not a zombie, and does not ignore ``signum``."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    fields = dict(line.split(":", 1) for line in text.splitlines() if ":" in line)
    if fields.get("State", "").strip().startswith("Z"):
        return False
    ignored = int(fields.get("SigIgn", "0").strip() or "0", 16)
    return not (ignored >> (signum - 1)) & 1


def stop_jobs(signum: int, frame=None) -> None:
    """Signal handler of a sweep's parent: pass ``signum`` on, wait for the jobs to close, then unwind."""
    jobs = [pid for pid in child_processes(os.getpid()) if _takes(pid, signum)]
    for pid in jobs:
        with contextlib.suppress(OSError):
            os.kill(pid, signum)
    deadline = time.monotonic() + GRACE_S
    while time.monotonic() < deadline and any(_takes(pid, signum) for pid in jobs):
        time.sleep(0.05)
    raise Interrupted(signum)


def become_sweep_parent() -> None:
    """In ``slot run -m``: mark this process as the jobs' parent and stop them with :func:`stop_jobs`."""
    os.environ[PARENT_ENV] = str(os.getpid())
    for signum in STOP_SIGNALS:
        if signal.getsignal(signum) is not signal.SIG_IGN:
            signal.signal(signum, stop_jobs)


def is_sweep_worker() -> bool:
    """Whether this process runs a sweep's job on the parent's behalf (a launcher worker, not the parent)."""
    parent = os.environ.get(PARENT_ENV)
    return parent is not None and parent != str(os.getpid())
