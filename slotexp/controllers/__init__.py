"""Controllers: what turns a measured state into the plant's command each MPC step (``controller=<name>``).

Every controller runs the convex MPC over ground-reaction forces (paper Sec. V)
and returns a :class:`ControlStep` with the MPC's forces and the tendon angles it
commands; the ideal plant takes the forces, the soft plant and the robot the
tendon angles. They differ in how the tendon angles are made:

- ``paper``: paper eq. 11 (f_z -> tendon angle) plus the gait's fixed tendon schedule.
- ``gait_mpc``: a periodic gait from the gait library, steered by the MPC's plan
  (its horizontal forces set the gait's velocity, its normal forces the legs' base angles).
- ``open_loop``: the same library gait at the reference velocity, with no feedback.

A new controller is one module here, named after it, whose class is decorated with
``@CONTROLLERS.register()`` and takes ``(cfg, robot)``, plus its
``conf/controller/<name>.yaml``. Settings of its own: a subclass of ``ControllerConfig``
as the class's ``schema``, composed by its YAML (``defaults: [<name>_schema, _self_]``);
rules on the whole config: ``check(cfg)`` (:mod:`slotexp.composition`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ..config import SlotConfig
from ..gait import ContactPlan
from ..mpc import MpcSolution
from ..plants import Command
from ..registry import Registry
from ..robot import RobotModel


@dataclass
class ControlStep:
    """One MPC step's result: the controller's two outputs (logged whatever the plant), the one ``command``
    the plant or robot is given (of the kind it takes: ``Controller.command_type``), and the MPC's record."""

    forces: np.ndarray  # (4, 3) applied ground-reaction forces, world frame
    tendon_deg: np.ndarray  # (4,) commanded tendon angles
    command: Command  # what the plant steps with: built from the two outputs, or the rigid controller's own
    solution: MpcSolution
    plan: ContactPlan
    x_ref: np.ndarray  # (H, 12)
    fallback: bool
    violations: dict[str, float]  # per constraint group, of the applied input
    telemetry: dict = field(default_factory=dict)  # the controller's own state, logged as /controller


class Controller(Protocol):
    period: float
    infeasible_steps: int
    command_type: type[Command]  # the kind of command its steps carry

    def step(self, t: float, x: np.ndarray, feet: np.ndarray) -> ControlStep:
        """One MPC step at time ``t`` from measured state ``x`` (12,) and world foot positions ``feet`` (4, 3)."""


CONTROLLERS: Registry[type] = Registry(__name__, "controller")


def make_controller(cfg: SlotConfig, robot: RobotModel, command_type: type[Command] | None = None) -> Controller:
    """The controller ``cfg.controller.name`` selects, commanding ``command_type`` (default: what the plant
    ``cfg.plant`` takes; ``slot hardware`` passes the servos' :class:`~slotexp.plants.TendonCommand`)."""
    controller = CONTROLLERS.get(cfg.controller.name)(cfg, robot)
    if command_type is not None:
        controller.command_type = command_type
    return controller


__all__ = ["ControlStep", "Controller", "CONTROLLERS", "make_controller"]
