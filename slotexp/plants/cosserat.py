"""The soft-leg plant (``plant=cosserat``): a rigid torso and four Cosserat legs, coupled both ways.

The Plant around the coupled kernels of :mod:`slotexp.soft.coupled` (whose docstring says what
the coupling conserves and assumes): it sets the robot down from the config, settles the legs
under the torso before a run, holds each robot's arrays and steps them, one robot or a batch
(:class:`CosseratBatch`), and reports the state, the feet, the markers and the legs' telemetry.
Servo commands go through the robot's horn map as on the robot; no fictitious force holds
anything up.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .. import telemetry as T
from ..actuation import tendon_angle_deg
from ..body import euler_to_quat, horizontal, quat_to_euler, quat_to_rot
from ..config import PlantConfig, SlotConfig, TorsoConfig, choice_field, num_field
from ..errors import ConfigError, DivergenceError
from ..robot import RobotModel, leg_root_z, leg_roots
from ..soft.coupled import (
    Robot,
    Settings,
    TorsoModel,
    Work,
    augmented_inertia,
    batch_steps,
    coupled_steps,
    new_work,
    row,
    stacked,
    velocity_from_momentum,
)
from ..soft.integrators import J_AGE, J_UNSOLVED, divergence_message, stable_dt
from ..soft.loads import pair_free_length, rest_free_length
from ..soft.params import O_F, O_FL, O_N, O_T, OUT, P_FSOLVE, P_JTURN, P_TPAIR, leg_params
from ..soft.rod import LegModel, build_leg, lateral_stiffness
from ..soft.servo import RPM_TO_RAD_S
from . import PLANTS, TendonCommand

SETTLE_S = 0.4  # s the legs get to settle under the held torso before a run starts
SETTLE_ITERATIONS = 8  # ... in this many steps towards the servo angle that carries the weight
LOWERING_MOVES = 25  # per settling step in the first half, in which the torso is lowered onto its initial pose
# Newton passes of a retaken period (plant.retakes): backward Euler, which the corrections solve, where the linearly
# implicit step (one linearisation at each step's start) blew up: a soft leg curled by its tendon turns its elements
# by tenths of a radian in one step, beyond what one linearisation covers
RETAKE_NEWTON = 8


def belly_points(torso: TorsoConfig) -> np.ndarray:
    """The torso's points that can touch the ground (body frame): its bottom face's corners, edge midpoints
    and centre with ``robot.torso.ground_contact``, else none."""
    if not torso.ground_contact:
        return np.zeros((0, 3))
    lx, ly, lz = torso.size
    points = np.array([[a * lx / 2, b * ly / 2, -lz / 2] for a in (-1.0, 0.0, 1.0) for b in (-1.0, 0.0, 1.0)])
    return points - horizontal(torso.com_offset)


def pose_between(start: np.ndarray, end: np.ndarray, s: float) -> np.ndarray:
    """Torso position and quaternion (7,) a fraction ``s`` of the way between two poses given as
    position and roll, pitch, yaw (6,)."""
    pose = (1.0 - s) * np.asarray(start, dtype=float) + s * np.asarray(end, dtype=float)
    return np.concatenate([pose[0:3], euler_to_quat(*pose[3:6])])


@dataclass
class CosseratPlantConfig(PlantConfig):
    """The soft plant's settings (``plant.*`` with ``plant=cosserat``)."""

    name: str = "cosserat"
    # implicit (linearly implicit Euler, stable at 1e-4 s and above) or symplectic (dt <~ 3e-5 s)
    integrator: str = choice_field("implicit", "implicit", "symplectic")
    # implicit step: steps a factored Jacobian may serve (1: a fresh one every step); a change of contact,
    # friction regime or tendon state refreshes it sooner (slotexp/soft/integrators.py)
    jacobian_age: int = num_field(1, lo=1, hi=100000, unit="steps")
    # implicit step: passes per step (1: linearly implicit, one linearisation at the step's start; more:
    # Newton corrections towards backward Euler, which stays stable in contact at millisecond steps)
    newton: int = num_field(1, lo=1, hi=50, unit="passes")
    # implicit step: a control period whose steps diverge is taken again from its start by backward Euler
    # (RETAKE_NEWTON passes), at half the step each further time it diverges, up to this many times (0: stop)
    retakes: int = num_field(4, lo=0, hi=10, unit="retakes")
    # implicit step: the feet's friction along the legs' planes, solved at the step's end through the step's
    # compliance (solved: a sliding or sticking foot answers its load as its own mass does; slotexp/soft/friction.py),
    # or linearised at its secant slope at the step's start (secant: as if it weighed h mu N / |v| more). The
    # symplectic step solves each node's friction itself, as solved does.
    friction: str = choice_field("solved", "secant", "solved")
    # implicit step: the Jacobians are made afresh once an element has turned this far (rad) since they were made,
    # whatever their age (0: by age, contact and cable only)
    jacobian_turn: float = num_field(0.0, lo=0.0, hi=10.0, unit="rad")
    # setting down: the time over which the servos wind the tendons in to the angle that carries the weight, within
    # the first settling move of SETTLE_S / SETTLE_ITERATIONS (0: at once; a cable shortened at once whips a soft
    # leg, its nodes at metres per second, before the legs settle)
    wind_in_s: float = num_field(SETTLE_S / SETTLE_ITERATIONS, lo=0.0, hi=SETTLE_S / SETTLE_ITERATIONS, unit="s")
    # ... in every settling move, each move's change of the angle that carries the weight (false: the first move's
    # only, the later moves' changes taken at once, which whips soft legs: docs/results/plant.md)
    wind_in_every_move: bool = False


