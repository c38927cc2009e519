"""Reference trajectory over the horizon: constant height, gait velocity, heading.

The desired heading starts at 0 and turns at ``gait.yaw_rate``; the body-frame gait
velocity is rotated by that desired heading (not the measured one), so a yaw
disturbance does not rotate the direction of travel. Positions in x and y have zero
weight in the paper's Q; they are filled in by integrating the reference velocity
from the measured position so the logged path is meaningful.
"""

from __future__ import annotations

import numpy as np

from .config import GaitConfig
from .metrics import wrap_angle


def desired_path(origin: np.ndarray, gait: GaitConfig, t: np.ndarray) -> np.ndarray:
    """Points (len(t), 2) of the path the gait asks for: the body-frame velocity turned by the
    desired heading (yaw_rate t), integrated in closed form from ``origin`` at t = 0."""
    t = np.asarray(t, dtype=float)
    v = np.asarray(gait.velocity, dtype=float)
    w = gait.yaw_rate
    if abs(w) < 1e-12:
        return origin + t[:, None] * v[None, :]
    s, c = np.sin(w * t), 1.0 - np.cos(w * t)  # integral of rot_z(w tau) v over [0, t], times w
    return origin + np.column_stack([v[0] * s - v[1] * c, v[0] * c + v[1] * s]) / w


def reference(
    x: np.ndarray,
    t: float,
    gait: GaitConfig,
    period: float,
    n: int,
    start: int = 1,
    path_origin: np.ndarray | None = None,
) -> np.ndarray:
    """States (n, 12) at times t + k * period for k = start .. start + n - 1.

    With ``path_origin`` the reference positions lie on the desired path from that
    origin (:func:`desired_path`), so a controller that weighs position returns to
    the path after a push; without it they start at the measured position.
    """
    k = np.arange(start, start + n, dtype=float)
    tk = t + k * period
    yaw_des = gait.yaw_rate * tk
    yaw_ref = x[2] + wrap_angle(yaw_des - x[2])  # unwrapped near the measured yaw
    out = np.zeros((n, 12))
    out[:, 2] = yaw_ref
    vx, vy = gait.velocity[0], gait.velocity[1]
    c, s = np.cos(yaw_des), np.sin(yaw_des)
    v_world = np.column_stack([c * vx - s * vy, s * vx + c * vy])  # rot_z(yaw_des) v_body
    out[:, 9:11] = v_world
    if path_origin is None:
        out[:, 3:5] = x[3:5] + (k * period)[:, None] * v_world
    else:
        out[:, 3:5] = desired_path(np.asarray(path_origin, dtype=float), gait, tk)
    out[:, 5] = gait.height
    out[:, 8] = gait.yaw_rate
    return out
