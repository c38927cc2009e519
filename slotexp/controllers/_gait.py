"""What the gait controllers share: a gait from the library on a phase clock, and its contact plan.

Each MPC step the gait command (body-frame velocity and yaw rate) becomes a mix of
library primitives (:meth:`slotexp.locomotion.library.GaitLibrary.command`); the
tendon angles are that mix at the clock's phase, held for the step, and the clock
advances by the style's frequency. The contact plan the MPC sees over its horizon
comes from the same mix: a leg is in stance while its tendon is above its cycle
mean (it presses harder and tends to stick, friction ``gait.mu_stance``), in
swing while it is below (it slides, ``gait.mu_swing``). The reference positions
follow the desired path from where the robot started, so position weights in Q
bring the robot back to its path after a push.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..actuation import tendon_angle_deg
from ..config import ControllerConfig, SlotConfig, check_library, choice_field, num_field
from ..errors import ConfigError
from ..gait import contact_plan
from ..locomotion.library import GaitCommand, GaitLibrary
from ..locomotion.primitives import mix, stance
from ..reference import reference
from ..robot import RobotModel
from . import ControlStep
from ._base import MpcController


def _style_library(cfg: SlotConfig) -> dict:
    """The gait library, checked to hold ``gait.style``."""
    library = cfg.controller.library
    if cfg.gait.style not in library:
        raise ConfigError(
            f"gait.style = {cfg.gait.style!r} is not in the gait library: choose one of "
            f"{', '.join(library) or '(none)'} (conf/library/)"
        )
    return library


@dataclass
class GaitControllerConfig(ControllerConfig):
    """The gait controllers' settings (``controller=open_loop``; ``gait_mpc`` adds its gains)."""

    # how the two primitives bracketing a direction combine: whole cycles of one or the other, their
    # schedules mixed, or one primitive with their parameters interpolated (slotexp/locomotion/library.py)
    blend: str = choice_field("cycles", "cycles", "schedules", "parameters")
    # blend=cycles: how many gait cycles each choice of primitive is held; every switch between two gaits costs a
    # transient (the legs' loads rebuild), and fewer switches zigzag wider across the path (library.py)
    blend_hold: int = num_field(3, lo=1, hi=8, unit="cycles")


