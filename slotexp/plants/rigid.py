"""The rigid-quadruped plant (``plant=rigid``): a published 12-joint robot in MuJoCo (seeds 001 and 002).

The robot (``robot=mini_cheetah``, ``robot=go1``, ...) is loaded from its installed
package (:mod:`slotexp.rigid.model`). It takes a :class:`LegCommand` held over the
MPC period and, at every MuJoCo step, turns it into joint torques through each
foot's Jacobian from MuJoCo (seed 002, eq. 5, ``tau = -J^T R^T F`` with J in the
base frame, i.e. ``-J_w^T F`` with MuJoCo's world-frame J_w):

- a stance leg pushes with the MPC's ground-reaction force f: ``tau = -J_w^T f``;
- a swing leg follows the parabola with a Cartesian PD force F:
  ``tau = J_w^T F`` (F acts on the foot, so no minus sign), plus (by default) the
  leg's inverse dynamics for the path's acceleration (:meth:`RigidPlant._swing_feedforward`);
- both add the leg joints' own bias torques (gravity and velocity terms of the
  model, ``qfrc_bias``) as feedforward, so a stance foot's ground force is the
  MPC's f, not f less what the leg's own weight takes (measured trotting in place:
  the CoM sat 2.0 mm above its reference without it, 0.9 mm with it).

The torques go to the model's motors, which clip them to their ``ctrlrange``.
MuJoCo's contacts make the ground forces: nothing is applied to the torso
directly except a scenario's pushes and process noise. The MPC state is that of
the whole robot: the CoM (``subtree_com`` of the base) and its velocity, and the
base's attitude and angular velocity.
"""

from __future__ import annotations

import time as _time

import mujoco
import numpy as np

from .. import telemetry as T
from ..body import quat_to_euler
from ..config import SlotConfig
from ..errors import ConfigError
from ..footstep import swing_point
from ..rigid.model import foot_jacobians, leg_indices, load_model, set_stance
from ..robot import RobotModel
from . import PLANTS, LegCommand


