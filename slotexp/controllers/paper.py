"""``controller=paper``: paper Fig. 3 / Algorithm 1: gait -> reference -> MPC -> eq. 11.

The MPC's normal forces become tendon angles through the affine force-to-tendon
map (eq. 11); the gait's fixed tendon schedule (ramp / hold / decay for the legs
the gait matrix marks as swing) is added on top. The MPC's horizontal forces are
not passed on: a tendon sets how hard a foot presses, not which way it pushes.
"""

from __future__ import annotations

import numpy as np

from ..actuation import tendon_angle_deg
from ..config import SlotConfig
from ..gait import GaitMatrix, contact_plan, tendon_profile
from ..reference import reference
from ..robot import RobotModel
from . import CONTROLLERS, ControlStep
from ._base import MpcController


@CONTROLLERS.register()
class PaperController(MpcController):
    def __init__(self, cfg: SlotConfig, robot: RobotModel) -> None:
        super().__init__(cfg, robot)
        self.gait = GaitMatrix(cfg.gait.phases)

    def step(self, t: float, x: np.ndarray, feet: np.ndarray) -> ControlStep:
        horizon = self.cfg.mpc.horizon
        plan = contact_plan(self.gait.contacts(horizon), self.cfg.gait, self.cfg.mpc.f_min_stance, self.cfg.mpc.f_max)
        x_ref = reference(x, t, self.cfg.gait, self.period, horizon)
        forces, solution, violations = self.solve(x, x_ref, feet - x[3:6], plan)
        self.gait.roll()
        gait = self.cfg.gait
        schedule = gait.tendon_amplitude_deg * tendon_profile(
            gait.phases, self.steps, gait.tendon_ramp, gait.tendon_hold, gait.tendon_decay
        )
        tendon = np.clip(
            tendon_angle_deg(forces[:, 2], self.cfg.robot.actuation, self.cfg.robot.leg.tendon_max_deg) + schedule,
            0.0,
            self.cfg.robot.leg.tendon_max_deg,
        )
        self.steps += 1
        return ControlStep(
            forces=forces,
            tendon_deg=tendon,
            command=self.command_type.from_outputs(forces, tendon),
            solution=solution,
            plan=plan,
            x_ref=x_ref,
            fallback=not solution.success,
            violations=violations,
        )
