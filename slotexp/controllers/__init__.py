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
from ..registry import Registry
from ..robot import RobotModel


@dataclass
class ControlStep:
    forces: np.ndarray  # (4, 3) applied ground-reaction forces, world frame
    tendon_deg: np.ndarray  # (4,) commanded tendon angles
    solution: MpcSolution
    plan: ContactPlan
    x_ref: np.ndarray  # (H, 12)
    fallback: bool
    violations: dict[str, float]  # per constraint group, of the applied input
    telemetry: dict = field(default_factory=dict)  # the controller's own state, logged as /controller
    # the plant command, when the controller builds one itself (the rigid controller's LegCommand);
    # None: the simulation builds it from forces and tendon_deg (slotexp.plants.command_for)
    command: object | None = None


class Controller(Protocol):
    period: float
    infeasible_steps: int

    def step(self, t: float, x: np.ndarray, feet: np.ndarray) -> ControlStep:
        """One MPC step at time ``t`` from measured state ``x`` (12,) and world foot positions ``feet`` (4, 3)."""


CONTROLLERS: Registry[type] = Registry(__name__, "controller")


def make_controller(cfg: SlotConfig, robot: RobotModel) -> Controller:
    """The controller ``cfg.controller.name`` selects."""
    return CONTROLLERS.get(cfg.controller.name)(cfg, robot)


__all__ = ["ControlStep", "Controller", "CONTROLLERS", "make_controller"]
