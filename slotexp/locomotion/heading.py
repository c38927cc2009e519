"""Heading feedback for the soft legs: the body leans onto one side of its travel to turn.

Why a lean, and not a turning gait mixed in. A soft leg moves its foot only in its own
vertical plane; out of that plane it is rigid, so while the torso translates at velocity
v every foot slides across its leg's plane at v . n_i, and Coulomb friction there pushes
back with mu N_i. The foot of a leg pointing out at alpha_i, a distance R from the body
centre, gives the torso a yaw moment

    M_i = R mu N_i sign(sin(alpha_i - h))        (h: the direction of travel)

(the across-plane unit vector n_i = (-sin alpha_i, cos alpha_i) is perpendicular to the
foot's radius, so its moment arm is R). With equal loads the four cancel; loading the
legs on the left of the direction of travel more than those on its right turns the
robot left, by a moment proportional to mu and to the load shifted. Each leg's normal
force rises with its tendon (eq. 11), so the actuator is a tendon offset of
``lean * side_i(h)`` with side_i proportional to sin(alpha_i - h).

That braking is not the lean's only effect. The loaded side's feet also grip better in
stance and push the body along harder, which turns it away from the loaded side: the
opposite sign. Which wins depends on the model. Measured (closed loop, a constant lean,
the forward walk at 20 mm/s, yaw rate per degree of lean over -8..+8 deg): the default
model +0.02 deg/s, friction 0.4 +0.017, friction 0.2 with E 1.4e7 Pa and damping 10 /s
-0.03 (its lateral walk -0.023), E 2e7 Pa with damping 5 /s about zero. So the loop does
not assume the sign: it learns it (below). Everything else tried yawed the robot
erratically: mixing the turning primitive into a walking one (its sign at r = 0.1 changed
with the turning gait's timing), stroke asymmetry between the sides, base offsets, a
twist of the diagonals.

The loop: a PI controller on the heading error averaged over the last gait cycles (the
gait rocks the body by about a degree within each cycle, and a blend of two gaits by more
from one cycle to the next), its output the lean in degrees of tendon, clipped to
``max_lean_deg`` with conditional integration (no wind-up). Its integral holds the lean
that cancels a gait's own yaw drift. Standing still there is no sliding and so no
authority: below ``MIN_SPEED`` the integral is held.

The deadband (``deadband_deg``): the loop acts only on the cycle-mean error beyond it, and inside it
the integral holds the lean where it is. On the default model the lean's authority is a few hundredths
of a degree per second per degree and not monotone in the lean, so holding the heading to a fraction of
a degree costs leans of several degrees, which roll the body by one to two degrees; which of its two
stable leans the loop then finds moves with the start-up, the plant's step and the mesh
(docs/results/plant.md). A band leaves those fractions alone. A steady drift still ends cancelled by the
integral, with the heading held at the band's edge instead of on the reference. Off by default: on the
stiff model's omni60 the lean it winds once the band is crossed misled the sign learner into a wrong flip.

The lean's sign (``learn_sign``): each gait cycle gives one sample, the cycle's mean lean
and the heading error's rate over the cycle (measured at the same phase, so the gait's
rocking cancels). A least-squares line through the last ``SIGN_WINDOW_CYCLES`` samples
estimates the lean's authority b (deg/s per deg). When it is significant (``SIGN_T``
standard errors) against the sign the loop assumes, and the lean moved by at least
``SIGN_SPREAD`` of its reach in that window (so the evidence is the loop's own large
moves, not noise around an equilibrium), the loop flips its sign; the integral is kept,
so the lean reverses at once. Near its equilibrium the lean hardly moves and nothing is
decided; with the right sign a transient makes the same line with the right slope.
This is the textbook remedy for a control direction unknown in advance (a switching
supervisor); no dither is needed, because a wrong sign winds the lean fast. While whole
cycles of two primitives alternate (``judge_sign`` false), their own yaw rates move the
heading more than the lean does, and no cycle is a sample. Tried and dropped: trying the
other sign when the lean sits at its limit with the error still growing (the fit sees no
spread there). On the sampled models it changed little; on the default model's
15 mm/s forward walk, where the right sign is too weak at 15 mm/s, its one trial turned a
heading that recovered into one that did not. Measured on the low-friction model's
forward walk: the sign flips 7.5 s in at a heading error of -1.1 deg, and the heading then
holds within 1.1 deg (without: -10.2 deg in 30 s).
"""

from __future__ import annotations

from collections import deque

import numpy as np

MIN_SPEED = 0.002  # m/s of commanded travel below which the lean has nothing to act through
SIGN_WINDOW_CYCLES = 12  # gait cycles of (lean, heading rate) the sign is judged on (6.4 s of the walk)
SIGN_MIN_CYCLES = 8  # no judgement on fewer
SIGN_T = 3.0  # standard errors the slope must stand from zero against the assumed sign
SIGN_SPREAD = 0.4  # of max_lean_deg: how far the lean must have moved within the window


