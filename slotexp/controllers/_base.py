"""What every controller shares: the MPC solve with Algorithm 1's fallback, and its bookkeeping.

When a solve is infeasible or fails, the last feasible input is applied and the
step is counted (Algorithm 1, lines 32-34). Before any solve has succeeded the
"last feasible input" is the static stance, m g / 4 straight up on every leg,
within the configured force limit ``mpc.f_max`` (a limit below m g / 4 cannot hold
the robot up; a run whose MPC never succeeds fails, :func:`slotexp.simulation.run_closed_loop`).
"""

from __future__ import annotations

import numpy as np

from ..backends import make_mpc
from ..config import SlotConfig
from ..gait import ContactPlan
from ..mpc import MpcSolution, constraint_violations
from ..plants import PLANTS, Command
from ..robot import RobotModel


class MpcController:
    """The convex MPC over ground-reaction forces, with the last-feasible-input fallback."""

    def __init__(self, cfg: SlotConfig, robot: RobotModel) -> None:
        self.cfg = cfg
        self.robot = robot
        self.period = 1.0 / cfg.mpc.rate_hz
        self.mpc = make_mpc(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
        self.weight = robot.mass * cfg.sim.gravity
        self.last_feasible = np.tile([0.0, 0.0, min(self.weight / 4.0, cfg.mpc.f_max)], (4, 1))
        self.infeasible_steps = 0
        self.steps = 0
        # the kind of command its steps carry: what the configured plant takes (make_controller may set another)
        self.command_type: type[Command] = PLANTS.get(cfg.plant.name).command_type

    @classmethod
    def gait_cycle_steps(cls, cfg: SlotConfig) -> int | None:
        """MPC steps in one cycle of the gait this controller walks under ``cfg`` (None: it walks none). A
        controller with a cycle declares it here: Table I's ``cost_average=gait_cycle`` averages over it."""
        return None

    def solve(
        self, x: np.ndarray, x_ref: np.ndarray, lever_arms: np.ndarray, plan: ContactPlan
    ) -> tuple[np.ndarray, MpcSolution, dict[str, float]]:
        """The forces to apply (the plan's first, or the last feasible), the solution, and their violations.

        ``lever_arms`` are the feet relative to the CoM: (4, 3) for one B over the
        horizon, (H, 4, 3) for a B_k per step (:func:`slotexp.mpc.step_lever_arms`).
        """
        solution = self.mpc.solve(x, x_ref, lever_arms, plan)
        if solution.success:
            forces = solution.forces
            self.last_feasible = forces.copy()
        else:
            forces = self.last_feasible.copy()
            self.infeasible_steps += 1
        violations = constraint_violations(forces, plan, self.weight, self.cfg.mpc.force_balance_band)
        return forces, solution, violations
