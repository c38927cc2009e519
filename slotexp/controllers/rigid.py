"""``controller=rigid``: seeds 001 and 002's controller for a rigid 12-joint quadruped (``plant=rigid``).

Each MPC step:

1. the gait matrix (seed 001, eq. 18) gives the contact flags over the horizon and
   is rolled one step; a leg that has just lifted off records where and when;
2. the footstep planner (seed 001, eqs. 19-28, :mod:`slotexp.footstep`) places each
   swing leg's foothold for its remaining swing time;
3. the MPC plans ground-reaction forces with swing legs at zero force
   (``gait.swing_contact=false``). Its B_k holds each step's footholds relative to
   the CoM predicted for that step (seed 001, eq. 46; ``controller.footholds=horizon``):
   a standing foot where it stands until it lifts, a swinging foot at its planned
   target, and a foot that lifts and lands again within the horizon at the
   foothold the planner gives for that landing (:meth:`RigidController.horizon_lever_arms`).
   ``controller.footholds=current`` keeps one B: the feet now, relative to the CoM now;
4. the plant gets a :class:`~slotexp.plants.LegCommand`: stance legs push with the
   MPC's first forces, swing legs follow seed 002's parabola from lift-off to the
   foothold under a Cartesian PD, both through the foot Jacobians.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..body import rot_z
from ..config import ControllerConfig, SlotConfig, choice_field
from ..footstep import footholds
from ..gait import GaitMatrix, contact_plan
from ..plants import LegCommand
from ..reference import desired_path, reference
from ..robot import RobotModel
from . import CONTROLLERS, ControlStep
from ._base import MpcController


def stance_durations(phases: list[list[int]], period: float) -> np.ndarray:
    """Each leg's stance time (s) over one gait period (seed 001's t_stance)."""
    rows = np.asarray(phases, dtype=float)
    return (rows[:, 0:1] * rows[:, 1:]).sum(axis=0) * period


def swing_steps_left(contacts: np.ndarray) -> np.ndarray:
    """For each leg in swing at step 0, how many steps its swing still lasts (0 for stance legs)."""
    out = np.zeros(contacts.shape[1], dtype=int)
    for i in range(contacts.shape[1]):
        if not contacts[0, i]:
            landing = np.flatnonzero(contacts[:, i])
            out[i] = int(landing[0]) if landing.size else contacts.shape[0]
    return out


@dataclass
class RigidControllerConfig(ControllerConfig):
    """``controller=rigid``: seeds 001/002's controller's settings (the robot's own are ``robot.rigid``)."""

    name: str = "rigid"
    # the lever arms of the MPC's B_k. "horizon": each step's footholds (feet standing, swing targets, and the
    # footholds of steps that land later in the horizon) relative to the CoM predicted for that step (seed 001);
    # "current": the feet where they stand and the swing targets, relative to the CoM now, one B
    footholds: str = choice_field("horizon", "horizon", "current")


@CONTROLLERS.register()
class RigidController(MpcController):
    """Gait matrix, footstep planner, MPC and swing parabolas for a rigid quadruped."""

    schema: ClassVar[type] = RigidControllerConfig

    @classmethod
    def gait_cycle_steps(cls, cfg: SlotConfig) -> int:
        """The gait matrix's period: its rows' durations in MPC steps."""
        return sum(int(row[0]) for row in cfg.gait.phases)

    def __init__(self, cfg: SlotConfig, robot: RobotModel) -> None:
        super().__init__(cfg, robot)
        self.gait = GaitMatrix(cfg.gait.phases)
        self.t_stance = stance_durations(cfg.gait.phases, self.period)
        self.shoulders = robot.feet_body[:, 0:2].copy()  # ground projection of the nominal feet, body frame
        rigid = cfg.robot.rigid
        self.swing_height = rigid.swing_height
        self.kp = np.asarray(rigid.swing_kp, dtype=float)
        self.kd = np.asarray(rigid.swing_kd, dtype=float)
        self.was_stance = np.ones(4, dtype=bool)
        self.swing_start = np.zeros((4, 3))
        self.swing_t0 = np.zeros(4)
        self.swing_duration = np.full(4, self.period)
        self.targets = np.zeros((4, 3))
        self.origin: np.ndarray | None = None  # where the desired path starts: the first measured position
        self.lever_arms = np.zeros((cfg.mpc.horizon, 4, 3))  # what the last solve used, (H, 4, 3)

    def local_footholds(self, x: np.ndarray, t_remaining: np.ndarray) -> np.ndarray:
        """Footholds (4, 2) in the local frame (seed 001's eqs. 19-28), from the measured state ``x``."""
        gait = self.cfg.gait
        v_local = rot_z(x[2])[0:2, 0:2].T @ x[9:11]
        return footholds(
            self.shoulders,
            self.t_stance,
            t_remaining,
            v_local,
            np.asarray(gait.velocity, dtype=float),
            float(x[8]),
            gait.yaw_rate,
            gait.height,
            self.cfg.sim.gravity,
        )

    def plan_footholds(self, x: np.ndarray, t_remaining: np.ndarray) -> np.ndarray:
        """World footholds (4, 3) on the ground for every leg, from the measured state ``x``."""
        out = np.zeros((4, 3))
        out[:, 0:2] = x[3:5] + self.local_footholds(x, t_remaining) @ rot_z(x[2])[0:2, 0:2].T
        return out

    def horizon_lever_arms(self, x: np.ndarray, t: float, contacts: np.ndarray, feet: np.ndarray) -> np.ndarray:
        """Seed 001's r_{k,i} (H, 4, 3): each step's footholds relative to the CoM predicted for that step.

        The CoM is predicted along the reference from where it is now: the reference
        velocity turned by the reference yaw rate, integrated from the measured
        position (the height held). Footholds: a foot standing now stays where it
        stands until it lifts; a swinging foot lands on its target (``self.targets``,
        planned this step); a foot that lifts later in the horizon lands, at step j,
        on the planner's foothold for a base at the pose predicted for j (shoulder,
        symmetry, feedback and centrifugal terms turned by the predicted yaw; its
        prediction term is that pose). A leg in swing at a step keeps its last
        foothold there (its force is zero). ``contacts`` (H, 4) from the gait matrix.
        """
        gait = self.cfg.gait
        h = contacts.shape[0]
        tk = t + self.period * np.arange(h)
        com = np.empty((h, 3))
        com[:, 0:2] = x[3:5] + desired_path(np.zeros(2), gait, tk) - desired_path(np.zeros(2), gait, np.array([t]))
        com[:, 2] = x[5]
        yaw = x[2] + gait.yaw_rate * (tk - t)
        offsets = self.local_footholds(x, np.zeros(4))  # eqs. 19-22: the same for every future landing
        held = np.where(contacts[0][:, None], feet, self.targets)  # (4, 3) where each foot is or is going
        world = np.empty((h, 4, 3))
        for i in range(4):
            world[:, i] = held[i]
            lands = np.flatnonzero(contacts[1:, i] & ~contacts[:-1, i]) + 1
            if not contacts[0, i]:
                lands = lands[1:]  # the swing under way lands on its target
            for k in lands:  # a swing that starts within the horizon lands on a new foothold
                world[k:, i, 0:2] = com[k, 0:2] + rot_z(yaw[k])[0:2, 0:2] @ offsets[i]
                world[k:, i, 2] = 0.0
        return world - com[:, None, :]

    def step(self, t: float, x: np.ndarray, feet: np.ndarray) -> ControlStep:
        cfg = self.cfg
        horizon = cfg.mpc.horizon
        contacts = self.gait.contacts(max(horizon, self.gait.period))
        stance = contacts[0].copy()
        left = swing_steps_left(contacts)
        lifted = self.was_stance & ~stance
        self.swing_start[lifted] = feet[lifted]
        self.swing_t0[lifted] = t
        self.swing_duration[lifted] = left[lifted] * self.period
        t_remaining = np.where(stance, 0.0, self.swing_t0 + self.swing_duration - t)
        planned = self.plan_footholds(x, t_remaining)
        self.targets[~stance] = planned[~stance]
        plan = contact_plan(contacts[:horizon], cfg.gait, cfg.mpc.f_min_stance, cfg.mpc.f_max)
        if self.origin is None:
            self.origin = x[3:5].copy()
        # positions on the desired path (not from wherever the robot is): Q's position weights then hold the
        # robot to its path, so speed errors and pushes do not accumulate into drift
        x_ref = reference(x, t, cfg.gait, self.period, horizon, path_origin=self.origin)
        if cfg.controller.footholds == "horizon":
            self.lever_arms = self.horizon_lever_arms(x, t, contacts[:horizon], feet)
        else:
            self.lever_arms[:] = np.where(stance[:, None], feet, self.targets) - x[3:6]
        forces, solution, violations = self.solve(x, x_ref, self.lever_arms, plan)
        self.gait.roll()
        self.was_stance = stance
        self.steps += 1
        command = LegCommand(
            forces=forces,
            stance=stance,
            swing_start=self.swing_start.copy(),
            swing_target=self.targets.copy(),
            swing_t0=self.swing_t0.copy(),
            swing_duration=self.swing_duration.copy(),
            swing_height=self.swing_height,
            kp=self.kp,
            kd=self.kd,
            swing_timing=cfg.robot.rigid.swing_timing,
            swing_feedforward=cfg.robot.rigid.swing_feedforward,
        )
        if self.command_type is not LegCommand:  # a plant without legs takes the stance forces alone
            command = self.command_type.from_outputs(forces, np.zeros(4))
        return ControlStep(
            forces=forces,
            tendon_deg=np.zeros(4),
            command=command,
            solution=solution,
            plan=plan,
            x_ref=x_ref,
            fallback=not solution.success,
            violations=violations,
            telemetry={"foothold": self.targets.copy(), "swing": (~stance).astype(float)},
        )
