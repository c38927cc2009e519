"""``controller=schedule``: play a schedule, the way the physical robot's own gaits are written.

The schedule (``controller.schedule``, one of ``conf/schedule/``) is a cycle of steps,
each a set of per-leg angles held for ``step_s``; horn angles go through the robot's
horn map (``robot.servo.horn_*``), the same map ``slot hardware`` writes the servos
with, so the simulated and the real robot get the same goal positions. It is open
loop: the MPC runs and is logged (standing reference, every leg in stance), but
nothing it plans reaches the tendons.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from ..config import ControllerConfig, SlotConfig, check_schedule_reach, check_schedule_ticks
from ..errors import ConfigError
from ..gait import contact_plan
from ..locomotion.schedules import schedule_tendon_deg, schedule_velocity, step_index
from ..reference import reference
from ..robot import RobotModel
from ..soft.servo import HornMap
from . import CONTROLLERS, ControlStep
from ._base import MpcController


@dataclass
class ScheduleControllerConfig(ControllerConfig):
    """``controller=schedule``: which of the schedules (``conf/schedule/``, ``schedules.<name>``) it plays."""

    name: str = "schedule"
    schedule: str = "forward"


@CONTROLLERS.register()
class ScheduleController(MpcController):
    schema: ClassVar[type] = ScheduleControllerConfig

    @staticmethod
    def check(cfg: SlotConfig) -> None:
        """The schedule exists and its steps last whole controller ticks."""
        if cfg.controller.schedule not in cfg.schedules:
            raise ConfigError(
                f"controller.schedule = {cfg.controller.schedule!r} is not a schedule: choose one of "
                f"{', '.join(sorted(cfg.schedules)) or '(none)'} (conf/schedule/)"
            )
        check_schedule_ticks(cfg, cfg.schedules[cfg.controller.schedule], cfg.mpc.rate_hz, "mpc.rate_hz")
        check_schedule_reach(cfg, cfg.controller.schedule)

    @staticmethod
    def derive(cfg: SlotConfig) -> SlotConfig:
        """A schedule run is named and judged as its schedule, not as the gait config it happens to carry: the
        log, the metrics' ``gait`` and the figures take the schedule's name, and the reference path (what the
        metrics compare the walk with) is the robot's own pace for it (``schedule_velocity``: along its compass
        heading at its distance per cycle; standing where the distance is not known)."""
        name = cfg.controller.schedule
        gait = replace(cfg.gait, name=name, velocity=schedule_velocity(cfg.schedules[name]), yaw_rate=0.0)
        return replace(cfg, gait=gait)

    @classmethod
    def gait_cycle_steps(cls, cfg: SlotConfig) -> int:
        """The schedule's cycle: its steps, each a whole number of MPC ticks (config.check_schedule_ticks)."""
        schedule = cfg.schedules[cfg.controller.schedule]
        return round(schedule.step_s * cfg.mpc.rate_hz) * len(schedule.steps)

    def __init__(self, cfg: SlotConfig, robot: RobotModel) -> None:
        super().__init__(cfg, robot)
        self.schedule = cfg.schedules[cfg.controller.schedule]
        self.tendon = schedule_tendon_deg(
            self.schedule, list(cfg.robot.leg.names), HornMap.from_config(cfg.robot.servo)
        )
        self.standing = replace(cfg.gait, velocity=[0.0, 0.0], yaw_rate=0.0)  # the MPC's reference: stand

    def step(self, t: float, x: np.ndarray, feet: np.ndarray) -> ControlStep:
        horizon = self.cfg.mpc.horizon
        stance = np.ones((horizon, 4), dtype=bool)
        plan = contact_plan(stance, self.standing, self.cfg.mpc.f_min_stance, self.cfg.mpc.f_max)
        x_ref = reference(x, t, self.standing, self.period, horizon)
        forces, solution, violations = self.solve(x, x_ref, feet - x[3:6], plan)
        k = step_index(self.schedule, t)
        self.steps += 1
        tendon = self.tendon[k].copy()
        return ControlStep(
            forces=forces,
            tendon_deg=tendon,
            command=self.command_type.from_outputs(forces, tendon),
            solution=solution,
            plan=plan,
            x_ref=x_ref,
            fallback=not solution.success,
            violations=violations,
            telemetry={
                "schedule_step": float(k),
                "cycle": float(np.floor(t / (self.schedule.step_s * len(self.tendon)))),
            },
        )
