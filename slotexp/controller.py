"""The control loop of paper Fig. 3 / Algorithm 1: gait -> reference -> MPC -> actuation map.

When a solve is infeasible or fails, the last feasible input is applied and the
step is counted (Algorithm 1, lines 32-34). Before any solve has succeeded the
"last feasible input" is the static stance: m g / 4 straight up on every leg.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .actuation import tendon_angle_deg
from .config import SlotConfig
from .gait import ContactPlan, GaitMatrix, contact_plan, tendon_profile
from .mpc import MpcSolution, constraint_violations, make_mpc
from .reference import reference
from .robot import RobotModel


@dataclass
class ControlStep:
    forces: np.ndarray            # (4, 3) applied ground-reaction forces, world frame
    tendon_deg: np.ndarray        # (4,) commanded tendon angles from the force-to-tendon map
    solution: MpcSolution
    plan: ContactPlan
    x_ref: np.ndarray             # (H, 12)
    fallback: bool
    violations: dict[str, float]  # per constraint group, of the applied input


class Controller:
    def __init__(self, cfg: SlotConfig, robot: RobotModel) -> None:
        self.cfg = cfg
        self.robot = robot
        self.period = 1.0 / cfg.mpc.rate_hz
        self.gait = GaitMatrix(cfg.gait.phases)
        self.mpc = make_mpc(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
        self.weight = robot.mass * cfg.sim.gravity
        self.last_feasible = np.tile([0.0, 0.0, self.weight / 4.0], (4, 1))
        self.infeasible_steps = 0
        self.steps = 0

    def step(self, t: float, x: np.ndarray, feet: np.ndarray) -> ControlStep:
        horizon = self.cfg.mpc.horizon
        plan = contact_plan(self.gait.contacts(horizon), self.cfg.gait, self.cfg.mpc.f_min_stance,
                            self.cfg.mpc.f_max)
        x_ref = reference(x, t, self.cfg.gait, self.period, horizon)
        solution = self.mpc.solve(x, x_ref, feet - x[3:6], plan)
        if solution.success:
            forces = solution.forces
            self.last_feasible = forces.copy()
        else:
            forces = self.last_feasible.copy()
            self.infeasible_steps += 1
        self.gait.roll()
        violations = constraint_violations(forces, plan, self.weight, self.cfg.mpc.force_balance_band)
        gait = self.cfg.gait
        schedule = gait.tendon_amplitude_deg * tendon_profile(gait.phases, self.steps, gait.tendon_ramp,
                                                               gait.tendon_hold, gait.tendon_decay)
        tendon = np.clip(tendon_angle_deg(forces[:, 2], self.cfg.robot.actuation, self.cfg.robot.leg.tendon_max_deg)
                         + schedule, 0.0, self.cfg.robot.leg.tendon_max_deg)
        self.steps += 1
        return ControlStep(forces=forces, tendon_deg=tendon, solution=solution, plan=plan, x_ref=x_ref,
                           fallback=not solution.success, violations=violations)
