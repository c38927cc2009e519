"""``controller=gait_mpc``: the MPC's plan steers a library gait and sets each leg's base angle.

The soft legs cannot push the body sideways at will: a foot only moves along its
leg, and horizontal motion comes from the gait's stick-slip. What the MPC's plan
asks for is used where the legs can give it:

- **Path.** A PI loop on the cycle-mean path error sets the gait's velocity command:
  the reference velocity plus a world-frame correction turned into the body frame by
  the measured yaw, clipped to what the library measured (its envelope) with the part
  across the path kept whole (:mod:`slotexp.locomotion.path`). omni60's path RMSE
  6.6 mm over 45 s (14.0 before), and its line held for 120 s (161 mm beside it before).
- **Horizontal forces and yaw moment (off by default).** The plan's first forces give
  the body a planned acceleration a (and yaw acceleration alpha); with
  ``velocity_gain`` > 0 each step the command moves by ``velocity_gain * T * a`` (body
  frame), and with ``yaw_gain`` > 0 the yaw-rate command by ``yaw_gain * T * alpha``,
  within the envelope. Until the path loop this was how the command moved
  (``velocity_gain`` 0.02): integral action on the MPC's own errors. But the planned
  horizontal forces are bounded by the friction cones of whichever legs the gait's
  phase puts in stance, so their mean is biased: over 120 s of omni60 their 10-s means
  pointed anywhere, backwards included, and the robot fell 400 mm behind its path.
  The planned yaw moment follows the legs' lever arms as much as the yaw error; its
  integral wound up and the turning it mixed in stopped the walk (a 45 s walk at
  20 mm/s made 5 mm/s with ``yaw_gain = 0.005``).
- **Heading.** A PI loop on the measured heading error (averaged over
  ``heading_cycles`` gait cycles) leans the body onto the legs left or right of the
  direction of travel (:mod:`slotexp.locomotion.heading`: feet sliding across their
  legs' planes brake the body by mu N each, so the loaded side turns it). On some
  models the loaded side's stronger push wins and the lean turns the other way, so
  the loop learns its sign from its own moves (``heading_learn_sign``); everything
  that mixed gaits to turn steered the corrected plant erratically. Measured (default model, 30 s): the 20 mm/s walk,
  the 15 mm/s lateral walk and the backward walk hold their heading within 1.5 deg
  (13.7 and 1.8 deg before, lateral and walk).
- **Normal forces.** Each leg's tendon is offset from the gait by
  ``(f_z - m g / 4) / a`` with ``a`` the force-to-tendon map's slope (eq. 11,
  fitted to the leg by ``experiment=calibrate``; ``experiment=legmap`` gives the
  same slope at every root height): height and attitude as in the paper, less the
  plan's twist, which the plan does not determine (:func:`without_twist`). The gait
  heaves and rocks the body within each cycle, and that is how it walks (the leg
  that presses harder sticks): a controller that flattened it step by step would
  stop the robot. So the legs' differences (attitude) and most of their common
  part (height) are averaged over gait cycles, and only the fraction
  ``height_at_once`` of the common part acts at once. Measured (``sim.dt=1e-4``):
  the forward gait at full stroke (12 s, 35 mm/s command) made 30.6 mm/s with every
  offset averaged and 19.1 mm/s with the whole height part at once (31.6 open
  loop); at a 20 mm/s command the averaged height let it heave (CoM z RMSE 6.5 mm;
  2.1 mm at ``height_at_once`` 0.25, 2.7 mm at 1), while the 132-deg gait, which
  walks by heaving, made 13.0, 13.5, 8.2 and 2.5 mm/s at 0, 0.25, 0.5 and 1.
  The average runs over ``offset_cycles`` cycles, two by default: a one-cycle
  average passes a mode that alternates from cycle to cycle, and with the height
  part applied at once the loop walked in it (on the 15 mm/s walk, cycles of 17
  and 13.5 mm/s in turn; two cycles: 15.7 every cycle).
  By default only the common part reaches the tendons (``attitude_from_plan``
  false): the plan's attitude correction loads the leg a diagonal gait keeps
  nearly slack, and with it the four diagonal headings fell 10-18 % behind their
  command over 45 s (within 7 % without); the attitude is left to the gait, the
  trim and the heading loop's lean.
- **Attitude trim.** The MPC's rigid-body model has no stance stiffness: a body
  that sits tilted on its compliant legs looks to it like one that a small moment
  pulse would level, so its plan corrects attitude only transiently, and a gait
  that walks 2 deg nose-up stays so (the planned front and rear normal forces
  agreed within 0.01 N). An integral trim levels the stance: each leg's tendon
  moves at ``attitude_trim`` (1/s) times the corner height by which the measured
  roll and pitch put its root off level, in degrees of tendon (``MM_PER_DEG``,
  from the leg maps), and holds what it has reached. It never acts along the
  heading loop's lean (it is projected off that pattern): the two integrators
  would wind up against each other (measured: with both on full, the 15 mm/s walk's
  heading error swung +-2 deg and Table I's Baseline ended at 24 % of its maximum).
  Its rate, 0.1/s: the diagonal gaits walk tilted (one leg of each nearly slack), and
  levelling them faster slows them once the path loop asks for their full stroke (at
  0.2/s the 45-deg headings made 8.8-14.4 % less than commanded, at 0.1/s 2.6-7.6 %,
  at 0.05/s 0.5-5.6 % but omni60 then fell 7 % short); at 0.5/s a sideways push while
  walking left the robot 16 mm off its line for good. Table I's Baseline ends at
  0.98 % of its maximum at 0.1/s (0.47 % at 0.05/s, 0.76 % at 0.2/s).
  Standing it also holds the stance's height (every leg alike); walking, the gait
  keeps the posture it was searched at (holding the height made the 20 mm/s walk
  fall 21 mm behind in 25 s), unless ``height_trim`` (1/s) is set. On a model whose
  legs are stiffer or softer than the leg eq. 11's slope was fitted to, the plan's
  height correction is proportional and leaves the walk 10-18 mm off its reference
  height, which Table I charges; the trim removes that, and on the models whose
  gaits walk at another posture costs them speed (walking.md). Before the heading loop it was off: the levelled
  forward gait yawed 0.4 deg/s with nothing to feed yaw back. With both, Table I
  walking at 20 mm/s settles in all six deterministic scenarios.
- **Standing** (a reference that does not travel): the velocity command stays at
  zero and the lean off. A standing robot's small corrective commands played the
  gait's strokes at a few percent of their size, and the robot shuffled in a limit
  cycle (Table I's Pitch standing rocked at 0.3 rad/s to the end; with the command
  held, it settles in 0.6 s).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..body import rot_z
from ..config import SlotConfig, num_field
from ..locomotion.heading import MIN_SPEED, HeadingLoop, lean_pattern
from ..locomotion.path import PathLoop
from ..metrics import wrap_angle
from ..reference import desired_path
from ..robot import RobotModel
from . import CONTROLLERS
from ._gait import GaitController, GaitControllerConfig

MAX_OFFSET_DEG = 30.0  # the normal-force correction stays a correction of the gait
MAX_TRIM_DEG = 15.0  # the attitude trim's reach, either way
# corner (root) height per degree of tendon at the standing load, free foot: the leg maps' normal force
# (results/legmap/legmap_free.csv) rises 0.069 N/deg with the tendon and falls 74 N/m with the root height
# at 80 deg and 23 mm, so holding the load, a degree raises the root 0.069 / 74 m
MM_PER_DEG = 0.93


def without_twist(per_leg: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """``per_leg`` (4,) less its twist: the pattern of normal forces with no net force and no roll or
    pitch moment about the CoM (for feet at ``lever`` (4, 3)), about (+, -, +, -) over the diagonals.
    Four normal forces carry three conditions, so the MPC's plan (with R ~ 0) leaves this one
    pattern to its solver's path; the legs' compliance decides it, not the plan."""
    # The null space of the rows (1, x_i, y_i): their generalised cross product, whose component j is
    # (-1)^j det of the columns without column j, twice the signed area of the other three feet's triangle.
    x, y = lever[:, 0].tolist(), lever[:, 1].tolist()
    null = np.empty(4)
    for j in range(4):
        a, b, c = (i for i in range(4) if i != j)
        null[j] = (-1.0) ** j * ((x[b] - x[a]) * (y[c] - y[a]) - (x[c] - x[a]) * (y[b] - y[a]))
    twist = null / np.sqrt(null @ null)
    return per_leg - (per_leg @ twist) * twist


@dataclass
class GaitMpcConfig(GaitControllerConfig):
    """``controller=gait_mpc``: how much of the MPC's plan reaches the gait (see the module docstring)."""

    name: str = "gait_mpc"
    # each step adds this fraction of the MPC's planned change of velocity (and yaw rate) to the gait command
    velocity_gain: float = num_field(0.0, lo=0.0, hi=1.0, unit="")
    yaw_gain: float = num_field(0.0, lo=0.0, hi=1.0, unit="")
    # the fraction of the legs' common normal-force offset (height) applied each step; the rest, and the legs'
    # differences (attitude), are averaged over offset_cycles gait cycles
    height_at_once: float = num_field(0.25, lo=0.0, hi=1.0, unit="")
    offset_cycles: int = num_field(2, lo=1, hi=8, unit="cycles")
    # whether the legs' differences in the plan's normal forces (its attitude correction) offset the tendons too;
    # off (default): only their common part (height) does, and the attitude is left to the gait and the trim. On,
    # the plan loads the leg a diagonal gait keeps slack and the diagonals fell 10-18 % behind (walking.md)
    attitude_from_plan: bool = False
    # rate (1/s) of the integral trim that levels the stance: each leg's tendon moves by the corner height the
    # measured roll and pitch put it off by; 0 (default) turns it off
    attitude_trim: float = num_field(0.0, lo=0.0, hi=10.0, unit="1/s")
    # rate (1/s) at which the trim also holds the reference height while walking (standing, attitude_trim's); 0: off
    height_trim: float = num_field(0.0, lo=0.0, hi=10.0, unit="1/s")
    # heading feedback (slotexp/locomotion/heading.py): the lean, in degrees of tendon on the legs left of the
    # direction of travel (and minus that on the right), is a PI function of the cycle-mean heading error
    heading_kp: float = num_field(10.0, lo=0.0, hi=100.0, unit="deg of tendon per deg")
    heading_ki: float = num_field(1.0, lo=0.0, hi=100.0, unit="deg of tendon per deg s")
    max_lean_deg: float = num_field(15.0, lo=0.0, hi=MAX_OFFSET_DEG, unit="deg")
    heading_cycles: int = num_field(2, lo=1, hi=8, unit="cycles")  # the heading error is averaged over these
    # whether the loop learns which way the lean turns the robot (it differs between models: heading.py); off, it
    # assumes the friction-braking sign (the loaded side turns towards itself)
    heading_learn_sign: bool = True
    # heading errors (deg, the cycle-mean) the loop leaves alone: it acts on what lies beyond; 0: none
    heading_deadband_deg: float = num_field(0.0, lo=0.0, hi=10.0, unit="deg")
    # path feedback (slotexp/locomotion/path.py): path_kp times the cycle-mean path error plus path_ki times its
    # integral, turned into the body frame by the measured yaw, is added to the command the MPC's plan moved
    path_kp: float = num_field(1.0, lo=0.0, hi=10.0, unit="1/s")
    path_ki: float = num_field(0.05, lo=0.0, hi=10.0, unit="1/s^2")


