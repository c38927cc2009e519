"""The ideal plant (``plant=ideal``): the rigid torso pushed by ideal force actuators.

It isolates the controller: the commanded forces act at the nominal (body-fixed)
feet, each held for one MPC period, and the torso is integrated with RK4.
"""

from __future__ import annotations

import numpy as np

from ..body import euler_to_quat, integrate_rk4, quat_to_euler, quat_to_rot
from ..config import SlotConfig
from ..robot import RobotModel
from ..scene import straight_legs
from . import PLANTS, ForceCommand


@PLANTS.register()
class IdealPlant:
    """Rigid torso pushed by ideal force actuators at the nominal (body-fixed) feet."""

    command_type = ForceCommand

    @classmethod
    def from_config(cls, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> IdealPlant:
        return cls(robot, x0, cfg.sim.gravity, cfg.sim.dt)

    def __init__(self, robot: RobotModel, x0: np.ndarray, gravity: float, dt: float) -> None:
        self.robot = robot
        self.gravity = gravity
        self.dt = dt
        self.time = 0.0
        self._inertia = np.ascontiguousarray(robot.inertia_body)
        self._inertia_inv = np.linalg.inv(self._inertia)
        self._points = np.ascontiguousarray(robot.feet_body)
        self._segments = np.stack((robot.corners_body, robot.feet_body), axis=1)  # each leg: corner, foot
        q = euler_to_quat(*x0[0:3])
        rot = quat_to_rot(q)
        self._s = np.concatenate([x0[3:6], q, x0[9:12], rot.T @ x0[6:9]])

    def state(self) -> np.ndarray:
        q = self._s[3:7]
        rot = quat_to_rot(q)
        return np.concatenate([quat_to_euler(q), self._s[0:3], rot @ self._s[10:13], self._s[7:10]])

    def feet(self) -> np.ndarray:
        rot = quat_to_rot(self._s[3:7])
        return self._s[0:3] + self._points @ rot.T

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        return self._s[0:3].copy(), self._s[3:7].copy()

    def markers(self) -> dict[str, np.ndarray]:
        feet = self.feet()
        out = {"com": self._s[0:3].copy()}
        out.update({f"{name}_foot": feet[i] for i, name in enumerate(self.robot.names)})
        return out

    def legs(self) -> np.ndarray:
        """Straight segments from each torso corner to its force point: the ideal plant has no legs."""
        return straight_legs(self._segments, self._s[0:3], self._s[3:7])

    def telemetry(self) -> dict[str, dict]:
        return {}

    def step(self, command: ForceCommand, period: float, external_force: np.ndarray | None = None) -> None:
        n = max(1, int(round(period / self.dt)))
        f_ext = np.zeros(3) if external_force is None else np.asarray(external_force, dtype=float)
        self._s = integrate_rk4(
            self._s,
            np.ascontiguousarray(command.forces, dtype=float),
            self._points,
            f_ext,
            self.robot.mass,
            self._inertia,
            self._inertia_inv,
            self.gravity,
            period / n,
            n,
        )
        self.time += period

    def apply_impulse(self, linear: np.ndarray, angular: np.ndarray) -> None:
        rot = quat_to_rot(self._s[3:7])
        self._s[7:10] += np.asarray(linear, dtype=float) / self.robot.mass
        self._s[10:13] += self._inertia_inv @ (rot.T @ np.asarray(angular, dtype=float))
