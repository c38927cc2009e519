"""Reference trajectory over the horizon: constant height, gait velocity, heading.

The desired heading starts at 0 and turns at ``gait.yaw_rate``; the body-frame gait
velocity is rotated by that desired heading (not the measured one), so a yaw
disturbance does not rotate the direction of travel. Positions in x and y have zero
weight in the paper's Q; they are filled in by integrating the reference velocity
from the measured position so the logged path is meaningful.
"""

from __future__ import annotations

import numpy as np

from .body import rot_z
from .config import GaitConfig
from .metrics import wrap_angle


def reference(x: np.ndarray, t: float, gait: GaitConfig, period: float, n: int, start: int = 1) -> np.ndarray:
    """States (n, 12) at times t + k * period for k = start .. start + n - 1."""
    k = np.arange(start, start + n, dtype=float)
    tk = t + k * period
    yaw_des = gait.yaw_rate * tk
    yaw_ref = x[2] + wrap_angle(yaw_des - x[2])  # unwrapped near the measured yaw
    out = np.zeros((n, 12))
    out[:, 2] = yaw_ref
    v_body = np.array([gait.velocity[0], gait.velocity[1], 0.0])
    v_world = np.stack([rot_z(y) @ v_body for y in yaw_des])
    out[:, 9:12] = v_world
    out[:, 3:5] = x[3:5] + (k * period)[:, None] * v_world[:, 0:2]
    out[:, 5] = gait.height
    out[:, 8] = gait.yaw_rate
    return out
