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
from numba import prange

from ..actuation import tendon_angle_deg
from ..body import euler_to_quat, quat_to_euler, quat_to_rot, torso_step
from ..config import SlotConfig
from ..errors import DivergenceError
from ..jit import njit
from ..robot import RobotModel
from ..soft.integrators import divergence_message, implicit_once, jacobian_state, stable_dt, symplectic_once
from ..soft.loads import rest_free_length
from ..soft.params import O_DIV, O_F, O_FX, O_FZ, O_M, O_N, O_T, OUT, leg_params
from ..soft.rod import LegModel, build_leg
from ..soft.servo import RPM_TO_RAD_S, servo_step
from . import PLANTS, TendonCommand

SETTLE_S = 0.4  # s the legs get to settle under the held torso before a run starts
SETTLE_ITERATIONS = 8  # ... in this many steps towards the servo angle that carries the weight
LOWERING_MOVES = 25  # per settling step in the first half, in which the torso is lowered onto its initial pose


def pose_between(start: np.ndarray, end: np.ndarray, s: float) -> np.ndarray:
    """Torso position and quaternion (7,) a fraction ``s`` of the way between two poses given as
    position and roll, pitch, yaw (6,)."""
    pose = (1.0 - s) * np.asarray(start, dtype=float) + s * np.asarray(end, dtype=float)
    return np.concatenate([pose[0:3], euler_to_quat(*pose[3:6])])


