"""Hardware-in-the-loop: the simulator stands in for the robot behind the servo-bus interface.

:class:`SimWorld` is the plant (built by :func:`slotexp.plants.make_plant`, so any
plant the config names, ``ideal`` today) plus four position-controlled servos that
move toward their goals at the profile velocity, all advanced in wall-clock time.
:class:`SimulatedBus` is its :class:`~.bus.ServoBus`; :class:`~.odometry.SimOdometry`
reads its state. The control loop cannot tell it from the robot.

The plant gets the form of the servos' output it takes (:func:`slotexp.plants.command_for`):
the tendon angles, which drive a soft-leg plant (``plant=cosserat``, whose own servo
model then adds its short lag), and the normal forces eq. 11 predicts for them
(inverse map, :func:`slotexp.actuation.normal_force`), which is all the ideal plant
can use: it has no leg mechanics to turn a tendon pull into traction, so with
``plant=ideal`` a HIL run exercises the loop, the bus interface and the timing, not
locomotion. While torque is off (before ``enable``, in a dry run) the world is held
still: nothing is commanded, nothing moves.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..actuation import normal_force, tendon_angle_deg
from ..config import SlotConfig
from ..plants import Plant, command_for, make_plant, nominal_state
from ..robot import RobotModel
from . import xl430 as X
from .bus import ServoReadings
from .mapping import ServoMap

MAX_STEP_S = 0.1  # a longer gap (a stalled loop) is simulated as this much time, not all at once


class SimWorld:
    """Plant + servos in wall-clock time."""

    def __init__(
        self,
        cfg: SlotConfig,
        robot: RobotModel,
        smap: ServoMap,
        profile_velocity_rpm: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.plant: Plant = make_plant(cfg, robot, nominal_state(robot))
        # Compile the plant's numba kernels now, on a throwaway copy: compiling inside the
        # timed loop stalls it past odometry.max_age_s on a machine without a warm cache.
        warm = make_plant(cfg, robot, nominal_state(robot))
        warm.step(command_for(warm.command_type, np.zeros((4, 3)), np.zeros(4)), cfg.sim.dt)
        self.smap = smap
        self.actuation = cfg.robot.actuation
        self.clock = clock
        stand = tendon_angle_deg(np.full(4, robot.mass * cfg.sim.gravity / 4.0), self.actuation, smap.tendon_max_deg)
        self.goal, _ = smap.to_ticks(stand)  # the servos start where a standing robot has them
        self.position = self.goal.astype(float)
        self.velocity = np.zeros(4)
        rpm = profile_velocity_rpm if profile_velocity_rpm > 0 else 61.0
        self.max_ticks_per_s = rpm / 60.0 * X.TICKS_PER_REV
        self.torque = False
        self.sim_time = 0.0
        self._last = clock()

    def tendon_deg(self) -> np.ndarray:
        """The tendon angles the servos hold now (what a soft-leg plant is driven by)."""
        return self.smap.to_tendon_deg(self.position)

    def forces(self) -> np.ndarray:
        """Ground forces (4, 3): the normal force eq. 11 predicts for each servo's present tendon angle."""
        if not self.torque:
            return np.zeros((4, 3))
        fz = np.maximum(normal_force(self.smap.to_tendon_deg(self.position), self.actuation), 0.0)
        out = np.zeros((4, 3))
        out[:, 2] = fz
        return out

    def sync(self) -> None:
        """Advance to now: servos toward their goals, then the plant under the resulting forces."""
        now = self.clock()
        dt = min(now - self._last, MAX_STEP_S)
        self._last = now
        if not self.torque or dt <= 1e-5:
            self.velocity[:] = 0.0
            return
        step = np.clip(self.goal - self.position, -self.max_ticks_per_s * dt, self.max_ticks_per_s * dt)
        self.position += step
        self.velocity = step / dt
        self.plant.step(command_for(self.plant.command_type, self.forces(), self.tendon_deg()), dt)
        self.sim_time += dt


@dataclass
class SimulatedBus:
    """:class:`~.bus.ServoBus` over a :class:`SimWorld`."""

    world: SimWorld
    ids: list[int] = field(default_factory=lambda: [1, 2, 3, 4])

    def open(self) -> list[str]:
        return []

    def configure(self, dry_run: bool) -> list[str]:
        return []

    def enable(self) -> None:
        self.world.sync()
        self.world.torque = True

    def read(self) -> ServoReadings:
        self.world.sync()
        rpm = self.world.velocity / X.TICKS_PER_REV * 60.0
        return ServoReadings(
            position=np.rint(self.world.position).astype(np.int64),
            velocity=np.rint(rpm / X.RPM_PER_VELOCITY_UNIT).astype(np.int64),
            load=np.zeros(4, dtype=np.int64),
        )

    def write_goals(self, ticks: np.ndarray) -> int:
        self.world.sync()
        self.world.goal = np.clip(np.asarray(ticks, dtype=np.int64), 0, X.MAX_TICK)
        return 0

    def hardware_errors(self) -> np.ndarray:
        return np.zeros(4, dtype=np.int64)

    def disable(self) -> list[str]:
        self.world.sync()
        self.world.torque = False
        return []

    def close(self) -> None:
        pass
