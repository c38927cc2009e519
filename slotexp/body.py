"""Rigid torso: quaternion kinematics and 6-DOF Newton-Euler dynamics (numba).

Conventions: world frame z up; quaternion (w, x, y, z) rotates body to world;
Euler angles are Z-Y-X (yaw, pitch, roll) so R = Rz(yaw) Ry(pitch) Rx(roll);
angular velocity is integrated in the body frame (Euler's equations keep their
gyroscopic term here, unlike the MPC's prediction model, paper eq. 7).
"""

from __future__ import annotations

import numpy as np

from .jit import njit


def horizontal(xy) -> np.ndarray:
    """A horizontal offset (x, y) as a 3-vector (z = 0), e.g. ``robot.torso.com_offset``: the torso's mass
    centre from its box's centre, body frame."""
    return np.array([*xy, 0.0][:3], dtype=float)


@njit(cache=True)
def quat_to_rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q[0], q[1], q[2], q[3]
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@njit(cache=True)
def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array(
        [
            a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
        ]
    )


@njit(cache=True, allocates=False)
def advance_quaternion(torso, w0, w1, w2, h):
    """q <- q exp(h w / 2), renormalised: the torso's attitude (``torso[3:7]``) turned by the body-frame
    angular velocity (w0, w1, w2) held over a step of ``h``."""
    a0, a1, a2 = 0.5 * h * w0, 0.5 * h * w1, 0.5 * h * w2
    angle = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    d0 = np.cos(angle)
    sa = np.sin(angle) / angle if angle > 0.0 else 0.0
    d1, d2, d3 = a0 * sa, a1 * sa, a2 * sa
    q0, q1, q2, q3 = torso[3], torso[4], torso[5], torso[6]
    n0 = q0 * d0 - q1 * d1 - q2 * d2 - q3 * d3
    n1 = q0 * d1 + q1 * d0 + q2 * d3 - q3 * d2
    n2 = q0 * d2 - q1 * d3 + q2 * d0 + q3 * d1
    n3 = q0 * d3 + q1 * d2 - q2 * d1 + q3 * d0
    norm = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
    torso[3], torso[4], torso[5], torso[6] = n0 / norm, n1 / norm, n2 / norm, n3 / norm


@njit(cache=True, allocates=False)
def solve_spd(a, b, x):
    """x = a^-1 b for a small symmetric positive definite ``a`` (Cholesky; ``a`` is overwritten by its factor)."""
    n = b.shape[0]
    for j in range(n):
        d = a[j, j]
        for k in range(j):
            d -= a[j, k] * a[j, k]
        d = np.sqrt(d)
        a[j, j] = d
        for i in range(j + 1, n):
            t = a[i, j]
            for k in range(j):
                t -= a[i, k] * a[j, k]
            a[i, j] = t / d
    for i in range(n):
        t = b[i]
        for k in range(i):
            t -= a[i, k] * x[k]
        x[i] = t / a[i, i]
    for i in range(n - 1, -1, -1):
        t = x[i]
        for k in range(i + 1, n):
            t -= a[k, i] * x[k]
        x[i] = t / a[i, i]


def euler_to_quat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def quat_to_euler(q: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of a unit quaternion, Z-Y-X convention."""
    w, x, y, z = q
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.array([roll, pitch, yaw])


def rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def euler_rate_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """E with omega_world = E @ d(roll, pitch, yaw)/dt for Z-Y-X Euler angles."""
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])


@njit(cache=True)
def _derivative(
    state: np.ndarray,
    forces: np.ndarray,
    points_b: np.ndarray,
    f_ext: np.ndarray,
    mass: float,
    inertia: np.ndarray,
    inertia_inv: np.ndarray,
    gravity: float,
) -> np.ndarray:
    # state: p(3) q(4) v(3) w_body(3)
    q = state[3:7]
    w = state[10:13]
    rot = quat_to_rot(q)
    total = f_ext.copy()
    total[2] -= mass * gravity
    torque_w = np.zeros(3)
    for i in range(forces.shape[0]):
        r = rot @ points_b[i]
        f = forces[i]
        total += f
        torque_w += np.array([r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]])
    torque_b = rot.T @ torque_w
    iw = inertia @ w
    gyro = np.array([w[1] * iw[2] - w[2] * iw[1], w[2] * iw[0] - w[0] * iw[2], w[0] * iw[1] - w[1] * iw[0]])
    out = np.empty(13)
    out[0:3] = state[7:10]
    qd = 0.5 * quat_mul(q, np.array([0.0, w[0], w[1], w[2]]))
    out[3:7] = qd
    out[7:10] = total / mass
    out[10:13] = inertia_inv @ (torque_b - gyro)
    return out


@njit(cache=True)
def integrate_rk4(
    state: np.ndarray,
    forces: np.ndarray,
    points_b: np.ndarray,
    f_ext: np.ndarray,
    mass: float,
    inertia: np.ndarray,
    inertia_inv: np.ndarray,
    gravity: float,
    h: float,
    n_steps: int,
) -> np.ndarray:
    """Advance the torso ``n_steps`` RK4 steps of ``h`` with world forces held constant.

    ``forces[i]`` acts at the body-fixed point ``points_b[i]`` (relative to the CoM).
    The quaternion is renormalised after every step.
    """
    s = state.copy()
    for _ in range(n_steps):
        k1 = _derivative(s, forces, points_b, f_ext, mass, inertia, inertia_inv, gravity)
        k2 = _derivative(s + 0.5 * h * k1, forces, points_b, f_ext, mass, inertia, inertia_inv, gravity)
        k3 = _derivative(s + 0.5 * h * k2, forces, points_b, f_ext, mass, inertia, inertia_inv, gravity)
        k4 = _derivative(s + h * k3, forces, points_b, f_ext, mass, inertia, inertia_inv, gravity)
        s = s + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        s[3:7] = s[3:7] / np.sqrt(np.sum(s[3:7] ** 2))
    return s
