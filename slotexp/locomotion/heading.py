"""Heading feedback for the soft legs: the body leans onto the side it should turn towards.

Why a lean, and not a turning gait mixed in. A soft leg moves its foot only in its own
vertical plane; out of that plane it is rigid, so while the torso translates at velocity
v every foot slides across its leg's plane at v . n_i, and Coulomb friction there pushes
back with mu N_i. The foot of a leg pointing out at alpha_i, a distance R from the body
centre, gives the torso a yaw moment

    M_i = R mu N_i sign(sin(alpha_i - h))        (h: the direction of travel)

(the across-plane unit vector n_i = (-sin alpha_i, cos alpha_i) is perpendicular to the
foot's radius, so its moment arm is R). With equal loads the four cancel; loading the
legs on the left of the direction of travel more than those on its right turns the
robot left, at any heading, by a moment proportional to mu and to the load shifted.
Each leg's normal force rises with its tendon (eq. 11), so the actuator is a tendon
offset of ``lean * side_i(h)`` with side_i proportional to sin(alpha_i - h).

Measured on the soft plant (closed loop, 20 s, the default model), a constant lean turns
the forward walk at 20 mm/s monotonically, -0.17 to +0.27 deg/s for -8 to +8 deg of
tendon, with the speed within 2 %; the lateral walk the same way. Everything else tried
yawed the robot erratically: mixing the turning primitive into a walking one (its sign
at r = 0.1 changed with the turning gait's timing, and with the library's timing it was
reversed on the forward walk, so a yaw loop through it stopped that walk), stroke
asymmetry between the sides, base offsets, a twist of the diagonals. The lean's sign
follows from the friction law, not from a gait's stick-slip pattern, which is why the
loop below can rely on it across models (its strength scales with mu and the speed).

The loop: a PI controller on the heading error averaged over the last gait cycles (the
gait rocks the body by about a degree within each cycle, and a blend of two gaits by
more from one cycle to the next), its output the lean in degrees
of tendon, clipped to ``max_lean_deg`` with conditional integration (no wind-up). Its
integral holds the lean that cancels a gait's own yaw drift. Standing still there is no
sliding and so no authority: below ``MIN_SPEED`` the integral is held.
"""

from __future__ import annotations

from collections import deque

import numpy as np

MIN_SPEED = 0.002  # m/s of commanded travel below which the lean has nothing to act through


def lean_pattern(leg_yaw: np.ndarray, heading: float) -> np.ndarray:
    """Per-leg tendon offsets (4,) for a unit lean towards the left of travel at body-frame ``heading`` (rad):
    proportional to sin(alpha_i - heading) (each foot's across-plane slip), the largest 1 (a diagonal heading
    has two legs along it, which slide only along their planes and take no share)."""
    side = np.sin(np.asarray(leg_yaw, dtype=float) - heading)
    return side / np.max(np.abs(side))


class HeadingLoop:
    """PI feedback from the heading error to the lean (deg of tendon); see the module docstring."""

    def __init__(self, kp: float, ki: float, max_lean_deg: float, period: float, window_steps: int) -> None:
        self.kp, self.ki, self.max_lean, self.period = kp, ki, max_lean_deg, period
        self.errors: deque[float] = deque(maxlen=max(1, window_steps))
        self.integral = 0.0  # deg s
        self.lean = 0.0  # deg of tendon

    @property
    def active(self) -> bool:
        """Whether the loop steers at all (a gain and a reach)."""
        return self.max_lean > 0.0 and (self.kp > 0.0 or self.ki > 0.0)

    def steers(self, speed: float) -> bool:
        """Whether the loop steers at commanded ``speed`` (m/s): it is active and the robot travels."""
        return self.active and speed >= MIN_SPEED

    @property
    def error_deg(self) -> float:
        """The heading error (deg) the loop acts on: the mean over the window (the last gait cycles)."""
        return float(np.mean(self.errors)) if self.errors else 0.0

    def update(self, error_deg: float, speed: float) -> float:
        """Take this step's heading error (measured minus desired yaw, deg) at commanded ``speed`` (m/s); return
        the lean (deg of tendon; positive leans left of travel, which turns the robot left)."""
        self.errors.append(error_deg)
        if not self.steers(speed):
            self.lean = 0.0
            return 0.0
        e = self.error_deg
        integral = self.integral + e * self.period
        # conditional integration: not while the output is clipped, unless the step unwinds the integral
        if abs(self.kp * e + self.ki * integral) <= self.max_lean or abs(integral) < abs(self.integral):
            self.integral = integral
        self.lean = float(np.clip(-(self.kp * e + self.ki * self.integral), -self.max_lean, self.max_lean))
        return self.lean