@PLANTS.register()
class CosseratPlant:
    """Torso + four soft legs behind the :class:`slotexp.plants.Plant` interface."""

    command_type = TendonCommand
    schema: ClassVar[type] = CosseratPlantConfig
    free_space: ClassVar[bool] = True  # sim.ground=false: the robot in free space (checks of what it conserves)

    @staticmethod
    def check(cfg: SlotConfig) -> None:
        """The laws the chosen step has: static friction and the paper's rod need the right integrator."""
        symplectic = cfg.plant.integrator == "symplectic"
        if symplectic and cfg.robot.contact.static_friction is not None:
            raise ConfigError(
                "robot.contact.static_friction is a law of the implicit step only: drop it, or use "
                "plant.integrator=implicit"
            )
        if symplectic and cfg.plant.newton > 1:
            raise ConfigError("plant.newton is the implicit step's: drop it, or use plant.integrator=implicit")
        if symplectic and cfg.plant.friction == "secant":
            raise ConfigError(
                "plant.friction=secant is the implicit step's linearisation (the symplectic step solves each "
                "node's friction itself): drop it, or use plant.integrator=implicit"
            )
        if cfg.robot.leg.model == "paper" and not symplectic:
            raise ConfigError(
                "robot.leg.model=paper has no Jacobian for the implicit step: add plant.integrator=symplectic "
                "sim.dt=2e-5"
            )
        tendon = cfg.robot.tendon
        if tendon.routing == "bowstring" and tendon.antagonist:
            raise ConfigError(
                "robot.tendon.antagonist is a cable pair along the leg (robot.tendon.routing=offset): drop one"
            )

    @classmethod
    def from_config(cls, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> CosseratPlant:
        return cls(cfg, robot, x0)

    def __init__(self, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> None:
        self.cfg = cfg
        self.robot = robot
        self.dt = cfg.sim.dt
        self.time = 0.0
        self.implicit = cfg.plant.integrator == "implicit"
        self.retaken_periods = 0  # control periods taken again after their steps diverged (_retake)
        leg_cfg = cfg.robot.leg
        self.model: LegModel = build_leg(leg_cfg, anchor_fraction=cfg.robot.tendon.routed_fraction)
        self.wave_speed = float(np.sqrt(leg_cfg.youngs_modulus / leg_cfg.density))  # m/s: no node moves faster
        m = self.model
        n = m.n_nodes
        lx, ly, lz = cfg.robot.torso.size
        # each root node moves with its corner, so its mass rides with the torso
        self.torso_mass = cfg.robot.torso.mass + 4 * m.mass[0]
        self.inertia = self.torso_mass / 12.0 * np.diag([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
        self.yaw = np.deg2rad(np.asarray(leg_cfg.yaw_deg, dtype=float))
        self.corners = leg_roots(cfg.robot)  # relative to the torso's mass centre
        root_z = leg_root_z(cfg.robot)
        drop = m.rest_pos[0, 1] - m.rest_pos[-1, 1]
        # The torso starts level, with the resting feet just touching the ground; settling lowers it
        # onto the scenario's offset pose (see _settle_legs).
        z0 = -root_z + drop + (x0[5] - robot.stance_height)
        self.start_pose = np.array([x0[3], x0[4], -root_z + drop, 0.0, 0.0, x0[2]])  # position, roll pitch yaw
        self.target_pose = np.array([x0[3], x0[4], z0, *x0[0:3]])
        self.torso = np.concatenate([pose_between(self.start_pose, self.target_pose, 0.0), np.zeros(6)])
        self.momentum = np.zeros(6)  # linear, and angular about the world origin (coupled_steps)
        rot = quat_to_rot(self.torso[3:7])
        self.pos = np.repeat(m.rest_pos[None], 4, axis=0).copy()
        corner_w = self.torso[0:3] + self.corners @ rot.T
        self.pos[:, :, 1] += (corner_w[:, 2] - m.rest_pos[0, 1])[:, None]
        self.eta = np.zeros((4, n))  # each node's offset across its leg's plane
        self.vel = np.zeros_like(self.pos)
        self.theta = np.repeat(m.rest_theta[None], 4, axis=0).copy()
        self.omega = np.zeros_like(self.theta)
        self.prev_corner = corner_w.copy()
        self.prev_u = np.column_stack([np.cos(self.yaw), np.sin(self.yaw)])  # the planes' directions (level torso)
        self.par = np.tile(leg_params(cfg, ground=cfg.sim.ground), (4, 1))  # one row per leg, no tip load
        # free cable with the servo at zero; the servo angle then sets each leg's free length
        self.free0 = np.full(4, rest_free_length(m, self.par[0], cfg.robot.tendon.slack))
        if cfg.robot.tendon.antagonist:
            self.par[:, P_TPAIR] = pair_free_length(m, self.par[0], self.free0[0])
        self.par[:, P_FSOLVE] = 1.0 if cfg.plant.friction == "solved" else 0.0
        self.par[:, P_JTURN] = cfg.plant.jacobian_turn
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
        self.belly_points = belly_points(cfg.robot.torso)
        contact = cfg.robot.contact
        mu_belly = contact.friction if cfg.robot.torso.friction is None else cfg.robot.torso.friction
        self.belly_par = np.array([contact.stiffness, contact.damping, mu_belly, contact.slip_velocity])
        self.belly = np.zeros(3)  # the torso's underside on the ground: normal force, friction x, y
        self.k_lat = lateral_stiffness(cfg.robot.leg)  # 0: the legs are rigid across their planes
        self.lateral = np.zeros((4, 2))  # each contact patch's deflection across its plane (m) and its rate
        self.normal = np.zeros((4, n))
        self.out = np.zeros((4, len(OUT)))
        self.reaction = np.zeros((4, 6))
        self._work = new_work(self.theta)  # scratch, the directors, each leg's implicit-step Jacobian
        self.marker_nodes = sorted({0, (n - 1) // 3, 2 * (n - 1) // 3, n - 1})
        self._legs: np.ndarray | None = None  # leg_world's, until the legs next move
        self._settle_legs(SETTLE_S)
        self._release(x0[9:12], x0[6:9])

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
            lat = np.column_stack([-u[:, 1], u[:, 0], np.zeros(4)])
            out = corners[:, None, :] + self.pos[:, :, 0:1] * u[:, None, :] + self.eta[:, :, None] * lat[:, None, :]
            out[:, :, 2] = self.pos[:, :, 1]
            out.flags.writeable = False
            self._legs = out
        return self._legs

    def feet(self) -> np.ndarray:
        return self.leg_world()[:, -1, :]

    def foot_reach(self) -> np.ndarray:
        """Each foot's distance from its leg's root along the leg's plane (4,), m: a stroke is how far it moves."""
        return self.pos[:, -1, 0].copy()

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
            T.LEGS_SHAPE: {name: legs[i] for i, name in enumerate(names)},
            T.LEGS_TENDON: {
                "tension_n": self.out[:, O_T].copy(),
                "servo_deg": np.rad2deg(self.servo),
                "command_deg": np.rad2deg(self.servo_cmd),
            },
            # friction_n: the size of the leg's friction, along its plane and across it
            T.LEGS_CONTACT: {
                "normal_n": self.out[:, O_N].copy(),
                "friction_n": np.hypot(self.out[:, O_F], self.out[:, O_FL]),
                "lateral_m": self.lateral[:, 0].copy(),  # the patch's deflection across the plane
            },
            T.LEGS_ROOT: {"force_n": self.reaction[:, 0:3].copy(), "moment_nm": self.reaction[:, 3:6].copy()},
            T.TORSO_CONTACT: {"normal_n": float(self.belly[0]), "friction_n": self.belly[1:3].copy()},
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
        it, and a servo at its rated speed needs about 0.3 s to wind in. The robot is
        then released with the scenario's velocities (:meth:`_release`).
        """
        weight = self.robot.mass * self.cfg.sim.gravity
        slope = 4.0 * self.cfg.robot.actuation.slope_n_per_deg
        top = self.cfg.robot.leg.tendon_max_deg
        angle = float(tendon_angle_deg(np.array([weight / 4.0]), self.cfg.robot.actuation, top)[0])
        lowering = SETTLE_ITERATIONS // 2
        move = seconds / SETTLE_ITERATIONS / LOWERING_MOVES
        wind_in = self.cfg.plant.wind_in_s
        previous = 0.0  # rad: the servos' angle before this settling move
        for k in range(SETTLE_ITERATIONS):
            target = np.deg2rad(angle)
            self.servo[:] = self.servo_cmd[:] = target
            # the servos wind the tendons in over plant.wind_in_s: in the first move, or in every one
            ramp = wind_in > 0.0 and (k == 0 or self.cfg.plant.wind_in_every_move)
            if k < lowering or ramp:  # in small moves, so that every leg deforms continuously onto the ground
                for j, s in enumerate(np.linspace(k, k + 1, LOWERING_MOVES + 1)[1:] / lowering):
                    if ramp:
                        level = previous + (target - previous) * min(1.0, (j + 1) * move / wind_in)
                        self.servo[:] = self.servo_cmd[:] = level
                    if k < lowering:
                        self.torso[0:7] = pose_between(self.start_pose, self.target_pose, float(s))
                    self._run(move, np.zeros(3), hold=True)
            else:
                self._run(seconds / SETTLE_ITERATIONS, np.zeros(3), hold=True)
            previous = target
            angle = float(np.clip(angle + (weight - self.out[:, O_N].sum()) / slope, 0.0, top))
        self.time = 0.0

    def _release(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """Let the robot go with the torso moving at ``linear`` and ``angular`` (world) velocity: the whole
        robot moves with it as one rigid body (each leg's nodes and elements get the rigid motion of its
        root frame on top of what they had), and the momentum state is the one of that motion."""
        rot = quat_to_rot(self.torso[3:7])
        _, u = self._plane()
        p = self.torso[0:3]
        for i in range(4):
            axis = np.cross(u[i], [0.0, 0.0, 1.0])  # the in-plane angle's axis
            r = self.leg_world()[i] - p
            rigid = linear + np.cross(angular, r)
            self.vel[i, :, 0] += rigid @ u[i]
            self.vel[i, :, 1] += rigid[:, 2]
            self.omega[i] += angular @ axis
        aug = self._augmented_inertia()
        pi = aug @ np.concatenate([linear, angular])
        self.momentum[:] = np.concatenate([pi[0:3], pi[3:6] + np.cross(p, pi[0:3])])
        self.torso[7:10] = linear
        self.torso[10:13] = rot.T @ angular

    def _augmented_inertia(self) -> np.ndarray:
        """The 6x6 inertia of the torso and the legs' motion across their planes (:func:`augmented_inertia`)."""
        out = np.empty((6, 6))
        rot = quat_to_rot(self.torso[3:7])
        augmented_inertia(
            self.torso,
            rot,
            self.torso_mass,
            self.inertia,
            self.corners,
            np.cos(self.yaw),
            np.sin(self.yaw),
            self.pos,
            self.model.mass,
            out,
        )
        return out

    def momentum_world(self) -> tuple[np.ndarray, np.ndarray]:
        """The whole robot's linear momentum and its angular momentum about the world origin, from the
        velocities of every part: the torso, every leg node (along its plane its own velocity, across it
        the torso's rigid motion there) and every element's spin in its plane."""
        p = self.torso[0:3]
        rot = quat_to_rot(self.torso[3:7])
        v = self.torso[7:10]
        w = rot @ self.torso[10:13]
        linear = self.torso_mass * v
        angular = np.cross(p, linear) + rot @ (self.inertia @ self.torso[10:13])
        _, u = self._plane()
        legs = self.leg_world()
        m = self.model.mass[1:, None]
        for i in range(4):
            lat = np.cross([0.0, 0.0, 1.0], u[i])
            r = legs[i, 1:]
            vlat = (v + np.cross(w, r - p)) @ lat
            velocity = self.vel[i, 1:, 0:1] * u[i] + vlat[:, None] * lat
            velocity[:, 2] += self.vel[i, 1:, 1]
            linear = linear + (m * velocity).sum(axis=0)
            angular = angular + np.cross(r, m * velocity).sum(axis=0)
            angular = angular + (self.model.inertia * self.omega[i]).sum() * np.cross(u[i], [0.0, 0.0, 1.0])
        return linear, angular

    def centre_of_mass(self) -> np.ndarray:
        """The whole robot's centre of mass (world): the torso (with the legs' root nodes) and every leg node."""
        m = self.model.mass[1:]
        legs = self.leg_world()[:, 1:]
        total = self.torso_mass * self.torso[0:3] + np.einsum("k,lkj->j", m, legs)
        return total / (self.torso_mass + 4 * m.sum())

    def step(self, command: TendonCommand, period: float, external_force: np.ndarray | None = None) -> None:
        """Advance ``period`` with the servos tracking the commanded angles (ground forces are the legs' own)."""
        self.servo_cmd[:] = np.deg2rad(command.tendon_deg)
        f_ext = np.zeros(3) if external_force is None else np.asarray(external_force, dtype=float)
        self._run(period, f_ext, hold=False)

    def _run(self, period: float, f_ext: np.ndarray, hold: bool) -> None:
        n, h = self._steps(period)
        own = self._own()
        kept = [a.copy() for a in own] if self._retaking else None  # the period's start, for a retake
        unsolved = self._unsolved().copy() if kept is not None else None
        done = coupled_steps(*self._kernel_args(own, self._work, f_ext, h, n), hold)
        if self._diverged(done, n) and kept is not None:
            done, n, h = self._retake(kept, unsolved, f_ext, n, h, hold)
        self._advanced(done, n, h, "the soft-leg simulation", "the scenario's offsets and impulses", kept is not None)

    def _own(self) -> Robot:
        """This robot's own arrays (views: the kernels write them in place)."""
        return Robot(*(getattr(self, name) for name in _OWN))

    def _unsolved(self) -> np.ndarray:
        """Each leg's count of unconverged friction solves (a view of the legs' Jacobian records)."""
        return self._work.jmeta[..., self.model.n_nodes + J_UNSOLVED]

    @property
    def unsolved_frictions(self) -> int:
        """How many of the kept steps' friction solves (``plant.friction=solved``) stopped before converging (the
        friction then is the law at the last iterate's velocities, the step's balance off by its residual); a
        diverged try that a retake replaces does not count."""
        return int(self._unsolved().sum())

    @property
    def _retaking(self) -> bool:
        """Whether a diverged period is taken again (:meth:`_retake`): the implicit step's, ``plant.retakes``."""
        return self.implicit and self.cfg.plant.retakes > 0

    def _diverged(self, done: int, n: int) -> bool:
        """A run of steps cut short by the kernel (non-finite, or a tip 100 m away), a torso gone non-finite,
        or a node faster than the rod's wave speed: in an elastic rod a material point moves at most at the
        strain times sqrt(E / rho), so a faster one is the step blowing up, not the leg."""
        return done < n or not np.all(np.isfinite(self.torso)) or not np.abs(self.vel).max() <= self.wave_speed

    def _retake(
        self, kept: list[np.ndarray], unsolved: np.ndarray, f_ext: np.ndarray, n: int, h: float, hold: bool
    ) -> tuple[int, int, float]:
        """Take a diverged period again from its start (``kept``, and the legs' ``unsolved`` friction counts then):
        backward Euler solved by Newton corrections (:data:`RETAKE_NEWTON` passes, the legs' own halvings within),
        at half the step each further time, up to ``plant.retakes`` times. Returns the last try's (steps done,
        steps, step). The period then counts in ``retaken_periods``; a period no retake carries through diverged."""
        newton = max(self.cfg.plant.newton, RETAKE_NEWTON)
        halve = self.cfg.plant.newton >= RETAKE_NEWTON  # a period already taken so is halved at once
        done = 0
        for k in range(self.cfg.plant.retakes):
            for array, start in zip(self._own(), kept):
                array[...] = start
            self._unsolved()[...] = unsolved  # the failed try's solves are not the trajectory's
            self._work.jmeta[:, self.model.n_nodes + J_AGE] = np.inf  # the failed try's Jacobians: factored afresh
            m = n << (k + halve)
            done = coupled_steps(*self._kernel_args(self._own(), self._work, f_ext, h * n / m, m, newton), hold)
            if not self._diverged(done, m):
                self.retaken_periods += 1
                return done, m, h * n / m
        return done, m, h * n / m

    def _steps(self, period: float) -> tuple[int, float]:
        """How many steps cover ``period``, and their length (at most ``sim.dt``, equal)."""
        n = max(1, int(round(period / self.dt)))
        return n, period / n

    def _kernel_args(
        self, own: Robot, work: Work, f_ext: np.ndarray, h: float, n: int, newton: int | None = None
    ) -> tuple:
        """The arguments :func:`coupled_steps` and :func:`batch_steps` share, in their order: the robot's
        arrays ``own`` and scratch ``work`` (one robot's, or a batch's stacked along a first axis), this
        plant's torso, legs and settings (``newton``: the implicit step's passes, if not the config's), the
        external force, the step and the number of steps."""
        contact = self.cfg.robot.contact
        torso = TorsoModel(
            self.torso_mass, self.inertia, self.cfg.sim.gravity, self.corners, self.yaw, float(self.model.rest_theta[0])
        )
        settings = Settings(
            self.servo_par,
            self.cfg.robot.leg.pulley_radius,
            contact.friction,
            contact.slip_velocity,
            self.implicit,
            self.cfg.plant.jacobian_age,
            self.cfg.plant.newton if newton is None else newton,
            self.belly_points,
            self.belly_par,
            self.k_lat,
        )
        return own, work, torso, self.model, settings, f_ext, h, n

    def _advanced(self, done: int, n: int, h: float, what: str, loads: str, retaken: bool = False) -> None:
        """Count ``done`` of ``n`` steps of ``h``; a run cut short or gone non-finite diverged (``retaken``: the
        steps are the last of :meth:`_retake`'s tries, if it diverged)."""
        self.time += done * h
        self._legs = None  # the legs moved
        if self._diverged(done, n):
            limit = stable_dt(self.model, self.cfg.robot.contact.stiffness)
            last = h if retaken else None
            step = self._steps(n * h)[1] if retaken else h  # the configured period's own step
            message = divergence_message(
                what,
                self.time,
                step,
                self.cfg.plant.integrator,
                limit,
                ("sim.dt", "plant.integrator"),
                loads,
                self.dt,
                last,
            )
            if self.implicit and not self._retaking:  # the retakes were turned off: say what they would do
                retakes = CosseratPlantConfig().retakes  # the schema's default
                message += (
                    f", or let the plant take a diverging period again by backward Euler (plant.retakes={retakes})"
                )
            raise DivergenceError(message)

    def apply_impulse(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """A push on the torso (world, about its centre): the momentum takes it, the velocity follows."""
        linear = np.asarray(linear, dtype=float)
        self.momentum[0:3] += linear
        self.momentum[3:6] += np.asarray(angular, dtype=float) + np.cross(self.torso[0:3], linear)
        velocity_from_momentum(
            self.torso,
            self.momentum,
            quat_to_rot(self.torso[3:7]),
            self._augmented_inertia(),
            np.empty((6, 6)),
            np.empty(6),
            np.empty(6),
        )


# each robot's own arrays (state, servo, contact output), the plant's attributes of these names: a batch
# stacks them along a first axis
_OWN = Robot._fields


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
        self.stacked = stacked([Robot(*(getattr(p, name) for name in _OWN)) for p in plants])
        self.work = stacked([p._work for p in plants])
        for b, p in enumerate(plants):
            for name, array in zip(_OWN, row(self.stacked, b)):
                setattr(p, name, array)
            p._work = row(self.work, b)
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
        self.stacked.servo_cmd[:] = np.deg2rad(tendon_deg)
        n, h = first._steps(period)
        kept = [a.copy() for a in self.stacked] if first._retaking else None
        unsolved = [p._unsolved().copy() for p in self.plants] if kept is not None else []  # for a robot's retake
        batch_steps(*first._kernel_args(self.stacked, self.work, self.f_ext, h, n), self.done)
        for b, p in enumerate(self.plants):
            done, steps, step = int(self.done[b]), n, h
            if p._diverged(done, n) and kept is not None:  # retaken alone, from its row of the period's start
                done, steps, step = p._retake([a[b] for a in kept], unsolved[b], self.f_ext[b], n, h, False)
            p._advanced(done, steps, step, f"robot {b} of the batch", "its tendon commands", kept is not None)
