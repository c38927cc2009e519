"""Plants the controller drives: the interface, and the ideal-force plant.

A plant advances one MPC period under a held set of ground-reaction forces and
reports the MPC state and where its feet are. The soft Cosserat-leg plant plugs
in behind the same :class:`Plant` protocol.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from .body import euler_rate_matrix, euler_to_quat, integrate_rk4, quat_to_euler, quat_to_rot
from .robot import RobotModel

STATE_NAMES = ("roll", "pitch", "yaw", "x", "y", "z", "wx", "wy", "wz", "vx", "vy", "vz")


class Plant(Protocol):
    time: float

    def state(self) -> np.ndarray:
        """MPC state [roll, pitch, yaw, p, omega_world, v] (12,)."""

    def feet(self) -> np.ndarray:
        """World positions (4, 3) of the points the ground forces act on."""

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Torso position (3,) and attitude quaternion (w, x, y, z)."""

    def markers(self) -> dict[str, np.ndarray]:
        """Named world points to log and validate against (at least ``com``)."""

    def step(self, forces: np.ndarray, period: float, external_force: np.ndarray | None = None,
             tendon_deg: np.ndarray | None = None) -> None:
        """Advance ``period`` seconds under the controller's output, held constant.

        The ideal plant applies ``forces`` (4, 3); the soft-leg plant drives its servos
        to ``tendon_deg`` (4,) and its legs make their own ground forces.
        """

    def telemetry(self) -> dict[str, dict]:
        """Plant-specific per-step log messages (topic -> message); may be empty."""

    def apply_impulse(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """Instantaneous world-frame push (N s) and angular impulse about the CoM (N m s)."""


class IdealPlant:
    """Rigid torso pushed by ideal force actuators at the nominal (body-fixed) feet."""

    def __init__(self, robot: RobotModel, x0: np.ndarray, gravity: float, dt: float) -> None:
        self.robot = robot
        self.gravity = gravity
        self.dt = dt
        self.time = 0.0
        self._inertia = np.ascontiguousarray(robot.inertia_body)
        self._inertia_inv = np.linalg.inv(self._inertia)
        self._points = np.ascontiguousarray(robot.feet_body)
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

    def telemetry(self) -> dict[str, dict]:
        return {}

    def step(self, forces: np.ndarray, period: float, external_force: np.ndarray | None = None,
             tendon_deg: np.ndarray | None = None) -> None:
        n = max(1, int(round(period / self.dt)))
        f_ext = np.zeros(3) if external_force is None else np.asarray(external_force, dtype=float)
        self._s = integrate_rk4(self._s, np.ascontiguousarray(forces, dtype=float), self._points, f_ext,
                                self.robot.mass, self._inertia, self._inertia_inv, self.gravity,
                                period / n, n)
        self.time += period

    def apply_impulse(self, linear: np.ndarray, angular: np.ndarray) -> None:
        rot = quat_to_rot(self._s[3:7])
        self._s[7:10] += np.asarray(linear, dtype=float) / self.robot.mass
        self._s[10:13] += self._inertia_inv @ (rot.T @ np.asarray(angular, dtype=float))


def nominal_state(robot: RobotModel) -> np.ndarray:
    """At rest at the stance height, level, heading +x."""
    x = np.zeros(12)
    x[5] = robot.stance_height
    return x


__all__ = ["Plant", "IdealPlant", "nominal_state", "STATE_NAMES", "euler_rate_matrix"]