def lean_pattern(leg_yaw: np.ndarray, heading: float) -> np.ndarray:
    """Per-leg tendon offsets (4,) for a unit lean towards the left of travel at body-frame ``heading`` (rad):
    proportional to sin(alpha_i - heading) (each foot's across-plane slip), the largest 1 (a diagonal heading
    has two legs along it, which slide only along their planes and take no share)."""
    side = np.sin(np.asarray(leg_yaw, dtype=float) - heading)
    return side / np.max(np.abs(side))


class HeadingLoop:
    """PI feedback from the heading error to the lean (deg of tendon), its sign learned; see the module docstring."""

    def __init__(
        self,
        kp: float,
        ki: float,
        max_lean_deg: float,
        period: float,
        window_steps: int,
        cycle_steps: int = 0,
        learn_sign: bool = False,
        deadband_deg: float = 0.0,
    ) -> None:
        self.kp, self.ki, self.max_lean, self.period = kp, ki, max_lean_deg, period
        self.deadband = deadband_deg  # |error| the loop leaves alone: it acts on what lies beyond it
        self.errors: deque[float] = deque(maxlen=max(1, window_steps))
        self.integral = 0.0  # deg s
        self.lean = 0.0  # deg of tendon
        self.sign = 1.0  # +1: a positive lean turns the robot left (the braking mechanism); learned if learn_sign
        self.learn_sign = learn_sign and cycle_steps > 0
        self.cycle_steps = max(1, cycle_steps)
        self.authority = float("nan")  # deg/s per deg of lean: the last window's estimate with evidence (NaN: none)
        self.flips: list[float] = []  # when (s of steering) the sign flipped
        self._samples: deque[tuple[float, float]] = deque(maxlen=SIGN_WINDOW_CYCLES)  # (mean lean, error rate)
        self._steps = 0  # steps steered
        self._anchor: float | None = None  # the error at this cycle's start
        self._lean_sum = 0.0

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

    def update(self, error_deg: float, speed: float, judge_sign: bool = True) -> float:
        """Take this step's heading error (measured minus desired yaw, deg) at commanded ``speed`` (m/s); return
        the lean (deg of tendon; positive leans left of travel, which turns the robot left if ``sign`` is +1).
        ``judge_sign`` false: this step is no evidence of the lean's sign (the gait alternates two primitives)."""
        self.errors.append(error_deg)
        if not self.steers(speed):
            self.lean = 0.0
            self._anchor = None  # a cycle interrupted by standing is no sample
            return 0.0
        if not judge_sign:
            self._anchor = None  # this cycle is no sample
        elif self.learn_sign:
            self._judge_sign(error_deg)
        e = self.error_deg
        e = float(np.sign(e)) * max(abs(e) - self.deadband, 0.0)  # inside the band: the lean holds where it is
        integral = self.integral + e * self.period
        # conditional integration: not while the output is clipped, unless the step unwinds the integral
        if abs(self.kp * e + self.ki * integral) <= self.max_lean or abs(integral) < abs(self.integral):
            self.integral = integral
        pi = float(np.clip(-(self.kp * e + self.ki * self.integral), -self.max_lean, self.max_lean))
        self.lean = self.sign * pi
        self._lean_sum += self.lean
        self._steps += 1
        return self.lean

    def _judge_sign(self, error_deg: float) -> None:
        """At each cycle's start: close the last cycle's sample, refit the authority and flip the sign on evidence."""
        if self._steps % self.cycle_steps:
            return
        if self._anchor is not None:
            cycle = self.cycle_steps * self.period
            self._samples.append((self._lean_sum / self.cycle_steps, (error_deg - self._anchor) / cycle))
            self._fit_and_flip()
        self._anchor, self._lean_sum = error_deg, 0.0

    def _fit_and_flip(self) -> None:
        if len(self._samples) < SIGN_MIN_CYCLES:
            return
        lean, rate = np.asarray(self._samples).T
        if np.ptp(lean) < SIGN_SPREAD * self.max_lean:  # the lean barely moved: no evidence either way
            return
        dl = lean - lean.mean()
        sxx = float(dl @ dl)
        b = float(dl @ rate) / sxx
        residual = rate - rate.mean() - b * dl
        se = np.sqrt(float(residual @ residual) / (len(rate) - 2) / sxx)
        self.authority = b
        if abs(b) > SIGN_T * se and np.sign(b) == -self.sign:
            self.sign = -self.sign  # the integral is kept: the lean reverses at once
            self.flips.append(self._steps * self.period)
