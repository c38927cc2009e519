"""Seed 001's footstep planner (eqs. 19-28) and seed 002's parabolic swing foot.

The planner works in the local frame l: at the CoM's ground projection, heading
the robot's yaw. The foothold of leg i is the sum of

- the shoulder (eq. 19): the hip's ground projection;
- symmetry (eq. 20): ``t_stance / 2 * v``, so the stance foot spends half its
  stance ahead of the shoulder and half behind;
- feedback (eq. 21): ``k (v - v*)``, k = 0.03, so a robot that is too slow steps
  shorter and pushes back harder;
- centrifugal (eq. 22): ``1/2 sqrt(h / g) v x omega*``;
- prediction (eqs. 23-28): where the base will be when the foot lands, moving at
  the current velocity and yaw rate for the leg's remaining swing time ``t_r``.

Symmetry, feedback and centrifugal are the same for every foot; shoulder and
prediction differ. Each term is its own function so it can be checked by hand.
"""

from __future__ import annotations

import numpy as np

FEEDBACK_GAIN = 0.03  # seed 001's k


def symmetry(t_stance: float, v: np.ndarray) -> np.ndarray:
    """Eq. 20: t_stance / 2 * v (local frame, x y)."""
    return 0.5 * t_stance * np.asarray(v[:2], dtype=float)


def feedback(v: np.ndarray, v_ref: np.ndarray, k: float = FEEDBACK_GAIN) -> np.ndarray:
    """Eq. 21: k (v - v*)."""
    return k * (np.asarray(v[:2], dtype=float) - np.asarray(v_ref[:2], dtype=float))


def centrifugal(v: np.ndarray, yaw_rate_ref: float, height: float, gravity: float) -> np.ndarray:
    """Eq. 22: 1/2 sqrt(h / g) v x omega* = 1/2 sqrt(h / g) [v_y psi_dot*, -v_x psi_dot*]."""
    return 0.5 * np.sqrt(height / gravity) * np.array([v[1] * yaw_rate_ref, -v[0] * yaw_rate_ref])


def prediction(v: np.ndarray, yaw_rate: float, t_r: float, eps: float = 1e-9) -> np.ndarray:
    """Eqs. 25-28: the base's displacement over ``t_r`` at constant local velocity and yaw rate."""
    vx, vy = float(v[0]), float(v[1])
    if abs(yaw_rate) < eps:
        return np.array([vx * t_r, vy * t_r])  # eqs. 27-28
    s, c = np.sin(yaw_rate * t_r), np.cos(yaw_rate * t_r)
    return np.array([vx * s + vy * (c - 1.0), -vx * (c - 1.0) + vy * s]) / yaw_rate  # eqs. 25-26


def footholds(
    shoulders: np.ndarray,
    t_stance: np.ndarray,
    t_remaining: np.ndarray,
    v: np.ndarray,
    v_ref: np.ndarray,
    yaw_rate: float,
    yaw_rate_ref: float,
    height: float,
    gravity: float,
    k: float = FEEDBACK_GAIN,
) -> np.ndarray:
    """Footholds (4, 2) in the local frame: the sum of eqs. 19-28 for each leg.

    ``shoulders`` (4, 2) local; ``t_stance`` (4,) each leg's stance duration;
    ``t_remaining`` (4,) the time until each leg lands (0 for a leg in stance);
    ``v``, ``v_ref`` local velocities; ``yaw_rate`` measured, ``yaw_rate_ref`` desired.
    """
    common = feedback(v, v_ref, k) + centrifugal(v, yaw_rate_ref, height, gravity)
    out = np.empty((4, 2))
    for i in range(4):
        out[i] = (
            np.asarray(shoulders[i], dtype=float)
            + symmetry(float(t_stance[i]), v)
            + common
            + prediction(v, yaw_rate, float(t_remaining[i]))
        )
    return out


def swing_point(
    p0: np.ndarray, p1: np.ndarray, height: float, t: float, duration: float, timing: str = "linear"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seed 002's swing foot: position, velocity and acceleration at time ``t`` of a swing from ``p0`` to ``p1``.

    The path is seed 002's parabola: horizontally the straight line from ``p0`` to
    ``p1``, vertically that line plus ``-4 h s (s - 1)``, zero at both ends and ``h``
    at s = 1/2 (seed 002's ``Height * t * (t - T)`` with its scale chosen to give
    apex ``h``). ``timing`` sets how s runs from 0 to 1 over ``duration``:

    - ``linear``: s = t / T (seed 002). The foot leaves and lands at full speed,
      vertically 4 h / T, a step change of velocity the leg cannot follow;
    - ``smooth``: the minimum-jerk law s = 10 u^3 - 15 u^4 + 6 u^5, u = t / T: the
      same path, left and reached at rest with zero acceleration, so a leg can
      track it and lands without an impact.
    """
    p0, p1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    u = float(np.clip(t / duration, 0.0, 1.0)) if duration > 0 else 1.0
    moving = 0.0 < t < duration
    if timing == "smooth":
        s = u**3 * (10.0 + u * (-15.0 + 6.0 * u))
        ds = 30.0 * u**2 * (1.0 - u) ** 2 / duration if moving else 0.0
        dds = 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u) / duration**2 if moving else 0.0
    else:
        s, ds, dds = u, (1.0 / duration if moving else 0.0), 0.0
    pos = p0 + (p1 - p0) * s
    pos[2] += -4.0 * height * s * (s - 1.0)
    # d/ds of the path, and d2/ds2 (only the parabola curves)
    tangent = p1 - p0
    tangent[2] += -4.0 * height * (2.0 * s - 1.0)
    curvature = np.array([0.0, 0.0, -8.0 * height])
    return pos, tangent * ds, tangent * dds + curvature * ds**2