@njit(cache=True)
def coupled_steps(
    torso,
    torso_mass,
    inertia,
    inertia_inv,
    gravity,
    corners,
    yaw,
    rest_theta0,
    pos,
    vel,
    theta,
    omega,
    rest_pos,
    l0,
    voronoi,
    dtheta0,
    ea,
    ga,
    ei,
    mass,
    inertia_el,
    par,
    servo,
    servo_cmd,
    servo_par,
    pulley,
    free0,
    prev_corner,
    f_ext,
    mu_lat,
    v_eps,
    implicit,
    max_age,
    h,
    n_steps,
    normal,
    out,
    force,
    moment,
    rhs,
    vflat,
    cth,
    sth,
    lu,
    kband,
    jvec,
    jmeta,
    reaction,
    hold_torso,
):
    """Advance torso (p q v w_body) and four legs ``n_steps`` steps of ``h``.

    ``cth``/``sth`` (4, E) are each leg's directors, kept current by the symplectic step;
    ``lu``, ``kband``, ``jvec``, ``jmeta`` each leg's Jacobian state for the implicit step,
    whose factorisation serves up to ``max_age`` steps (:func:`implicit_once`).

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
        ww0 = rot[0, 0] * wb[0] + rot[0, 1] * wb[1] + rot[0, 2] * wb[2]  # world angular velocity
        ww1 = rot[1, 0] * wb[0] + rot[1, 1] * wb[1] + rot[1, 2] * wb[2]
        ww2 = rot[2, 0] * wb[0] + rot[2, 1] * wb[1] + rot[2, 2] * wb[2]
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
            vcx = v[0] + ww1 * rcz - ww2 * rcy
            vcy = v[1] + ww2 * rcx - ww0 * rcz
            vcz = v[2] + ww0 * rcy - ww1 * rcx
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
            root[5] = ww0 * uy - ww1 * ux  # omega . (u x e_z)
            # servo: first-order lag towards the command, at most as fast as its load allows
            servo[i] = servo_step(
                servo[i], servo_cmd[i], h, servo_par[0], out[i, O_T] * pulley, servo_par[1], servo_par[2], servo_par[3]
            )
            free_length = free0[i] - pulley * servo[i]  # the cable the servo leaves out
            if implicit:
                implicit_once(
                    pos[i],
                    vel[i],
                    theta[i],
                    omega[i],
                    rest_pos,
                    l0,
                    voronoi,
                    dtheta0,
                    ea,
                    ga,
                    ei,
                    mass,
                    inertia_el,
                    par[i],
                    free_length,
                    root,
                    h,
                    normal[i],
                    out[i],
                    force,
                    moment,
                    lu[i],
                    kband[i],
                    jvec[i],
                    jmeta[i],
                    max_age,
                    rhs,
                    vflat,
                    cth[i],
                    sth[i],
                )
            else:
                symplectic_once(
                    pos[i],
                    vel[i],
                    theta[i],
                    omega[i],
                    rest_pos,
                    l0,
                    voronoi,
                    dtheta0,
                    ea,
                    ga,
                    ei,
                    mass,
                    inertia_el,
                    inv_mass,
                    inv_inertia,
                    par[i],
                    free_length,
                    root,
                    h,
                    normal[i],
                    out[i],
                    force,
                    moment,
                    cth[i],
                    sth[i],
                )
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
                vfx = v[0] + ww1 * rfz - ww2 * rfy
                vfy = v[1] + ww2 * rfx - ww0 * rfz
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
        if hold_torso:
            continue
        torso_step(torso, fx_t, fy_t, fz_t, tx, ty, tz, rot, torso_mass, inertia, inertia_inv, h)
    return n_steps


@njit(cache=True, parallel=True)
def batch_steps(
    torso,
    torso_mass,
    inertia,
    inertia_inv,
    gravity,
    corners,
    yaw,
    rest_theta0,
    pos,
    vel,
    theta,
    omega,
    rest_pos,
    l0,
    voronoi,
    dtheta0,
    ea,
    ga,
    ei,
    mass,
    inertia_el,
    par,
    servo,
    servo_cmd,
    servo_par,
    pulley,
    free0,
    prev_corner,
    f_ext,
    mu_lat,
    v_eps,
    implicit,
    max_age,
    h,
    n_steps,
    normal,
    out,
    force,
    moment,
    rhs,
    vflat,
    cth,
    sth,
    lu,
    kband,
    jvec,
    jmeta,
    reaction,
    done,
):
    """:func:`coupled_steps` for B robots of one model at once, one thread per robot: every per-robot
    array has a leading axis of length B; ``done`` (B,) receives each robot's completed steps."""
    for b in prange(torso.shape[0]):
        done[b] = coupled_steps(
            torso[b],
            torso_mass,
            inertia,
            inertia_inv,
            gravity,
            corners,
            yaw,
            rest_theta0,
            pos[b],
            vel[b],
            theta[b],
            omega[b],
            rest_pos,
            l0,
            voronoi,
            dtheta0,
            ea,
            ga,
            ei,
            mass,
            inertia_el,
            par[b],
            servo[b],
            servo_cmd[b],
            servo_par,
            pulley,
            free0[b],
            prev_corner[b],
            f_ext[b],
            mu_lat,
            v_eps,
            implicit,
            max_age,
            h,
            n_steps,
            normal[b],
            out[b],
            force[b],
            moment[b],
            rhs[b],
            vflat[b],
            cth[b],
            sth[b],
            lu[b],
            kband[b],
            jvec[b],
            jmeta[b],
            reaction[b],
            False,
        )