@CONTROLLERS.register()
class GaitMpcController(GaitController):
    schema: ClassVar[type] = GaitMpcConfig

    def __init__(self, cfg: SlotConfig, robot: RobotModel) -> None:
        super().__init__(cfg, robot)
        # each leg's normal-force offset, averaged over offset_cycles gait cycles (see the module docstring)
        self.cycle_offsets: deque[np.ndarray] = deque(
            maxlen=max(1, round(cfg.controller.offset_cycles / (self.style.frequency_hz * self.period)))
        )
        self.trim = np.zeros(4)  # each leg's attitude trim, deg of tendon
        ctrl = cfg.controller
        window = ctrl.heading_cycles * self.gait_cycle_steps(cfg)
        self.heading = HeadingLoop(
            ctrl.heading_kp,
            ctrl.heading_ki,
            ctrl.max_lean_deg,
            self.period,
            window,
            cycle_steps=self.gait_cycle_steps(cfg),
            learn_sign=ctrl.heading_learn_sign,
            deadband_deg=ctrl.heading_deadband_deg,
        )
        self.walking = bool(np.hypot(*cfg.gait.velocity) >= MIN_SPEED)  # the reference travels
        self.planned = self.velocity.copy()  # the command moved by the MPC's planned accelerations alone
        self.path = PathLoop(ctrl.path_kp, ctrl.path_ki, self.gait_cycle_steps(cfg), self.period)
        legs = robot.feet_body[:, :2] - robot.corners_body[:, :2]
        self.leg_yaw = np.arctan2(legs[:, 1], legs[:, 0])  # each leg's direction out of the body, rad

    def adjust(self, x: np.ndarray, feet: np.ndarray, forces: np.ndarray, solution) -> np.ndarray:
        ctrl = self.cfg.controller
        total = forces.sum(axis=0)
        accel_body = (rot_z(x[2]).T @ np.array([total[0], total[1], 0.0]))[0:2] / self.robot.mass
        lever = feet - x[3:6]
        torque_z = float(np.sum(lever[:, 0] * forces[:, 1] - lever[:, 1] * forces[:, 0]))
        yaw_accel = np.degrees(torque_z / self.robot.inertia_body[2, 2])
        if self.walking:  # standing, the gait stands: its small corrective strokes shuffled the robot (docstring)
            self.planned = self._in_envelope(self.planned + ctrl.velocity_gain * self.period * accel_body)
            self.velocity = self.planned
            if self.path.active:
                if self.origin is None:  # called on its own (step() sets it on the first step)
                    self.origin = x[3:5].copy()
                t = self.steps * self.period
                error = desired_path(self.origin, self.cfg.gait, np.array([t]))[0] - x[3:5]
                self.velocity = self.path.command(error, float(x[2]), self.planned, self._in_envelope)
        limit = self.library.max_yaw_rate_dps
        self.yaw_rate = float(np.clip(self.yaw_rate + ctrl.yaw_gain * self.period * yaw_accel, -limit, limit))
        offsets = without_twist((forces[:, 2] - self.weight / 4.0) / self.cfg.robot.actuation.slope_n_per_deg, lever)
        common = float(offsets.mean())
        if not ctrl.attitude_from_plan:  # the height alone: the gait keeps the posture it walks in
            offsets = np.full_like(offsets, common)
        at_once = ctrl.height_at_once * common
        self.cycle_offsets.append(offsets - at_once)
        corners = self.robot.corners_body
        off_level_mm = 1000.0 * (x[0] * corners[:, 1] - x[1] * corners[:, 0])  # roll lifts +y, pitch lowers +x
        if not self.walking:  # standing, the stance's height too; walking, only at height_trim's rate (docstring)
            off_level_mm += 1000.0 * (x[5] - self.cfg.gait.height)
        lean, pattern = self._lean(x)
        step = -ctrl.attitude_trim * self.period * off_level_mm / MM_PER_DEG
        if self.walking and ctrl.height_trim > 0.0:
            step -= ctrl.height_trim * self.period * 1000.0 * (x[5] - self.cfg.gait.height) / MM_PER_DEG
        if pattern.any():  # the trim levels the body across the lean, never against it (they would wind up)
            step -= (step @ pattern) / (pattern @ pattern) * pattern
        self.trim = np.clip(self.trim + step, -MAX_TRIM_DEG, MAX_TRIM_DEG)
        offset = at_once + np.mean(self.cycle_offsets, axis=0) + self.trim + lean * pattern
        return np.clip(offset, -MAX_OFFSET_DEG, MAX_OFFSET_DEG)

    def _in_envelope(self, velocity: np.ndarray) -> np.ndarray:
        """A body-frame velocity command (m/s) scaled down to the library's envelope in its direction."""
        speed = float(np.hypot(*velocity))
        top = self.library.max_speed(float(np.degrees(np.arctan2(velocity[1], velocity[0]))))
        return velocity * (min(1.0, top / speed) if speed > 0 else 1.0)

    def _lean(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """The heading loop's lean (deg of tendon) and its per-leg pattern for the commanded direction (4,)."""
        yaw_des = self.cfg.gait.yaw_rate * self.steps * self.period  # the reference's heading (slotexp/reference.py)
        error = float(np.degrees(wrap_angle(x[2] - yaw_des)))
        # the reference's speed, not the command's: a standing robot's velocity corrections are not travel
        speed = float(np.hypot(*self.cfg.gait.velocity))
        # between whole cycles of two primitives the heading's rate jumps with the blend's choices, not the lean:
        # no evidence of the lean's sign there (heading.py)
        judge = self.command is None or not self.command.by_cycles
        lean = self.heading.update(error, speed, judge_sign=judge)
        if not self.heading.steers(speed):  # standing: no slip for the lean to act through, and nothing to keep clear
            return 0.0, np.zeros(4)
        return lean, lean_pattern(self.leg_yaw, float(np.arctan2(self.velocity[1], self.velocity[0])))

    def extra_telemetry(self) -> dict:
        heading = {
            "heading_error_deg": self.heading.error_deg,
            "lean_deg": self.heading.lean,
            "lean_sign": self.heading.sign,
            "lean_authority_dps_per_deg": self.heading.authority,  # the sign's evidence (NaN: none yet)
        }
        return {**heading, "path_error_m": self.path.error}