@PLANTS.register()
class RigidPlant:
    """A rigid 12-joint quadruped in MuJoCo, driven by stance forces and swing-foot PD through J^T."""

    command_type = LegCommand

    @staticmethod
    def check(cfg: SlotConfig) -> None:
        if not cfg.robot.rigid.model:
            raise ConfigError(
                f"plant=rigid needs a rigid robot: robot={cfg.robot.name} has no robot.rigid.model "
                f"(use robot=mini_cheetah or robot=go1)"
            )

    @classmethod
    def from_config(cls, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> RigidPlant:
        return cls(cfg, robot, x0)

    def __init__(self, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> None:
        self.robot = robot
        self.model = load_model(cfg.robot.rigid, cfg.sim.dt, cfg.sim.gravity)
        self.data = mujoco.MjData(self.model)
        self.index = leg_indices(self.model, cfg.robot.leg.names, cfg.robot.rigid.base_body)
        set_stance(self.model, self.data, self.index, cfg.robot.rigid, np.asarray(x0, dtype=float))
        self.dt = self.model.opt.timestep
        self.time = 0.0
        self.torque = np.zeros((4, 3))
        self.mujoco_time_s = 0.0  # wall time spent in mj_step1/mj_step2, for `slot bench rigid`
        self._jdot = np.zeros((3, self.model.nv))
        parent = self.model.body_parentid
        calf = parent[self.index.foot_body]  # the calf body starts at the knee
        # each leg's hip, thigh, knee and foot bodies (4, 4), what legs() draws
        self._leg_bodies = np.stack([self.index.hip_body, parent[calf], calf, self.index.foot_body], axis=1)
        self._subtree_vel()

    # ------------------------------------------------------------------ measurements
    def _subtree_vel(self) -> None:
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_subtreeVel(self.model, self.data)

    def state(self) -> np.ndarray:
        d = self.data
        quat = d.qpos[3:7]
        rot = d.xmat[self.index.base].reshape(3, 3)
        return np.concatenate(
            [quat_to_euler(quat), d.subtree_com[self.index.base], rot @ d.qvel[3:6], d.subtree_linvel[self.index.base]]
        )

    def feet(self) -> np.ndarray:
        out = self.data.xpos[self.index.foot_body].copy()
        out[:, 2] -= self.index.foot_radius
        return out

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        return self.data.qpos[0:3].copy(), self.data.qpos[3:7].copy()

    def markers(self) -> dict[str, np.ndarray]:
        feet = self.feet()
        out = {"com": self.data.subtree_com[self.index.base].copy()}
        out.update({f"{name}_foot": feet[i] for i, name in enumerate(self.robot.names)})
        return out

    def legs(self) -> np.ndarray:
        """Each leg (4, 4, 3) as its hip, thigh, knee and foot body origins, world frame (the GIF and the 3D
        view draw them)."""
        return self.data.xpos[self._leg_bodies]

    def telemetry(self) -> dict[str, dict]:
        """Joint torques and angles, and each leg's points (:meth:`legs`)."""
        legs = self.legs()
        return {
            T.RIGID: {"joint_torque": self.torque.copy(), "joint_angle": self.data.qpos[self.index.qpos]},
            T.LEGS_SHAPE: {name: legs[i] for i, name in enumerate(self.robot.names)},
        }

    # ------------------------------------------------------------------ actuation
    def leg_torques(self, command: LegCommand, t: float) -> np.ndarray:
        """Joint torques (4, 3) at time ``t`` for the kinematics in ``data`` (mj_step1 done)."""
        m, d = self.model, self.data
        jac = foot_jacobians(m, d, self.index)
        tau = d.qfrc_bias[self.index.dof].copy()  # the legs' own gravity and velocity terms (feedforward)
        for i in range(4):
            dof = self.index.dof[i]
            j_leg = jac[i][:, dof]
            if command.stance[i]:
                tau[i] -= j_leg.T @ command.forces[i]
                continue
            radius = np.array([0.0, 0.0, self.index.foot_radius[i]])
            p_d, v_d, a_d = swing_point(
                command.swing_start[i] + radius,
                command.swing_target[i] + radius,
                command.swing_height,
                t - command.swing_t0[i],
                command.swing_duration[i],
                command.swing_timing,
            )
            p = d.xpos[self.index.foot_body[i]]
            v = jac[i] @ d.qvel
            force = command.kp * (p_d - p) + command.kd * (v_d - v)
            tau[i] += j_leg.T @ force
            if command.swing_feedforward:
                tau[i] += self._swing_feedforward(i, j_leg, p, a_d)
        return tau

    def _swing_feedforward(self, leg: int, j_leg: np.ndarray, p: np.ndarray, a_d: np.ndarray) -> np.ndarray:
        """Joint torques that give the foot the path's acceleration ``a_d``: M_ll J^-1 (a_d - Jdot qdot).

        The leg's inverse dynamics with the base held (its velocity terms are in
        ``qfrc_bias`` already), as in MIT Cheetah 3's swing controller (Bledt et al.
        2018: tau_ff = J^T Lambda (a_d - Jdot qdot) + C qdot + G, with Lambda the
        leg's operational-space inertia; for a square J, J^T Lambda = M_ll J^-1).
        Without it a heavy leg lags its path and lands late (measured: 40 ms on the
        Mini Cheetah at kp 500 N/m), while the MPC counts on its force.
        """
        m, d = self.model, self.data
        jdot = self._jdot
        mujoco.mj_jacDot(m, d, jdot, None, p, int(self.index.foot_body[leg]))
        qdd = np.zeros(m.nv)
        dof = self.index.dof[leg]
        qdd[dof] = np.linalg.solve(j_leg, a_d - jdot @ d.qvel)
        out = np.zeros(m.nv)
        mujoco.mj_mulM(m, d, out, qdd)
        return out[dof]

    def step(self, command: LegCommand, period: float, external_force: np.ndarray | None = None) -> None:
        m, d = self.model, self.data
        n = max(1, int(round(period / self.dt)))
        m.opt.timestep = period / n  # a period cut at a push is not a whole number of sim.dt
        d.xfrc_applied[:] = 0.0
        if external_force is not None:
            d.xfrc_applied[self.index.base, 0:3] = external_force
        start = self.time
        for k in range(n):
            t0 = _time.perf_counter()
            mujoco.mj_step1(m, d)
            t1 = _time.perf_counter()
            self.torque = self.leg_torques(command, start + k * period / n)
            d.ctrl[self.index.actuator] = self.torque / self.index.gear
            t2 = _time.perf_counter()
            mujoco.mj_step2(m, d)
            self.mujoco_time_s += (t1 - t0) + (_time.perf_counter() - t2)
        d.xfrc_applied[:] = 0.0
        m.opt.timestep = self.dt
        self.time += period
        self._subtree_vel()

    def apply_impulse(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """A push on the base: generalised impulse J^T P through the CoM and base Jacobians, then M^-1."""
        m, d = self.model, self.data
        jacp = np.zeros((3, m.nv))
        jacr = np.zeros((3, m.nv))
        mujoco.mj_jacSubtreeCom(m, d, jacp, self.index.base)
        mujoco.mj_jacBody(m, d, None, jacr, self.index.base)
        impulse = jacp.T @ np.asarray(linear, dtype=float) + jacr.T @ np.asarray(angular, dtype=float)
        dq = np.zeros(m.nv)
        mujoco.mj_solveM(m, d, dq.reshape(1, -1), impulse.reshape(1, -1))
        d.qvel[:] += dq
        self._subtree_vel()