class GaitController(MpcController):
    """A library gait driven by a velocity and yaw-rate command; subclasses decide how the command moves."""

    schema: ClassVar[type] = GaitControllerConfig

    @staticmethod
    def check(cfg: SlotConfig) -> None:
        """The library holds ``gait.style``, and every style's cycle is a whole number of MPC ticks."""
        check_library(cfg, list(_style_library(cfg)))

    @classmethod
    def gait_cycle_steps(cls, cfg: SlotConfig) -> int:
        """The library style's clock: its cycle in MPC steps."""
        return max(1, round(cfg.mpc.rate_hz / _style_library(cfg)[cfg.gait.style].frequency_hz))

    def __init__(self, cfg: SlotConfig, robot: RobotModel) -> None:
        super().__init__(cfg, robot)
        library = _style_library(cfg)
        self.top = cfg.robot.leg.tendon_max_deg
        self.standing = float(tendon_angle_deg(np.array([self.weight / 4.0]), cfg.robot.actuation, self.top)[0])
        self.library = GaitLibrary.from_config(
            library[cfg.gait.style], self.standing, self.top, cfg.controller.blend, cfg.controller.blend_hold
        )
        self.style = self.library.style
        self.velocity = np.asarray(cfg.gait.velocity, dtype=float).copy()  # body-frame gait command, m/s
        self.psi = self.library.start_phase(self.velocity)  # the gait clock's phase, cycles
        self.yaw_rate = float(np.degrees(cfg.gait.yaw_rate))  # deg/s
        self.origin: np.ndarray | None = None
        self.command: GaitCommand | None = None

    def step(self, t: float, x: np.ndarray, feet: np.ndarray) -> ControlStep:
        if self.origin is None:
            self.origin = x[3:5].copy()
        cfg = self.cfg
        horizon = cfg.mpc.horizon
        self.command = self.library.command(self.velocity, self.yaw_rate, cycle=int(np.floor(self.psi + 1e-9)))
        dpsi = self.style.frequency_hz * self.period
        psi = self.psi + dpsi * np.arange(horizon)
        angles = mix(self.style, self.command.parts, psi, self.top)  # the gait over the horizon; its first row now
        plan = contact_plan(
            stance(self.style, self.command.parts, psi, self.top, angles=angles),
            cfg.gait,
            cfg.mpc.f_min_stance,
            cfg.mpc.f_max,
        )
        x_ref = reference(x, t, cfg.gait, self.period, horizon, path_origin=self.origin)
        forces, solution, violations = self.solve(x, x_ref, feet - x[3:6], plan)
        self.command_velocity, self.command_yaw_rate = self.velocity.copy(), self.yaw_rate  # what this step used
        gait = angles[0]  # the mix at this step's phase (psi[0] is self.psi)
        tendon = gait + self.adjust(x, feet, forces, solution)
        self.psi += dpsi
        self.steps += 1
        telemetry = {
            "phase": self.psi - dpsi,
            "velocity_command": self.command_velocity,
            "yaw_rate_command_dps": self.command_yaw_rate,
            "speed_fraction": self.command.speed_fraction,
            "yaw_fraction": self.command.yaw_fraction,
            "max_speed": self.command.max_speed,
            # the measured heading of the translating primitive with the largest weight (NaN: none)
            "primitive_heading_deg": max(
                ((w, p.heading_deg) for w, p in self.command.parts if p.heading_deg is not None and w > 0),
                default=(0.0, float("nan")),
            )[1],
            "gait_deg": gait,
            **self.extra_telemetry(),
        }
        tendon = np.clip(tendon, 0.0, self.top)
        return ControlStep(
            forces=forces,
            tendon_deg=tendon,
            command=self.command_type.from_outputs(forces, tendon),
            solution=solution,
            plan=plan,
            x_ref=x_ref,
            fallback=not solution.success,
            violations=violations,
            telemetry=telemetry,
        )

    def adjust(self, x: np.ndarray, feet: np.ndarray, forces: np.ndarray, solution) -> np.ndarray:
        """Tendon angle offsets (4,) on top of the gait, and the command's update; none here."""
        return np.zeros(4)

    def extra_telemetry(self) -> dict:
        """A subclass's own state for the log's ``/controller`` topic (computed in :meth:`adjust`)."""
        return {}


def envelope_warning(cfg: SlotConfig) -> str | None:
    """One line when a library gait is asked for more than the gait library measured (None inside it): the
    robot then walks at the envelope's speed, and a run that finishes short should not finish silently."""
    from . import CONTROLLERS

    library = cfg.controller.library
    if not issubclass(CONTROLLERS.get(cfg.controller.name), GaitController) or cfg.gait.style not in library:
        return None
    lib = GaitLibrary.from_config(library[cfg.gait.style], 0.0, cfg.robot.leg.tendon_max_deg)
    v = np.asarray(cfg.gait.velocity, float)
    speed = float(np.hypot(*v))
    heading = float(np.degrees(np.arctan2(v[1], v[0])))
    top = lib.max_speed(heading)
    if speed > top * 1.001:
        return (
            f"gait.velocity = [{v[0]:g}, {v[1]:g}] m/s asks for {speed * 1e3:.1f} mm/s at {heading:.0f} deg, beyond "
            f"what the '{cfg.gait.style}' gait library measured there ({top * 1e3:.1f} mm/s, conf/library/): the "
            f"robot walks at most that; ask for less, e.g. gait.velocity=[{0.8 * top * v[0] / speed:.3f},"
            f"{0.8 * top * v[1] / speed:.3f}]"
        )
    yaw = abs(float(np.degrees(cfg.gait.yaw_rate)))
    if yaw > lib.max_yaw_rate_dps * 1.001:
        return (
            f"gait.yaw_rate = {cfg.gait.yaw_rate:g} rad/s ({yaw:.2f} deg/s) is beyond what the '{cfg.gait.style}' "
            f"gait library turns ({lib.max_yaw_rate_dps:.2f} deg/s, conf/library/): the robot turns at most that"
        )
    return None