@PLANTS.register()
class CosseratPlant:
    """Torso + four soft legs behind the :class:`slotexp.plants.Plant` interface."""

    command_type = TendonCommand

    @classmethod
    def from_config(cls, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> CosseratPlant:
        return cls(cfg, robot, x0)

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
        self.corners = np.column_stack(
            [np.sign(np.cos(self.yaw)) * lx / 2, np.sign(np.sin(self.yaw)) * ly / 2, np.full(4, -lz / 2)]
        )
        drop = m.rest_pos[0, 1] - m.rest_pos[-1, 1]
        # The torso starts level, with the resting feet just touching the ground; settling lowers it
        # onto the scenario's offset pose (see _settle_legs).
        z0 = lz / 2 + drop + (x0[5] - robot.stance_height)
        self.start_pose = np.array([x0[3], x0[4], lz / 2 + drop, 0.0, 0.0, x0[2]])  # position, roll pitch yaw
        self.target_pose = np.array([x0[3], x0[4], z0, *x0[0:3]])
        self.torso = np.concatenate([pose_between(self.start_pose, self.target_pose, 0.0), x0[9:12], np.zeros(3)])
        self.torso[10:13] = quat_to_rot(euler_to_quat(*x0[0:3])).T @ x0[6:9]  # body-frame angular velocity
        rot = quat_to_rot(self.torso[3:7])
        self.pos = np.repeat(m.rest_pos[None], 4, axis=0).copy()
        corner_w = self.torso[0:3] + self.corners @ rot.T
        self.pos[:, :, 1] += (corner_w[:, 2] - m.rest_pos[0, 1])[:, None]
        self.vel = np.zeros_like(self.pos)
        self.theta = np.repeat(m.rest_theta[None], 4, axis=0).copy()
        self.omega = np.zeros_like(self.theta)
        self.prev_corner = corner_w.copy()
        self.par = np.tile(leg_params(cfg), (4, 1))  # one row per leg, on the ground, no tip load
        # free cable with the servo at zero; the servo angle then sets each leg's free length
        self.free0 = np.full(4, rest_free_length(m, self.par[0], cfg.robot.tendon.slack))
        self.servo = np.zeros(4)  # servo (tendon) angle, rad
        self.servo_cmd = np.zeros(4)
        sc = cfg.robot.servo
        self.servo_par = np.array(
            [
                sc.time_constant,
                sc.stall_torque,
                sc.no_load_speed_rpm * RPM_TO_RAD_S,
                sc.profile_velocity_rpm * RPM_TO_RAD_S,
            ]
        )
        self.normal = np.zeros((4, n))
        self.out = np.zeros((4, len(OUT)))
        self.reaction = np.zeros((4, 6))
        nd = 3 * n - 1
        # scratch (force, moment, rhs, vflat), the directors, and each leg's implicit-step Jacobian
        self._work = (
            np.zeros((n, 2)),
            np.zeros(n - 1),
            np.zeros(nd),
            np.zeros(nd),
            np.cos(self.theta),
            np.sin(self.theta),
            *jacobian_state(n, 4),
        )
        self.marker_nodes = sorted({0, (n - 1) // 3, 2 * (n - 1) // 3, n - 1})
        self._legs: np.ndarray | None = None  # leg_world's, until the legs next move
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
        """Every node of every leg in the world frame (4, N, 3), read-only: computed once per plant step
        (the controller's feet, the log's markers, shapes and 3D scene all read it)."""
        if self._legs is None:
            corners, u = self._plane()
            out = corners[:, None, :] + self.pos[:, :, 0:1] * u[:, None, :]
            out[:, :, 2] = self.pos[:, :, 1]
            out.flags.writeable = False
            self._legs = out
        return self._legs

    def feet(self) -> np.ndarray:
        return self.leg_world()[:, -1, :]

    def legs(self) -> np.ndarray:
        return self.leg_world()

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
            "/legs/tendon": {
                "tension_n": self.out[:, O_T].copy(),
                "servo_deg": np.rad2deg(self.servo),
                "command_deg": np.rad2deg(self.servo_cmd),
            },
            "/legs/contact": {"normal_n": self.out[:, O_N].copy(), "friction_n": self.out[:, O_F].copy()},
            "/legs/root": {"force_n": self.reaction[:, 0:3].copy(), "moment_nm": self.reaction[:, 3:6].copy()},
        }

    def _settle_legs(self, seconds: float) -> None:
        """Put the robot down in equilibrium at its initial pose.

        The torso is held, at rest, while the legs settle onto the ground. It starts level
        with the resting feet just touching and is lowered in small moves onto the
        scenario's initial pose over the first half of the settling time: a pose whose
        corner is lower or tilted down puts that leg's resting foot tens of millimetres
        into the ground, and placed there at once the contact folded the leg under the
        body (combined offsets: the front-right foot 144 mm from its root instead of
        250 mm), a state no robot set down on its feet is in. The servos take
        the common angle at which the legs carry the robot's weight there (a few
        Newton steps on the total normal force, with the actuation map's slope), as a
        robot is powered up before it is let go: at zero tendon the legs cannot carry
        it, and a servo at its rated speed needs about 0.3 s to wind in. The torso is
        then released with the scenario's velocities.
        """
        weight = self.robot.mass * self.cfg.sim.gravity
        slope = 4.0 * self.cfg.robot.actuation.slope_n_per_deg
        top = self.cfg.robot.leg.tendon_max_deg
        angle = float(tendon_angle_deg(np.array([weight / 4.0]), self.cfg.robot.actuation, top)[0])
        velocities = self.torso[7:13].copy()
        self.torso[7:13] = 0.0
        lowering = SETTLE_ITERATIONS // 2
        for k in range(SETTLE_ITERATIONS):
            self.servo[:] = self.servo_cmd[:] = np.deg2rad(angle)
            if k < lowering:  # in small moves, so that every leg deforms continuously onto the ground
                for s in np.linspace(k, k + 1, LOWERING_MOVES + 1)[1:] / lowering:
                    self.torso[0:7] = pose_between(self.start_pose, self.target_pose, float(s))
                    self._run(seconds / SETTLE_ITERATIONS / LOWERING_MOVES, np.zeros(3), hold=True)
            else:
                self._run(seconds / SETTLE_ITERATIONS, np.zeros(3), hold=True)
            angle = float(np.clip(angle + (weight - self.out[:, O_N].sum()) / slope, 0.0, top))
        self.torso[7:13] = velocities
        self.time = 0.0

    def step(self, command: TendonCommand, period: float, external_force: np.ndarray | None = None) -> None:
        """Advance ``period`` with the servos tracking the commanded angles (ground forces are the legs' own)."""
        self.servo_cmd[:] = np.deg2rad(command.tendon_deg)
        f_ext = np.zeros(3) if external_force is None else np.asarray(external_force, dtype=float)
        self._run(period, f_ext, hold=False)

    def _run(self, period: float, f_ext: np.ndarray, hold: bool) -> None:
        n, h = self._steps(period)
        own = {name: getattr(self, name) for name in _OWN}
        done = coupled_steps(*self._kernel_args(own, self._work, f_ext, h, n), hold)
        self._advanced(done, n, h, "the soft-leg simulation", "the scenario's offsets and impulses")

    def _steps(self, period: float) -> tuple[int, float]:
        """How many steps cover ``period``, and their length (at most ``sim.dt``, equal)."""
        n = max(1, int(round(period / self.dt)))
        return n, period / n

    def _kernel_args(
        self, own: dict[str, np.ndarray], work: tuple[np.ndarray, ...], f_ext: np.ndarray, h: float, n: int
    ) -> tuple:
        """The arguments :func:`coupled_steps` and :func:`batch_steps` share, in their order: this plant's
        model and settings, and the per-robot arrays ``own`` (named as in ``_OWN``) and ``work`` (scratch),
        one robot's or a batch's stacked along a first axis."""
        m = self.model
        return (
            own["torso"],
            self.torso_mass,
            self.inertia,
            self.inertia_inv,
            self.cfg.sim.gravity,
            self.corners,
            self.yaw,
            float(m.rest_theta[0]),
            own["pos"],
            own["vel"],
            own["theta"],
            own["omega"],
            m.rest_pos,
            m.l0,
            m.voronoi,
            m.dtheta0,
            m.ea,
            m.ga,
            m.ei,
            m.mass,
            m.inertia,
            own["par"],
            own["servo"],
            own["servo_cmd"],
            self.servo_par,
            self.cfg.robot.leg.pulley_radius,
            own["free0"],
            own["prev_corner"],
            f_ext,
            self.cfg.robot.contact.friction,
            self.cfg.robot.contact.slip_velocity,
            self.implicit,
            self.cfg.plant.jacobian_age,
            h,
            n,
            own["normal"],
            own["out"],
            *work,
            own["reaction"],
        )

    def _advanced(self, done: int, n: int, h: float, what: str, loads: str) -> None:
        """Count ``done`` of ``n`` steps of ``h``; a run cut short or gone non-finite diverged."""
        self.time += done * h
        self._legs = None  # the legs moved
        if done < n or not np.all(np.isfinite(self.torso)):
            limit = stable_dt(self.model, self.cfg.robot.contact.stiffness)
            raise DivergenceError(
                divergence_message(
                    what, self.time, h, self.cfg.plant.integrator, limit, ("sim.dt", "plant.integrator"), loads, self.dt
                )
            )

    def apply_impulse(self, linear: np.ndarray, angular: np.ndarray) -> None:
        rot = quat_to_rot(self.torso[3:7])
        self.torso[7:10] += np.asarray(linear, dtype=float) / self.torso_mass
        self.torso[10:13] += self.inertia_inv @ (rot.T @ np.asarray(angular, dtype=float))


# each robot's own arrays (state, servo, contact output): a batch stacks them along a first axis
_OWN = (
    "torso",
    "pos",
    "vel",
    "theta",
    "omega",
    "par",
    "servo",
    "servo_cmd",
    "free0",
    "prev_corner",
    "normal",
    "out",
    "reaction",
)


class CosseratBatch:
    """B soft robots of one config stepped together in one compiled call, one thread per robot.

    For searches and Monte Carlo runs: each robot has its own tendon commands and
    state, and they advance in parallel (numba ``prange``, as many threads as
    ``NUMBA_NUM_THREADS``, every core by default). The robots are ordinary
    :class:`CosseratPlant` objects, set down as usual; the batch moves their state
    into stacked arrays and leaves each plant's attributes as views of its row, so
    ``state()``, ``feet()`` and ``telemetry()`` keep working on every one of them.
    Stepped in a batch or alone, a robot follows the same arithmetic.
    """

    def __init__(self, plants: list[CosseratPlant]) -> None:
        if not plants:
            raise ValueError("a batch needs at least one plant")
        first = plants[0]
        if any(p.cfg is not first.cfg and (p.cfg.robot != first.cfg.robot or p.dt != first.dt) for p in plants):
            raise ValueError("every plant in a batch must share the robot and sim.dt of the first")
        if any(p.cfg.plant != first.cfg.plant for p in plants):
            raise ValueError("every plant in a batch must use the same integrator and Jacobian age")
        self.plants = plants
        self.stacked = {name: np.stack([getattr(p, name) for p in plants]) for name in _OWN}
        self.work = tuple(np.stack([p._work[k] for p in plants]) for k in range(len(first._work)))
        for b, p in enumerate(plants):
            for name, stacked in self.stacked.items():
                setattr(p, name, stacked[b])
            p._work = tuple(w[b] for w in self.work)
        self.f_ext = np.zeros((len(plants), 3))
        self.done = np.zeros(len(plants), dtype=np.int64)

    def __len__(self) -> int:
        return len(self.plants)

    def step(self, tendon_deg: np.ndarray, period: float) -> None:
        """Advance every robot ``period`` with its servos tracking ``tendon_deg`` (B, 4), deg."""
        tendon_deg = np.asarray(tendon_deg, dtype=float)
        if tendon_deg.shape != (len(self), 4):
            raise ValueError(f"tendon_deg must be ({len(self)}, 4), not {tendon_deg.shape}")
        first = self.plants[0]
        self.stacked["servo_cmd"][:] = np.deg2rad(tendon_deg)
        n, h = first._steps(period)
        batch_steps(*first._kernel_args(self.stacked, self.work, self.f_ext, h, n), self.done)
        for b, p in enumerate(self.plants):
            p._advanced(int(self.done[b]), n, h, f"robot {b} of the batch", "its tendon commands")
