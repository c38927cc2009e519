"""Ctrl-C and SIGTERM become a request to stop at the next cycle boundary.

Why not let SIGINT raise KeyboardInterrupt anywhere: an exception in the middle of
a dynamixel-sdk transaction can leave the port half-used; stopping between cycles
keeps the shutdown (torque off on every servo, log closed) on a known path. A
second signal raises KeyboardInterrupt at once, for a loop stuck in a long solve;
the caller's ``finally`` still turns the torque off.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from ..simulation import STOP_SIGNALS


class StopFlag:
    def __init__(self) -> None:
        self.signum: int | None = None

    @property
    def requested(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else ""

    def _handle(self, signum: int, _frame: object) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum

    @contextmanager
    def installed(self) -> Iterator[StopFlag]:
        """Install the handlers (main thread only) and restore the previous ones afterwards."""
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
        for s in STOP_SIGNALS:
            signal.signal(s, self._handle)
        try:
            yield self
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)
