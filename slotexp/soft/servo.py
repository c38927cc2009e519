"""The tendon servo: a Dynamixel XL430-W250 in position mode, as the soft plant drives it.

Per step of length h the servo angle s moves towards the command c along a first-
order lag (time constant tau, the position loop), but never faster than the motor
can turn under its load:

    ds = clip((c - s) (h/tau) / (1 + h/tau), -w_max h, +w_max h)

    winding (ds > 0, against the tendon's pull):  w_max = w0 max(0, 1 - T r / tau_stall)
    unwinding (the load helps):                    w_max = w0
    (the load torque is signed: with a pair of cables, robot.tendon.antagonist, the upper
    one resists turning the other way)
    and w_max <= the Profile Velocity the bus sets (when it sets one).

That is the DC motor's linear speed-torque line from the no-load speed w0 to the
stall torque tau_stall, with the load torque T r of the tendon tension T on the
pulley of radius r. Figures (ROBOTIS e-Manual, XL430-W250-T specifications, at
11.1 V, the voltage the paper's 1.4 N m belongs to): stall torque 1.4 N m, no-load
speed 57 rpm (342 deg/s). ``slot hardware`` writes the same Profile Velocity
(``robot.servo.profile_velocity_rpm``) to the servos.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import ServoConfig
from ..jit import njit

RPM_TO_RAD_S = 2.0 * 3.141592653589793 / 60.0


@njit(cache=True, allocates=False)
def servo_step(
    angle: float,
    command: float,
    h: float,
    tau: float,
    load_torque: float,
    stall_torque: float,
    no_load_speed: float,
    profile_speed: float,
) -> float:
    """The servo angle (rad) after one step of ``h`` s (speeds in rad/s; ``profile_speed`` 0: no profile;
    ``load_torque`` > 0 resists turning up, < 0 turning down)."""
    delta = (command - angle) * (h / tau) / (1.0 + h / tau)
    if delta * load_torque > 0.0:  # turning against the load
        w_max = no_load_speed * max(0.0, 1.0 - abs(load_torque) / stall_torque)
    else:
        w_max = no_load_speed
    if profile_speed > 0.0 and profile_speed < w_max:
        w_max = profile_speed
    limit = w_max * h
    if delta > limit:
        delta = limit
    elif delta < -limit:
        delta = -limit
    return angle + delta


@dataclass(frozen=True)
class HornMap:
    """Servo-horn angle <-> tendon angle, the one map simulation and robot share (``robot.servo.horn_*``).

    tendon = direction (horn - zero), per leg in ``robot.leg.names`` order, every horn angle
    inside [min_deg, max_deg] (the servo's position limits). A horn below the zero leaves the
    cable more slack (a negative tendon angle: the servo lets out cable it must wind back in
    before the tendon pulls again), which is how the robot's own gaits relax a leg.
    """

    zero_deg: np.ndarray  # (4,)
    direction: np.ndarray  # (4,) +-1
    min_deg: np.ndarray  # (4,)
    max_deg: np.ndarray  # (4,)

    @classmethod
    def from_config(cls, servo: ServoConfig) -> HornMap:
        return cls(
            np.asarray(servo.horn_zero_deg, float),
            np.asarray(servo.horn_direction, float),
            np.asarray(servo.horn_min_deg, float),
            np.asarray(servo.horn_max_deg, float),
        )

    def tendon_deg(self, horn_deg: np.ndarray) -> np.ndarray:
        """Tendon angles (..., 4) for horn angles, the horn first held inside its limits."""
        horn = np.clip(np.asarray(horn_deg, dtype=float), self.min_deg, self.max_deg)
        return self.direction * (horn - self.zero_deg)

    def horn_deg(self, tendon_deg: np.ndarray) -> np.ndarray:
        """Horn angles (..., 4) for tendon angles, inside the limits."""
        return np.clip(self.zero_deg + self.direction * np.asarray(tendon_deg, dtype=float), self.min_deg, self.max_deg)
