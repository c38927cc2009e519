"""Metric definitions shared by every experiment (see docs/results/index.md, "Definitions").

stage cost  J(t) = 1000 * e^T Q e, e = x(t) - x_ref(t), Q the MPC's Q (so the
            factor 1000 undoes the paper's 1/1000 and J uses the paper's listed
            weights); angle errors are wrapped to [-pi, pi).
cycle cost  the same of the error averaged over the last gait cycle (walking soft legs).
settle time the earliest t_s with J(t) <= fraction * max J for every t >= t_s,
            provided the run stays settled for at least ``hold`` seconds after t_s;
            NaN otherwise (never settled, or only dipped in at the very end).
"""

from __future__ import annotations

import numpy as np

COST_SCALE = 1000.0


def wrap_angle(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def state_error(x: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
    e = np.asarray(x, dtype=float) - np.asarray(x_ref, dtype=float)
    e[..., 0:3] = wrap_angle(e[..., 0:3])
    return e


def stage_cost(x: np.ndarray, x_ref: np.ndarray, q_diag: np.ndarray) -> np.ndarray:
    """J = 1000 e^T Q e for one state (12,) or a trajectory (n, 12)."""
    e = state_error(x, x_ref)
    return COST_SCALE * np.sum(np.asarray(q_diag) * e**2, axis=-1)


def cycle_mean_cost(x: np.ndarray, x_ref: np.ndarray, q_diag: np.ndarray, window: int) -> np.ndarray:
    """J of the error averaged over the last ``window`` steps (a gait cycle): 1000 ebar^T Q ebar.

    A walking soft robot's state swings within every gait cycle (the stick-slip that
    moves it); averaging the error over one cycle before weighing it measures how far
    the motion is from the reference, not the gait's own swing. ``window`` = 1 is the
    stage cost. The average is causal (the steps so far, at most ``window``).
    """
    return COST_SCALE * np.sum(np.asarray(q_diag) * _cycle_mean_error(x, x_ref, window) ** 2, axis=-1)


def cycle_mean_cost_parts(x: np.ndarray, x_ref: np.ndarray, q_diag: np.ndarray, window: int) -> np.ndarray:
    """Each state's term of :func:`cycle_mean_cost` (n, 12): which error keeps a run from settling."""
    return COST_SCALE * np.asarray(q_diag) * _cycle_mean_error(x, x_ref, window) ** 2


def _cycle_mean_error(x: np.ndarray, x_ref: np.ndarray, window: int) -> np.ndarray:
    """The state error averaged over the last ``window`` steps, causally (n, 12)."""
    e = state_error(x, x_ref)
    csum = np.cumsum(np.vstack([np.zeros((1, e.shape[1])), e]), axis=0)
    k = np.arange(1, e.shape[0] + 1)
    lo = np.maximum(0, k - int(window))
    return (csum[k] - csum[lo]) / (k - lo)[:, None]


def settle_time(t: np.ndarray, cost: np.ndarray, fraction: float, hold: float = 1.0) -> float:
    """First time after which the cost stays at or below ``fraction`` of its maximum.

    A run that only enters the band less than ``hold`` seconds before its end has
    not been shown to settle, so it gets NaN too.
    """
    t = np.asarray(t, dtype=float)
    cost = np.asarray(cost, dtype=float)
    if cost.size == 0:
        return float("nan")
    threshold = fraction * np.nanmax(cost)
    above = np.flatnonzero(cost > threshold)
    if above.size == 0:
        return float(t[0])
    if above[-1] == cost.size - 1:
        return float("nan")
    settled = float(t[above[-1] + 1])
    return settled if t[-1] - settled >= hold else float("nan")


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    return float(np.sqrt(np.nanmean(d**2)))


def lateral_drift(xy: np.ndarray, direction: np.ndarray, distance: float) -> tuple[float, float]:
    """Largest deviation across the direction of travel within the first ``distance`` m along it.

    Returns (drift, along-track distance actually covered, capped at ``distance``).
    """
    d = direction / np.linalg.norm(direction)
    n = np.array([-d[1], d[0]])
    rel = xy - xy[0]
    along = rel @ d
    covered = np.maximum.accumulate(along)
    mask = covered <= distance
    mask[0] = True
    return float(np.max(np.abs(rel[mask] @ n))), float(min(covered[-1], distance))


def tracking(
    t: np.ndarray,
    x: np.ndarray,
    x_ref: np.ndarray,
    velocity,
    drift_distance: float,
    measure_from_s: float = 2.0,
    yaw_rate: float = 0.0,
) -> dict[str, float]:
    """How a run tracked its reference (docs/results/index.md, "Definitions"), from its states ``x`` and
    reference ``x_ref`` (N, 12) at times ``t``. Speed, heading and the speed error are the mean over
    t >= ``measure_from_s`` (net displacement over time); the commanded direction is ``velocity``'s (the
    world frame, the robot starting at zero yaw), ``yaw_rate`` the commanded one (rad/s); the drift is
    :func:`lateral_drift` over ``drift_distance``."""
    xy, xy_ref = x[:, 3:5], x_ref[:, 3:5]
    direction = np.asarray(velocity, dtype=float)
    commanded = float(np.linalg.norm(direction))
    if commanded < 1e-12:
        direction = np.array([1.0, 0.0])
    drift, covered = lateral_drift(xy, direction, drift_distance)
    start = int(np.searchsorted(t, t[0] + measure_from_s))
    start = min(start, len(t) - 2)
    span = float(t[-1] - t[start])
    mean_v = (xy[-1] - xy[start]) / span
    d = direction / np.linalg.norm(direction)
    along = float(mean_v @ d)
    heading_error = float(np.degrees(np.arctan2(mean_v[1], mean_v[0]) - np.arctan2(d[1], d[0])))
    heading_error = (heading_error + 180.0) % 360.0 - 180.0
    yaw = np.unwrap(x[:, 2])
    mean_yaw_rate = float((yaw[-1] - yaw[start]) / span)  # turning in place is measured by this
    return {
        "speed_mps": float(np.linalg.norm(mean_v)),
        "speed_along_mps": along,
        "speed_error_fraction": (along - commanded) / commanded if commanded > 0 else float("nan"),
        "heading_error_deg": heading_error if commanded > 0 else float("nan"),
        "yaw_drift_deg": float(np.degrees(x[-1, 2] - x_ref[-1, 2])),
        "yaw_rate_radps": mean_yaw_rate,
        "yaw_rate_error_fraction": (mean_yaw_rate - yaw_rate) / yaw_rate if abs(yaw_rate) > 0 else float("nan"),
        "lateral_drift_per_m": drift / covered if covered > 0 else float("nan"),
        "measured_from_s": float(t[start]),
        "duration_s": float(t[-1] - t[0]),
        "com_rmse_x_m": rmse(x[:, 3], x_ref[:, 3]),
        "com_rmse_y_m": rmse(x[:, 4], x_ref[:, 4]),
        "com_rmse_z_m": rmse(x[:, 5], x_ref[:, 5]),
        "path_rmse_m": float(np.sqrt(np.mean(np.sum((xy - xy_ref) ** 2, axis=1)))),
        "mean_vx": float(np.mean(x[:, 9])),
        "mean_vy": float(np.mean(x[:, 10])),
        "distance_m": float(np.linalg.norm(xy[-1] - xy[0])),
        "lateral_drift_m": drift,
        "drift_measured_over_m": covered,
    }
