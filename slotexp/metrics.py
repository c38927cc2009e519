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
    e = state_error(x, x_ref)
    csum = np.cumsum(np.vstack([np.zeros((1, e.shape[1])), e]), axis=0)
    k = np.arange(1, e.shape[0] + 1)
    lo = np.maximum(0, k - int(window))
    mean = (csum[k] - csum[lo]) / (k - lo)[:, None]
    return COST_SCALE * np.sum(np.asarray(q_diag) * mean**2, axis=-1)


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
