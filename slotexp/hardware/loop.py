"""The control loop of Algorithm 1 on a servo bus: identical for the robot, the emulator and the simulator.

Each cycle: read the servos; take the newest state estimate (stop if it is too old);
gait phase, reference and MPC with the last-feasible fallback
(:meth:`slotexp.controllers.Controller.step`); map f_z to tendon angles (eq. 11) and
tendon angles to clamped servo positions; command them (not in a dry run); check
Hardware Error Status every few cycles; log the step with the simulation's schema
(:func:`slotexp.simulation.log_step`) plus ``/servos`` and ``/loop``; sleep to the
next deadline.

On hardware the state estimate is both the "true" and the measured state, the only
marker is the CoM, and the feet are the nominal body-fixed feet rotated by the
measured attitude.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..body import quat_to_rot
from ..config import SlotConfig
from ..controllers import Controller
from ..errors import SafetyStop
from ..reference import reference
from ..robot import RobotModel
from ..scene import straight_legs
from ..signals import StopFlag
from ..telemetry import LOOP, SERVOS, Sink, StepRecord, log_step, scene_track
from . import xl430 as X
from .bus import ServoBus
from .mapping import ServoMap
from .odometry import OdometrySource
from .timing import Deadlines, LoopStats


@dataclass
class LoopOutcome:
    steps: int
    stop_reason: str  # duration | replay finished | SIGINT | SIGTERM | SIGHUP | stale odometry | bus | hardware error
    stats: LoopStats
    clamped: np.ndarray = field(default_factory=lambda: np.zeros(4, dtype=np.int64))  # cycles clamped, per servo
    comm_retries: int = 0
    error: str | None = None

    @classmethod
    def empty(cls, rate_hz: float) -> LoopOutcome:
        return cls(steps=0, stop_reason="", stats=LoopStats(1.0 / rate_hz))


def nominal_feet(robot: RobotModel, position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    """World positions of the body-fixed nominal feet at the measured pose."""
    return position + robot.feet_body @ quat_to_rot(np.asarray(quaternion, dtype=float)).T


def nominal_legs(robot: RobotModel, position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    """Straight legs (4, 2, 3) from the torso corners to the nominal feet at the measured pose: the 3D view's
    legs on the robot, whose leg shapes are not measured."""
    segments = np.stack((robot.corners_body, robot.feet_body), axis=1)
    return straight_legs(segments, np.asarray(position, dtype=float), np.asarray(quaternion, dtype=float))


def run_loop(
    cfg: SlotConfig,
    robot: RobotModel,
    controller: Controller,
    bus: ServoBus,
    odometry: OdometrySource,
    smap: ServoMap,
    sink: Sink,
    stop: StopFlag,
    *,
    rate_hz: float,
    max_age_s: float,
    error_check_every: int,
    duration: float | None,
    dry_run: bool,
    outcome: LoopOutcome | None = None,
    notify: Callable[[str], None] = lambda _m: None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> LoopOutcome:
    """Run until ``duration``, a stop signal, the end of a replay, or a :class:`SafetyStop` / ``BusError``.

    Safety stops propagate as exceptions (the caller turns the torque off). Pass an
    ``outcome`` (see :meth:`LoopOutcome.empty`) to keep the counts and timings of a
    loop that ended that way: it is filled in as the loop goes.
    """
    period = 1.0 / rate_hz
    n_max = None if duration is None else int(round(duration * rate_hz))
    names = list(robot.names)
    q_diag = np.asarray(cfg.mpc.q_diag, dtype=float)
    scene = scene_track(sink, names, cfg.robot.torso)
    outcome = outcome if outcome is not None else LoopOutcome.empty(rate_hz)
    stats = outcome.stats
    sched = Deadlines(period, clock, sleep)
    hw_errors = np.zeros(4, dtype=np.int64)
    p_des: np.ndarray | None = None
    warned = np.zeros(4, dtype=bool)
    sched.start()
    while True:
        if stop.requested:
            outcome.stop_reason = stop.name
            break
        if n_max is not None and outcome.steps >= n_max:
            outcome.stop_reason = "duration"
            break
        t = sched.k * period
        started = clock()
        readings = bus.read()
        t_read = clock()
        sample = odometry.latest()
        if odometry.finished:
            outcome.stop_reason = "replay finished"
            break
        age = float("inf") if sample is None else clock() - sample.received
        if age > max_age_s:
            refused = getattr(odometry, "last_problem", None)  # messages arrive but are refused: say why
            raise SafetyStop(
                "stale odometry",
                f"odometry is {age:.3f} s old (limit odometry.max_age_s = "
                f"{max_age_s:g} s): stopped the loop and turned the torque off"
                + (f"; its messages were refused: {refused}" if refused else ""),
            )
        x = sample.state
        step = controller.step(t, x, nominal_feet(robot, sample.position, sample.quaternion))
        t_solve = clock()
        goal, clamped = smap.to_ticks(step.command.tendon_deg)
        retries = readings.retries
        if not dry_run:
            retries += bus.write_goals(goal)
        t_write = clock()
        if outcome.steps % error_check_every == 0:
            hw_errors = bus.hardware_errors()
            if np.any(hw_errors):
                k = int(np.flatnonzero(hw_errors)[0])
                raise SafetyStop(
                    "hardware error",
                    f"servo {bus.ids[k]} ({names[k]}) reports hardware error "
                    f"{X.describe_hardware_error(int(hw_errors[k]))}: stopped, torque off",
                )
        outcome.clamped += clamped
        outcome.comm_retries += retries
        for k in np.flatnonzero(clamped & ~warned):
            warned[k] = True
            notify(
                f"note: {names[k]} command clamped to the servo limits (tendon {step.command.tendon_deg[k]:.2f} deg "
                f"-> {smap.to_tendon_deg(goal)[k]:.2f} deg); counted in /servos and the summary"
            )
        if p_des is None:
            p_des = x[3:5].copy()
        x_ref_now = reference(x, t, cfg.gait, period, 1, start=0)[0]
        x_ref_now[3:5] = p_des
        p_des = p_des + period * x_ref_now[9:11]
        record = StepRecord(
            t,
            x,
            x,
            x_ref_now,
            step,
            controller.infeasible_steps,
            {"com": sample.position},
            sample.position,
            sample.quaternion,
            names,
            q_diag,
            functools.partial(nominal_legs, robot, sample.position, sample.quaternion),
        )
        log_step(sink, record, scene)
        sink.write(
            SERVOS,
            t,
            {
                "ids": list(bus.ids),
                "sent": not dry_run,
                "goal": goal,
                "goal_deg": goal * X.DEG_PER_TICK,
                "goal_tendon_deg": smap.to_tendon_deg(goal),
                "clamped": clamped,
                "present_position": readings.position,
                "present_position_deg": readings.position * X.DEG_PER_TICK,
                "present_tendon_deg": smap.to_tendon_deg(readings.position),
                "present_velocity_rpm": readings.velocity * X.RPM_PER_VELOCITY_UNIT,
                "present_load_percent": readings.load * X.LOAD_PERCENT_PER_UNIT,
                "hardware_error": hw_errors,
                "comm_retries": retries,
            },
        )
        lateness = started - sched.due
        cycle_time = clock() - started
        overrun = clock() > sched.next_due
        sink.write(
            LOOP,
            t,
            {
                "cycle": sched.k,
                "cycle_time_s": cycle_time,
                "read_s": t_read - started,
                "solve_s": t_solve - t_read,
                "write_s": t_write - t_solve,
                "lateness_s": lateness,
                "overrun": overrun,
                "overruns_total": sched.overruns + int(overrun),
                "skipped_total": sched.skipped,
                "odometry_age_s": age,
                "odometry_stamp": sample.stamp,
            },
        )
        stats.add(started, cycle_time, lateness, age)
        outcome.steps += 1
        sched.wait_next()
        stats.overruns, stats.skipped = sched.overruns, sched.skipped
    return outcome


__all__ = ["run_loop", "LoopOutcome", "nominal_feet"]
