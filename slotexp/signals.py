"""Stop signals, in one place: which ones, how a run takes them, and how a sweep's parent passes them on.

- :data:`STOP_SIGNALS`: Ctrl-C (SIGINT), SIGTERM (a timeout, SLURM, systemd) and SIGHUP (a closed
  terminal, a dropped SSH connection) end every command the same way.
- :func:`interrupts_between_steps`: a simulated run takes a stop signal
  between two MPC steps (or stages of its setup), never inside a compiled kernel, and raises
  :class:`~slotexp.errors.Interrupted` there, so its log closes.
- :class:`StopFlag`: the hardware loop's version: the first signal asks it to stop at
  the next cycle (torque off, log closed), a second raises at once, unless the shutdown
  (torque off) has begun: nothing interrupts that.
- ``slot run -m``: the joblib launcher ends its workers with SIGKILL when the parent
  stops, which would cut each job's MCAP log wherever it was. The parent
  (:func:`become_sweep_parent`) passes the signal on to its child processes instead
  (:func:`stop_jobs`); each job stops at its next MPC step, closes its log and exits
  (:func:`is_sweep_worker`); the parent waits for them, then unwinds. Child processes
  come from ``psutil`` (any platform); children that ignore the signal (joblib's resource
  tracker) are not waited for where the platform says so (Linux's signal mask), and
  elsewhere the wait ends after :data:`GRACE_S`.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import psutil

from .errors import Interrupted

# Ctrl-C; timeout, SLURM, systemd; a closed terminal or a dropped SSH connection
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
PARENT_ENV = "SLOT_SWEEP_PARENT"  # the sweep's parent PID, inherited by its job processes
GRACE_S = 20.0  # longest wait for the jobs to close their logs; then the launcher kills what is left


_pending: list[int] | None = None  # the stop signals taken while :func:`interrupts_between_steps` is active


@contextmanager
def interrupts_between_steps() -> Iterator[Callable[[], None]]:
    """Take the stop signals (SIGINT, SIGTERM, SIGHUP) at the points the caller checks, never inside a compiled kernel.

    Python raises KeyboardInterrupt wherever the interpreter happens to be; inside a
    numba kernel's call back into Python it surfaces as a ``SystemError`` instead,
    which no handler expects, and SIGTERM's and SIGHUP's defaults end the process with the
    log unfinished. While this is active, a stop signal only sets a flag, and the
    function it yields raises :class:`Interrupted` at the next check (between MPC steps,
    and between the stages of setting a run up), so the caller's ``with`` blocks close their logs.

    Nested uses share one flag: a run's log holder opens it before the log and the loop inside opens it
    again, so a signal that arrives while the kernels compile, before the first step, is taken at the
    first check rather than by the default action (which would leave the log without its summary).
    Outside the main thread it does nothing; a signal that is ignored stays ignored.
    """
    global _pending
    if threading.current_thread() is not threading.main_thread():
        yield lambda: None
        return
    pending = _pending

    def check() -> None:
        if pending:
            raise Interrupted(pending[0])

    if pending is not None:  # nested: the outer use holds the handlers and checks once more at its end
        yield check
        return
    pending = _pending = []
    previous = {}
    for signum in STOP_SIGNALS:
        if signal.getsignal(signum) is not signal.SIG_IGN:
            previous[signum] = signal.signal(signum, lambda num, frame: pending.append(num))
    try:
        yield check
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        _pending = None
    check()


class StopFlag:
    """A stop signal as a request to stop the hardware loop at the next cycle boundary.

    Why not let SIGINT raise KeyboardInterrupt anywhere: an exception in the middle of
    a dynamixel-sdk transaction can leave the port half-used; stopping between cycles
    keeps the shutdown (torque off on every servo, log closed) on a known path. A
    second signal raises KeyboardInterrupt at once, for a loop stuck in a long solve;
    the caller's ``finally`` still turns the torque off. Once the caller has begun that
    shutdown (:meth:`shutting_down`), further signals are only noted: a second Ctrl-C,
    or the SIGHUP and SIGTERM a closing terminal sends one after the other, must not cut
    the torque-off writes short.

    SIGINT and SIGTERM are taken even where the process was started ignoring them (the
    robot must stop when asked). SIGHUP is left ignored where it was (``nohup slot
    hardware`` asks the run to outlive its terminal); otherwise it stops the run too.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._shutting_down = False

    @property
    def requested(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else ""

    def shutting_down(self) -> None:
        """From now on a signal is not an exception: the torque-off path runs to its end."""
        self._shutting_down = True

    def _handle(self, signum: int, _frame: object) -> None:
        if self.signum is None:
            self.signum = signum
        elif not self._shutting_down:
            raise KeyboardInterrupt

    @contextmanager
    def installed(self) -> Iterator[StopFlag]:
        """Install the handlers (main thread only) and restore the previous ones afterwards."""
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
        for s in STOP_SIGNALS:
            if not (s == signal.SIGHUP and previous[s] is signal.SIG_IGN):
                signal.signal(s, self._handle)
        try:
            yield self
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)


def exit_code(signum: int) -> int:
    """128 + the signal's number, the shell's convention (SIGINT 130, SIGTERM 143, SIGHUP 129)."""
    return 128 + int(signum)


# --------------------------------------------------------------------------- a sweep's parent and its jobs
def child_processes(pid: int) -> list[int]:
    """Direct child processes of ``pid`` that are alive (zombies left out)."""
    try:
        children = psutil.Process(pid).children(recursive=False)
    except psutil.Error:
        return []
    out = []
    for child in children:
        with contextlib.suppress(psutil.Error):
            if child.status() != psutil.STATUS_ZOMBIE:
                out.append(child.pid)
    return out


def _ignores(pid: int, signum: int) -> bool:
    """Whether process ``pid`` ignores ``signum``, where the platform tells (Linux's SigIgn mask); False
    elsewhere (psutil has no signal masks), so such a process is waited for until :data:`GRACE_S`."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    for line in text.splitlines():
        if line.startswith("SigIgn:"):
            return bool((int(line.split(":", 1)[1].strip() or "0", 16) >> (signum - 1)) & 1)
    return False


def _takes(pid: int, signum: int) -> bool:
    """Whether process ``pid`` is alive, not a zombie, and does not ignore ``signum``."""
    try:
        if psutil.Process(pid).status() == psutil.STATUS_ZOMBIE:
            return False
    except psutil.Error:
        return False
    return not _ignores(pid, signum)


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


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent: int | None = None) -> None:
    """Have the kernel send this process SIGTERM when its parent dies, however it dies (SIGKILL included), so
    a sweep's or a search's workers never outlive the command that started them. Linux only (``prctl``); a
    no-op elsewhere. If the parent (``parent``, or the one we have now) is already gone, stop at once.

    Why not polling the parent: a worker deep in a compiled kernel polls nothing; the kernel's signal arrives
    anyway, and a sweep's job takes SIGTERM between MPC steps, closing its log."""
    expected = os.getppid() if parent is None else parent
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: the parent's own handlers still stop its workers
        return
    if os.getppid() != expected:  # the parent died before the request was in place
        os.kill(os.getpid(), signal.SIGTERM)


def is_sweep_worker() -> bool:
    """Whether this process runs a sweep's job on the parent's behalf (a launcher worker, not the parent)."""
    parent = os.environ.get(PARENT_ENV)
    return parent is not None and parent != str(os.getpid())
