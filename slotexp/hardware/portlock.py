"""The servo bus's serial port, claimed by one run at a time.

Two processes on one RS-485 bus interleave their packets: each sees the other's
replies as corrupt, one may command goal positions while the other turns the
torque off, and the second's ``reset_input_buffer`` flushes replies the first is
waiting for. So ``slot hardware`` takes an exclusive ``flock`` on the port before
dynamixel-sdk opens it and holds it until the port is closed; a second run (or
any tool that locks the same way, such as pyserial's ``exclusive=True``) is
refused in one line naming the holder. The lock belongs to the open file, so it
is released by the kernel however the holder ends, SIGKILL included: no stale
lock file to clean up. It is advisory: a program that opens the port without
locking it is not stopped (the same holds for pyserial's own exclusive mode).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from ..errors import UserError

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows opens a COM port exclusively by itself
    fcntl = None


class PortLock:
    """An exclusive, non-blocking ``flock`` on a serial port's device, held until :meth:`release`."""

    def __init__(self, port: str) -> None:
        self.port = port
        self._fd: int | None = None

    def acquire(self) -> None:
        """Claim the port, or raise :class:`UserError` naming the process that holds it."""
        if fcntl is None or self._fd is not None:
            return
        try:
            fd = os.open(self.port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError as exc:
            raise UserError(f"cannot open serial port {self.port}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _holder(fd)
            os.close(fd)
            raise UserError(
                f"serial port {self.port} is in use by another process{holder}: one run drives the servos at a "
                f"time; stop that one first (or set hardware.port=...)"
            ) from None
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)  # closing the file releases its lock
            self._fd = None

    @property
    def held(self) -> bool:
        return self._fd is not None


def _holder(fd: int) -> str:
    """`` (PID n, name)`` of the process holding a flock on ``fd``'s file, where Linux's /proc/locks says; else ''."""
    try:
        st = os.fstat(fd)
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return ""
    device = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for line in lines:
        fields = line.split()
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[5] == device and fields[4].isdigit():
            pid = int(fields[4])
            try:
                import psutil

                process = psutil.Process(pid)
                words = " ".join(Path(a).name for a in process.cmdline()[:3]) or process.name()
                return f" (PID {pid}: {words})"
            except Exception:  # gone meanwhile, or not ours to read
                return f" (PID {pid})"
    return ""
