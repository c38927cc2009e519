"""Plants the controller drives: the interface, the commands, and the registry (``plant=<name>``).

A plant advances one MPC period under a held command and reports the MPC state
and where its feet are. What it is commanded with depends on what it is: the
ideal plant takes ground-reaction forces (:class:`ForceCommand`), the soft-leg
plant takes tendon angles and makes its own ground forces (:class:`TendonCommand`).
Each plant names its command type, and the type builds itself from the
controller's outputs (``from_outputs``, through :func:`command_for`), so the closed
loop never passes a value a plant ignores and a new plant with a new command edits
nothing here.

A new plant is one module here, named after the plant, whose class is decorated with
``@PLANTS.register()`` and has ``from_config(cfg, robot, x0)``, plus its
``conf/plant/<name>.yaml``. Settings of its own: a subclass of ``PlantConfig`` as the
class's ``schema``, composed by its YAML (``defaults: [<name>_schema, _self_]``); rules
on the whole config: ``check(cfg)`` (:mod:`slotexp.composition`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from ..config import SlotConfig
from ..registry import Registry
from ..robot import RobotModel

STATE_NAMES = ("roll", "pitch", "yaw", "x", "y", "z", "wx", "wy", "wz", "vx", "vy", "vz")


@dataclass(frozen=True)
class ForceCommand:
    """Ground-reaction forces (4, 3), world frame, held over the period."""

    forces: np.ndarray

    @classmethod
    def from_outputs(cls, forces: np.ndarray, tendon_deg: np.ndarray) -> ForceCommand:
        return cls(np.asarray(forces, dtype=float))


@dataclass(frozen=True)
class TendonCommand:
    """Servo (tendon) angle commands (4,), degrees, held over the period."""

    tendon_deg: np.ndarray

    @classmethod
    def from_outputs(cls, forces: np.ndarray, tendon_deg: np.ndarray) -> TendonCommand:
        return cls(np.asarray(tendon_deg, dtype=float))


@dataclass(frozen=True)
class LegCommand:
    """What a legged rigid robot's joint-level loop runs with over the period (``plant=rigid``).

    Stance legs push with ``forces`` (4, 3), the MPC's ground-reaction forces
    (world frame); swing legs follow seed 002's parabola from ``swing_start`` to
    ``swing_target`` (world, foot contact points), lifted off at ``swing_t0`` for
    ``swing_duration`` s, with a Cartesian PD (``kp``, ``kd``), timed by
    ``swing_timing`` (:func:`slotexp.footstep.swing_point`) and, with
    ``swing_feedforward``, the leg's inverse dynamics for the path's acceleration.
    Both become joint torques through the foot Jacobian at every physics step, as
    a robot's motor loop runs faster than its MPC.
    """

    forces: np.ndarray
    stance: np.ndarray  # (4,) bool
    swing_start: np.ndarray  # (4, 3)
    swing_target: np.ndarray  # (4, 3)
    swing_t0: np.ndarray  # (4,) s
    swing_duration: np.ndarray  # (4,) s
    swing_height: float
    kp: np.ndarray  # (3,) N/m
    kd: np.ndarray  # (3,) N s/m
    swing_timing: str = "smooth"  # "smooth" or "linear"
    swing_feedforward: bool = True

    @classmethod
    def standing(cls, forces: np.ndarray) -> LegCommand:
        """Every leg in stance, pushing with ``forces``."""
        zeros = np.zeros((4, 3))
        return cls(
            np.asarray(forces, dtype=float), np.ones(4, bool), zeros, zeros, np.zeros(4), np.ones(4), 0.0,
            np.zeros(3), np.zeros(3),
        )  # fmt: skip

    @classmethod
    def from_outputs(cls, forces: np.ndarray, tendon_deg: np.ndarray) -> LegCommand:
        """Every leg in stance (the rigid controller builds its own, swing legs in it: ControlStep.command)."""
        return cls.standing(forces)


class Command(Protocol):
    """What a plant is commanded with over one period: a frozen dataclass that builds itself from the
    controller's two outputs (a plant whose command is neither names its own type)."""

    @classmethod
    def from_outputs(cls, forces: np.ndarray, tendon_deg: np.ndarray) -> Command:
        """The command from the MPC's ground-reaction forces (4, 3) and the tendon angles (4,), degrees."""


def command_for(command_type: type[Command], forces: np.ndarray, tendon_deg: np.ndarray) -> Command:
    """The command a plant of ``command_type`` takes, from the controller's two outputs."""
    return command_type.from_outputs(forces, tendon_deg)


class Plant(Protocol):
    time: float
    command_type: ClassVar[type[Command]]

    @classmethod
    def from_config(cls, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> Plant:
        """The plant ``cfg`` describes, starting at MPC state ``x0``."""

    def state(self) -> np.ndarray:
        """MPC state [roll, pitch, yaw, p, omega_world, v] (12,)."""

    def feet(self) -> np.ndarray:
        """World positions (4, 3) of the points the ground forces act on."""

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Torso position (3,) and attitude quaternion (w, x, y, z)."""

    def markers(self) -> dict[str, np.ndarray]:
        """Named world points to log and validate against (at least ``com``)."""

    def legs(self) -> np.ndarray:
        """Each leg's centreline (4, N, 3), world frame, root to foot, for the 3D view: every node of a
        simulated leg, or a straight root-to-foot segment where the legs are not modelled."""

    def step(self, command: Command, period: float, external_force: np.ndarray | None = None) -> None:
        """Advance ``period`` seconds under ``command`` (of :attr:`command_type`), held constant."""

    def telemetry(self) -> dict[str, dict]:
        """Plant-specific per-step log messages (topic -> message); may be empty."""

    def apply_impulse(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """Instantaneous world-frame push (N s) and angular impulse about the CoM (N m s)."""


PLANTS: Registry[type[Plant]] = Registry(__name__, "plant")


def make_plant(cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> Plant:
    """The plant ``cfg.plant.name`` selects."""
    return PLANTS.get(cfg.plant.name).from_config(cfg, robot, x0)


def nominal_state(robot: RobotModel) -> np.ndarray:
    """At rest at the stance height, level, heading +x."""
    x = np.zeros(12)
    x[5] = robot.stance_height
    return x


__all__ = [
    "Plant",
    "PLANTS",
    "Command",
    "ForceCommand",
    "TendonCommand",
    "LegCommand",
    "command_for",
    "make_plant",
    "nominal_state",
    "STATE_NAMES",
]
