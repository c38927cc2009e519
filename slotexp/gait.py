"""Gait matrix (seed 001): rows ``[steps left, c_1 .. c_4]``, rolled one MPC step at a time.

Rolling consumes one step of the first phase and appends it to the end, merging
with the last phase when the contact pattern matches, so the matrix always covers
exactly one gait period ahead of "now". This reproduces seed 001, eq. (18).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import GaitConfig


class GaitMatrix:
    def __init__(self, phases: list[list[int]] | np.ndarray, n_rows: int | None = None) -> None:
        rows = np.asarray(phases, dtype=int)
        if rows.ndim != 2 or rows.shape[1] != 5:
            raise ValueError("gait rows must be [steps, c1, c2, c3, c4]")
        rows = rows[rows[:, 0] > 0]
        n_rows = max(n_rows or 0, rows.shape[0] + 2)
        self.matrix = np.zeros((n_rows, 5), dtype=int)
        self.matrix[: rows.shape[0]] = rows

    @property
    def period(self) -> int:
        return int(self.matrix[:, 0].sum())

    def _last_row(self) -> int:
        nonzero = np.flatnonzero(self.matrix[:, 0] > 0)
        return int(nonzero[-1])

    def roll(self) -> None:
        """Advance one MPC step."""
        pattern = self.matrix[0, 1:].copy()
        self.matrix[0, 0] -= 1
        last = self._last_row() if self.matrix[:, 0].any() else 0
        if self.matrix[last, 0] > 0 and np.array_equal(self.matrix[last, 1:], pattern):
            self.matrix[last, 0] += 1
        else:
            if last + 1 >= self.matrix.shape[0]:
                self.matrix = np.vstack([self.matrix, np.zeros((1, 5), dtype=int)])
            self.matrix[last + 1] = np.concatenate([[1], pattern])
        if self.matrix[0, 0] == 0:
            self.matrix = np.vstack([self.matrix[1:], np.zeros((1, 5), dtype=int)])

    def contacts(self, horizon: int) -> np.ndarray:
        """Contact flags (horizon, 4) for the next ``horizon`` steps, repeating the period."""
        rows = self.matrix[self.matrix[:, 0] > 0]
        steps = np.repeat(rows[:, 1:], rows[:, 0], axis=0)
        reps = -(-horizon // steps.shape[0])
        return np.tile(steps, (reps, 1))[:horizon].astype(bool)


@dataclass(frozen=True)
class ContactPlan:
    """What the MPC needs per leg and step: contact, friction and normal-force bounds."""

    stance: np.ndarray  # (H, 4) bool
    mu: np.ndarray  # (H, 4)
    fz_min: np.ndarray  # (H, 4)
    fz_max: np.ndarray  # (H, 4)


def contact_plan(stance: np.ndarray, gait: GaitConfig, f_min_stance: float, f_max: float) -> ContactPlan:
    """Turn stance flags into friction and force bounds.

    SLOT's swing legs stay on the ground and slide (``mu_swing``) unless
    ``gait.swing_contact`` is false, when they must exert no force at all.
    """
    mu = np.where(stance, gait.mu_stance, gait.mu_swing)
    fz_min = np.where(stance, f_min_stance, 0.0)
    if gait.swing_contact:
        fz_max = np.full(stance.shape, f_max)
    else:
        fz_max = np.where(stance, f_max, 0.0)
        mu = np.where(stance, mu, 0.0)
    return ContactPlan(stance=stance, mu=mu, fz_min=fz_min, fz_max=fz_max)


def tendon_profile(phases: list[list[int]], step: int, ramp: float, hold: float, decay: float) -> np.ndarray:
    """Per-leg tendon schedule in [0, 1] at MPC step ``step``: ramp / hold / decay over the
    phase for legs that swing (contract) in it, 0 for stance legs.

    ``ramp``, ``hold`` and ``decay`` are fractions of the phase's duration (the authors'
    crawl uses 0.2 / 0.6 / 0.2 of a 1 s phase).
    """
    rows = [r for r in phases if r[0] > 0]
    period = sum(int(r[0]) for r in rows)
    k = step % period
    for row in rows:
        if k < row[0]:
            break
        k -= row[0]
    f = (k + 0.5) / row[0]
    if f < ramp:
        level = f / ramp
    elif f < ramp + hold:
        level = 1.0
    elif f < ramp + hold + decay:
        level = 1.0 - (f - ramp - hold) / decay
    else:
        level = 0.0
    swing = np.asarray(row[1:]) == 0
    return np.where(swing, level, 0.0)
