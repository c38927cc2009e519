"""The soft-leg plant: a rigid torso and four Cosserat legs, coupled both ways (``plant=cosserat``).

Each leg lives in the vertical plane through its corner along its yaw; its root
node follows the corner and its clamp angle follows the torso's tilt in that
plane. The force and moment the leg exerts on its root, rotated into 3D, act back
on the torso, so torso and legs share one step. Tendons are driven by servos
(first-order lag towards the commanded angle, tension capped by the stall torque
over the pulley radius). No fictitious force holds anything up.

Out of plane we assume:
- each leg is rigid out of its plane (its width, 20 mm, is 1.5-6x its thickness),
  so the whole leg translates sideways and turns with its root;
- the foot's sideways friction is regularised Coulomb friction on the leg's actual
  ground normal force, with the foot's sideways velocity taken from the torso's
  rigid motion, applied to the torso at the foot;
- the leg plane turns with the torso's heading; node coordinates in the plane are
  kept (no Coriolis terms from the plane's slow rotation).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .body import euler_to_quat, quat_mul, quat_to_euler, quat_to_rot
from .config import SlotConfig
from .errors import UserError
from .leg import LegModel, build_leg
from .legsim import (O_DIV, O_F, O_FX, O_FZ, O_M, O_N, O_T, OUT, P_C, P_D, P_G, P_GROUND, P_K, P_KR, P_MU, P_NA,
                     P_PAPER, P_TFREE, P_TK, P_TMAX, P_TOFF, P_VEPS, PAR, implicit_once, stable_dt, symplectic_once,
                     tendon_length)
from .robot import RobotModel


SETTLE_S = 0.3  # s the legs get to settle under the held torso before a run starts


class DivergenceError(UserError):
    """The coupled simulation blew up; the message names sim.dt and the stability limit."""


@njit(cache=True)
def coupled_steps(torso, torso_mass, inertia, inertia_inv, gravity, corners, yaw, rest_theta0,
                  pos, vel, theta, omega, rest_pos, l0, voronoi, dtheta0, ea, ga, ei, mass, inertia_el, par,
                  servo, servo_cmd, servo_tau, pulley, free0, prev_corner, f_ext, mu_lat, v_eps,
                  implicit, h, n_steps, normal, out, force, moment, band, rhs, grad_l, cth, sth, work, reaction,
                  hold_torso):
    # cth/sth are (4, E): each leg's directors, kept current by the symplectic step
    """Advance torso (p q v w_body) and four legs ``n_steps`` steps of ``h``.

    ``reaction`` (4, 6) receives each leg's force and moment on the torso (world)
    at the last step. With ``hold_torso`` the torso stays where it is (the legs settle
    under it). Returns the number of steps done (< n_steps on divergence).
    """
    n_legs = pos.shape[0]
    n_nodes = pos.shape[1]
    inv_mass = 1.0 / mass
    inv_inertia = 1.0 / inertia_el
    root = np.zeros(6)
    cy = np.cos(yaw)
    sy = np.sin(yaw)
    for step in range(n_steps):
        p = torso[0:3]
        v = torso[7:10]
        wb = torso[10:13]
        rot = quat_to_rot(torso[3:7])
        ww = rot @ wb
        fx_t = f_ext[0]
        fy_t = f_ext[1]
        fz_t = f_ext[2] - torso_mass * gravity
        tx = 0.0
        ty = 0.0
        tz = 0.0
        for i in range(n_legs):
            # leg direction in the world, its horizontal unit u, and u x e_z (in-plane angle axis)
            dwx = rot[0, 0] * cy[i] + rot[0, 1] * sy[i]
            dwy = rot[1, 0] * cy[i] + rot[1, 1] * sy[i]
            dwz = rot[2, 0] * cy[i] + rot[2, 1] * sy[i]
            horiz = np.sqrt(dwx * dwx + dwy * dwy)
            ux = dwx / horiz
            uy = dwy / horiz
            # corner offset, position and velocity
            rcx = rot[0, 0] * corners[i, 0] + rot[0, 1] * corners[i, 1] + rot[0, 2] * corners[i, 2]
            rcy = rot[1, 0] * corners[i, 0] + rot[1, 1] * corners[i, 1] + rot[1, 2] * corners[i, 2]
            rcz = rot[2, 0] * corners[i, 0] + rot[2, 1] * corners[i, 1] + rot[2, 2] * corners[i, 2]
            cwx = p[0] + rcx
            cwy = p[1] + rcy
            cwz = p[2] + rcz
            vcx = v[0] + ww[1] * rcz - ww[2] * rcy
            vcy = v[1] + ww[2] * rcx - ww[0] * rcz
            vcz = v[2] + ww[0] * rcy - ww[1] * rcx
            # keep node world positions while the root moves in the plane
            ds = (cwx - prev_corner[i, 0]) * ux + (cwy - prev_corner[i, 1]) * uy
            for k in range(n_nodes):
                pos[i, k, 0] -= ds
            prev_corner[i, 0] = cwx
            prev_corner[i, 1] = cwy
            prev_corner[i, 2] = cwz
            root[0] = 0.0
            root[1] = cwz
            root[2] = vcx * ux + vcy * uy
            root[3] = vcz
            root[4] = rest_theta0 + np.arctan2(dwz, horiz)
            root[5] = ww[0] * uy - ww[1] * ux  # omega . (u x e_z)
            # servo: implicit first-order lag towards the command
            servo[i] = (servo[i] + h / servo_tau * servo_cmd[i]) / (1.0 + h / servo_tau)
            par[i, P_TFREE] = free0[i] - pulley * servo[i]
            if implicit:
                implicit_once(pos[i], vel[i], theta[i], omega[i], rest_pos, l0, voronoi, dtheta0, ea, ga, ei, mass,
                              inertia_el, par[i], root, h, normal[i], out[i], force, moment, band, rhs, grad_l,
                              cth[i], sth[i], work)
            else:
                symplectic_once(pos[i], vel[i], theta[i], omega[i], rest_pos, l0, voronoi, dtheta0, ea, ga, ei,
                                mass, inertia_el, inv_mass, inv_inertia, par[i], root, h, normal[i], out[i], force,
                                moment, cth[i], sth[i])
            if out[i, O_DIV] > 0.0:
                return step
            fwx = out[i, O_FX] * ux
            fwy = out[i, O_FX] * uy
            fwz = out[i, O_FZ]
            mwx = out[i, O_M] * uy
            mwy = -out[i, O_M] * ux
            # sideways foot friction, through the leg's out-of-plane rigidity
            nrm = out[i, O_N]
            if nrm > 0.0:
                tip_s = pos[i, n_nodes - 1, 0]
                rfx = cwx + tip_s * ux - p[0]
                rfy = cwy + tip_s * uy - p[1]
                rfz = pos[i, n_nodes - 1, 1] - p[2]
                vfx = v[0] + ww[1] * rfz - ww[2] * rfy
                vfy = v[1] + ww[2] * rfx - ww[0] * rfz
                vl = -vfx * uy + vfy * ux  # along lat = (-uy, ux, 0)
                fl = -mu_lat * nrm * max(-1.0, min(1.0, vl / v_eps))
                flx = -fl * uy
                fly = fl * ux
                tx += -rfz * fly
                ty += rfz * flx
                tz += rfx * fly - rfy * flx
                fx_t += flx
                fy_t += fly
                reaction[i, 0] = fwx + flx
                reaction[i, 1] = fwy + fly
            else:
                reaction[i, 0] = fwx
                reaction[i, 1] = fwy
            reaction[i, 2] = fwz
            reaction[i, 3] = mwx
            reaction[i, 4] = mwy
            reaction[i, 5] = 0.0
            fx_t += fwx
            fy_t += fwy
            fz_t += fwz
            tx += rcy * fwz - rcz * fwy + mwx
            ty += rcz * fwx - rcx * fwz + mwy
            tz += rcx * fwy - rcy * fwx
        f_tot = np.array([fx_t, fy_t, fz_t])
        tau = np.array([tx, ty, tz])
        if hold_torso:
            continue
        # torso: semi-implicit Euler, gyroscopic term kept
        v_new = v + h * f_tot / torso_mass
        tau_b = rot.T @ tau
        iw = inertia @ wb
        wb_new = wb + h * (inertia_inv @ (tau_b - np.cross(wb, iw)))
        torso[0:3] = p + h * v_new
        torso[7:10] = v_new
        torso[10:13] = wb_new
        half = 0.5 * h * wb_new
        angle = np.sqrt(half @ half)
        dq = np.array([np.cos(angle), 0.0, 0.0, 0.0])
        if angle > 0.0:
            sa = np.sin(angle) / angle
            dq[1:4] = half * sa
        qn = quat_mul(torso[3:7], dq)
        torso[3:7] = qn / np.sqrt(qn @ qn)
    return n_steps


class CosseratPlant:
    """Torso + four soft legs behind the :class:`slotexp.plant.Plant` interface."""

    def __init__(self, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> None:
        self.cfg = cfg
        self.robot = robot
        self.dt = cfg.sim.dt
        self.time = 0.0
        self.implicit = cfg.plant.integrator == "implicit"
        leg_cfg = cfg.robot.leg
        self.model: LegModel = build_leg(leg_cfg)
        m = self.model
        n = m.n_nodes
        lx, ly, lz = cfg.robot.torso.size
        # each root node moves with its corner, so its mass rides with the torso
        self.torso_mass = cfg.robot.torso.mass + 4 * m.mass[0]
        self.inertia = self.torso_mass / 12.0 * np.diag([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
        self.inertia_inv = np.linalg.inv(self.inertia)
        self.yaw = np.deg2rad(np.asarray(leg_cfg.yaw_deg, dtype=float))
        # leg roots on the torso's bottom face, relative to the torso centre
        self.corners = np.column_stack([np.sign(np.cos(self.yaw)) * lx / 2, np.sign(np.sin(self.yaw)) * ly / 2,
                                        np.full(4, -lz / 2)])
        drop = m.rest_pos[0, 1] - m.rest_pos[-1, 1]
        # torso placed so that the resting feet just touch the ground, plus the scenario's offset
        z0 = lz / 2 + drop + (x0[5] - robot.stance_height)
        q0 = euler_to_quat(*x0[0:3])
        rot = quat_to_rot(q0)
        self.torso = np.concatenate([[x0[3], x0[4], z0], q0, x0[9:12], rot.T @ x0[6:9]])
        self.pos = np.repeat(m.rest_pos[None], 4, axis=0).copy()
        corner_w = self.torso[0:3] + self.corners @ rot.T
        self.pos[:, :, 1] += (corner_w[:, 2] - m.rest_pos[0, 1])[:, None]
        self.vel = np.zeros_like(self.pos)
        self.theta = np.repeat(m.rest_theta[None], 4, axis=0).copy()
        self.omega = np.zeros_like(self.theta)
        self.prev_corner = corner_w.copy()
        c = cfg.robot.contact
        t = cfg.robot.tendon
        n_anchor = max(1, int(round(t.routed_fraction * (n - 1))))
        self.par = np.zeros((4, len(PAR)))
        self.par[:, P_G] = cfg.sim.gravity
        self.par[:, P_K] = c.stiffness
        self.par[:, P_D] = c.damping
        self.par[:, P_MU] = c.friction
        self.par[:, P_VEPS] = c.slip_velocity
        self.par[:, P_GROUND] = 1.0
        self.par[:, P_C] = leg_cfg.damping_per_s
        self.par[:, P_TK] = t.stiffness
        self.par[:, P_TOFF] = t.offset
        self.par[:, P_TMAX] = cfg.robot.servo.stall_torque / leg_cfg.pulley_radius
        self.par[:, P_NA] = n_anchor
        self.par[:, P_PAPER] = 1.0 if leg_cfg.model == "paper" else 0.0
        self.par[:, P_KR] = leg_cfg.restoring_stiffness
        rest_len = tendon_length(m.rest_pos, m.rest_theta, m.rest_theta[0], self.par[0])
        self.free0 = np.full(4, rest_len + t.slack)
        self.par[:, P_TFREE] = self.free0
        self.servo = np.zeros(4)        # servo (tendon) angle, rad
        self.servo_cmd = np.zeros(4)
        self.normal = np.zeros((4, n))
        self.out = np.zeros((4, len(OUT)))
        self.reaction = np.zeros((4, 6))
        nd = 3 * n - 1
        self._work = (np.zeros((n, 2)), np.zeros(n - 1), np.zeros((nd, 9)), np.zeros(nd), np.zeros(nd),
                      np.cos(self.theta), np.sin(self.theta), np.zeros(nd))
        self.marker_nodes = sorted({0, (n - 1) // 3, 2 * (n - 1) // 3, n - 1})
        self._settle_legs(SETTLE_S)

    # ------------------------------------------------------------------ Plant interface
    def state(self) -> np.ndarray:
        q = self.torso[3:7]
        rot = quat_to_rot(q)
        return np.concatenate([quat_to_euler(q), self.torso[0:3], rot @ self.torso[10:13], self.torso[7:10]])

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        return self.torso[0:3].copy(), self.torso[3:7].copy()

    def _plane(self) -> tuple[np.ndarray, np.ndarray]:
        """Corner world positions (4, 3) and in-plane unit directions (4, 3)."""
        rot = quat_to_rot(self.torso[3:7])
        corners = self.torso[0:3] + self.corners @ rot.T
        d = np.column_stack([np.cos(self.yaw), np.sin(self.yaw), np.zeros(4)]) @ rot.T
        u = d.copy()
        u[:, 2] = 0.0
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        return corners, u

    def leg_world(self) -> np.ndarray:
        """Every node of every leg in the world frame (4, N, 3)."""
        corners, u = self._plane()
        out = corners[:, None, :] + self.pos[:, :, 0:1] * u[:, None, :]
        out[:, :, 2] = self.pos[:, :, 1]
        return out

    def feet(self) -> np.ndarray:
        return self.leg_world()[:, -1, :]

    def markers(self) -> dict[str, np.ndarray]:
        legs = self.leg_world()
        out = {"com": self.torso[0:3].copy()}
        for i, name in enumerate(self.robot.names):
            out[f"{name}_foot"] = legs[i, -1]
            for k in self.marker_nodes:
                out[f"{name}_n{k}"] = legs[i, k]
        return out

    def telemetry(self) -> dict[str, dict]:
        """Extra per-step log messages: leg shapes, tendon tension, servo angle, contact."""
        legs = self.leg_world()
        names = self.robot.names
        return {
            "/legs/shape": {name: legs[i] for i, name in enumerate(names)},
            "/legs/tendon": {"tension_n": self.out[:, O_T].copy(), "servo_deg": np.rad2deg(self.servo),
                             "command_deg": np.rad2deg(self.servo_cmd)},
            "/legs/contact": {"normal_n": self.out[:, O_N].copy(), "friction_n": self.out[:, O_F].copy()},
            "/legs/root": {"force_n": self.reaction[:, 0:3].copy(), "moment_nm": self.reaction[:, 3:6].copy()},
        }

    def _settle_legs(self, seconds: float) -> None:
        """Put the robot down: the torso is held at its initial pose, at rest, while the legs
        settle onto the ground (a scenario's offsets can start the feet below it); then it
        is released with the scenario's velocities."""
        velocities = self.torso[7:13].copy()
        self.torso[7:13] = 0.0
        self._run(seconds, np.zeros(3), hold=True)
        self.torso[7:13] = velocities
        self.time = 0.0

    def step(self, forces: np.ndarray, period: float, external_force: np.ndarray | None = None,
             tendon_deg: np.ndarray | None = None) -> None:
        """Advance ``period`` with the servos tracking ``tendon_deg`` (ground forces are the legs' own)."""
        if tendon_deg is not None:
            self.servo_cmd[:] = np.deg2rad(tendon_deg)
        f_ext = np.zeros(3) if external_force is None else np.asarray(external_force, dtype=float)
        self._run(period, f_ext, hold=False)

    def _run(self, period: float, f_ext: np.ndarray, hold: bool) -> None:
        n = max(1, int(round(period / self.dt)))
        h = period / n
        m = self.model
        done = coupled_steps(self.torso, self.torso_mass, self.inertia, self.inertia_inv, self.cfg.sim.gravity,
                             self.corners, self.yaw, float(m.rest_theta[0]), self.pos, self.vel, self.theta,
                             self.omega, m.rest_pos, m.l0, m.voronoi, m.dtheta0, m.ea, m.ga, m.ei, m.mass, m.inertia,
                             self.par,
                             self.servo, self.servo_cmd, self.cfg.robot.servo.time_constant,
                             self.cfg.robot.leg.pulley_radius, self.free0, self.prev_corner, f_ext,
                             self.cfg.robot.contact.friction, self.cfg.robot.contact.slip_velocity,
                             self.implicit, h, n, self.normal, self.out, *self._work, self.reaction, hold)
        self.time += done * h
        if done < n or not np.all(np.isfinite(self.torso)):
            limit = stable_dt(m, self.cfg.robot.contact.stiffness)
            raise DivergenceError(
                f"the soft-leg simulation diverged at t = {self.time:.4g} s with sim.dt = {h:.3g} s "
                f"({self.cfg.plant.integrator}); the explicit stability limit of this leg is about {limit:.3g} s: "
                f"lower sim.dt or use plant.integrator=implicit")

    def apply_impulse(self, linear: np.ndarray, angular: np.ndarray) -> None:
        rot = quat_to_rot(self.torso[3:7])
        self.torso[7:10] += np.asarray(linear, dtype=float) / self.torso_mass
        self.torso[10:13] += self.inertia_inv @ (rot.T @ np.asarray(angular, dtype=float))
