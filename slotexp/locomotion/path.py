"""Path feedback for the soft legs: the gait's velocity command corrected from the path error, in the world frame.

Why a path loop. A library gait is a velocity source in the body frame, and what it makes
is not what the library measured once it is blended, steered or played on another model:
the 45/90-deg cycle blend that makes omni60 walks 5-25 deg off its command, and 20-40 %
slower, depending on how its cycles fall. ``gait_mpc`` moves the command by the MPC's
planned accelerations (``controller.velocity_gain``), which corrects that only on average:
the plan's horizontal forces are bounded by the friction cones of whichever legs the
gait's phase puts in stance, so their mean is biased too, and over 120 s of omni60 their
10-s means pointed anywhere, backwards included, while the robot fell 400 mm behind. The
path loop measures the error itself and adds

    dv_world = kp e + ki integral(e dt),    dv_body = R(-yaw) dv_world

to the command, with e the path error (desired minus measured position) averaged over the
last gait cycle (a gait surges and sways within each), yaw the cycle-mean measured yaw, and
the integral held while the command is clipped to the library's envelope (no wind-up). The
proportional part returns the robot to its line; the integral holds the direction and speed
bias of whatever blend is playing, which the blend's measured headings cannot know.

Where the envelope clips the command, the part across the path is kept whole and the part
along it gives way (:func:`_fit`): a pushed robot returns to its line first and catches up
after (scaling the whole vector left a pushed walk 14 mm off its line 12 s later).

Measured (default model, the defaults: ``controller.path_kp`` 1 /s, ``path_ki`` 0.05 /s^2,
``velocity_gain`` 0, ``attitude_trim`` 0.1 /s): omni60 at 15 mm/s, path RMSE 6.6 mm over 45 s
(14.0 before); over 120 s 36.8 mm (189 before); the 45-deg headings within 7.6 % of their
command. Behind its path the loop drives the command to the library's envelope, where a
gait at full stroke with the closed loop's offsets on top is slower than the library
measured it open loop (the 45-deg gait: 21.3 mm/s open loop at full stroke, 7.2 at 70 % of
it, 12.4 in this loop with the attitude trim at 0.2 /s), so what the envelope promises is
not always there: omni60 ends 120 s behind its pace by a few centimetres, on its line.
"""

from __future__ import annotations

from collections import deque

import numpy as np


class PathLoop:
    """PI feedback from the cycle-mean path error (m) to a world-frame velocity correction (m/s)."""

    def __init__(self, kp: float, ki: float, window_steps: int, period: float) -> None:
        self.kp, self.ki, self.period = kp, ki, period
        self.errors: deque[np.ndarray] = deque(maxlen=max(1, window_steps))
        self.yaws: deque[float] = deque(maxlen=max(1, window_steps))
        self.integral = np.zeros(2)  # m s

    @property
    def active(self) -> bool:
        return self.kp > 0.0 or self.ki > 0.0

    @property
    def error(self) -> np.ndarray:
        """The path error (m, world frame, desired minus measured) the loop acts on: the window's mean."""
        return np.mean(self.errors, axis=0) if self.errors else np.zeros(2)

    def command(self, error: np.ndarray, yaw: float, base_body: np.ndarray, clip) -> np.ndarray:
        """Take this step's path ``error`` (m, world) and measured ``yaw`` (rad); return the body-frame velocity
        command (m/s): ``base_body`` plus the correction turned into the body frame, after ``clip`` (the
        library's envelope: body-frame velocity in, velocity out)."""
        self.errors.append(np.asarray(error, float))
        self.yaws.append(float(yaw))
        e = self.error
        yaw_mean = float(np.angle(np.mean(np.exp(1j * np.asarray(self.yaws)))))
        c, s = np.cos(yaw_mean), np.sin(yaw_mean)

        def body(integral: np.ndarray) -> np.ndarray:
            w = self.kp * e + self.ki * integral
            return base_body + np.array([c * w[0] + s * w[1], -s * w[0] + c * w[1]])

        integral = self.integral + e * self.period
        wanted = body(integral)
        clipped = _fit(wanted, base_body, clip)
        # conditional integration: not while the command is clipped, unless the step unwinds the integral
        if _close(clipped, wanted) or np.linalg.norm(integral) < np.linalg.norm(self.integral):
            self.integral = integral
            return clipped
        return _fit(body(self.integral), base_body, clip)


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    """``np.allclose(a, b)`` for finite vectors of one length, its test written out: |a - b| <= 1e-8 + 1e-5 |b|
    (the same float64 operations, so the same answer, at a tenth of the cost on a planar command)."""
    return all(abs(x - y) <= 1e-8 + 1e-5 * abs(y) for x, y in zip(a, b, strict=True))


def _fit(wanted: np.ndarray, base: np.ndarray, clip) -> np.ndarray:
    """``wanted`` (body frame, m/s) brought inside the envelope ``clip`` by shortening its part along ``base``
    (the reference's direction) first, keeping the part across it whole: a robot pushed off its line and behind
    it returns to the line first and catches up after, where scaling the whole vector shrank the sideways
    correction with the forward one. Where the part across does not fit by itself, the whole is clipped."""

    def inside(v: np.ndarray) -> bool:  # the envelope leaves a command inside it exactly as it is
        c = clip(v)  # (a planar command: two comparisons cost less than np.array_equal, called ~40 times a step)
        return bool(c[0] == v[0] and c[1] == v[1])

    if inside(wanted):
        return wanted
    norm = float(np.hypot(*base))
    if norm == 0.0:
        return clip(wanted)
    u = base / norm
    along = float(wanted @ u) * u
    across = wanted - along
    if not inside(across):
        return clip(wanted)
    lo, hi = 0.0, 1.0  # the largest share of the along part that fits, by bisection (the envelope depends on direction)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if inside(across + mid * along):
            lo = mid
        else:
            hi = mid
    return across + lo * along
