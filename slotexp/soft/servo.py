"""The tendon servo: a Dynamixel XL430-W250 in position mode, as the soft plant drives it.

Per step of length h the servo angle s moves towards the command c along a first-
order lag (time constant tau, the position loop), but never faster than the motor
can turn under its load:

    ds = clip((c - s) (h/tau) / (1 + h/tau), -w_max h, +w_max h)

    winding (ds > 0, against the tendon's pull):  w_max = w0 max(0, 1 - T r / tau_stall)
    unwinding (the load helps):                    w_max = w0
    and w_max <= the Profile Velocity the bus sets (when it sets one).

That is the DC motor's linear speed-torque line from the no-load speed w0 to the
stall torque tau_stall, with the load torque T r of the tendon tension T on the
pulley of radius r. Figures (ROBOTIS e-Manual, XL430-W250-T specifications, at
11.1 V, the voltage the paper's 1.4 N m belongs to): stall torque 1.4 N m, no-load
speed 57 rpm (342 deg/s). ``slot hardware`` writes the same Profile Velocity
(``robot.servo.profile_velocity_rpm``) to the servos.
"""

from __future__ import annotations

from ..jit import njit

RPM_TO_RAD_S = 2.0 * 3.141592653589793 / 60.0


@njit(cache=True)
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
    """The servo angle (rad) after one step of ``h`` s (speeds in rad/s; ``profile_speed`` 0: no profile)."""
    delta = (command - angle) * (h / tau) / (1.0 + h / tau)
    if delta > 0.0:
        w_max = no_load_speed * max(0.0, 1.0 - load_torque / stall_torque)
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
