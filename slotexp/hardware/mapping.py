"""Tendon angle <-> servo position, and the limits every command is clamped to.

``position_deg = zero_offset_deg + direction * theta`` (servo-horn degrees, the robot's
horn map, :class:`slotexp.soft.servo.HornMap`), sent as ``round(position_deg * 4096 / 360)``
XL430 ticks, clamped to the servos' position limits, so no command can ever leave them.
A negative theta is a horn below the zero: more slack, as the robot's own gaits command.
The controllers keep their own commands within their maps (eq. 11 within
[0, robot.leg.tendon_max_deg]).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import HardwareConfig
from .xl430 import DEG_PER_TICK


@dataclass(frozen=True)
class ServoMap:
    """Per-servo mapping constants, in leg order."""

    zero_deg: np.ndarray  # (4,)
    direction: np.ndarray  # (4,) +-1
    min_ticks: np.ndarray  # (4,) int
    max_ticks: np.ndarray  # (4,) int
    tendon_max_deg: float

    @classmethod
    def from_config(cls, hw: HardwareConfig, tendon_max_deg: float) -> ServoMap:
        lo = [round(d / DEG_PER_TICK) for d in hw.min_position_deg]  # the nearest tick: within 0.044 deg
        hi = [round(d / DEG_PER_TICK) for d in hw.max_position_deg]
        return cls(
            np.asarray(hw.zero_offset_deg, float),
            np.asarray(hw.direction, float),
            np.asarray(lo, np.int64),
            np.asarray(hi, np.int64),
            float(tendon_max_deg),
        )

    def to_ticks(self, tendon_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Goal positions (ticks, int64) for tendon angles, and which of them had to be clamped."""
        theta = np.asarray(tendon_deg, dtype=float)
        bad = ~np.isfinite(theta)
        theta = np.where(bad, 0.0, theta)
        raw = np.rint((self.zero_deg + self.direction * theta) / DEG_PER_TICK).astype(np.int64)
        ticks = np.clip(raw, self.min_ticks, self.max_ticks)
        clamped = bad | (ticks != raw)
        return ticks, clamped

    def to_tendon_deg(self, ticks: np.ndarray) -> np.ndarray:
        """Tendon angle a servo position corresponds to (inverse of :meth:`to_ticks` inside the limits)."""
        return (np.asarray(ticks, dtype=float) * DEG_PER_TICK - self.zero_deg) * self.direction

    def tendon_range_deg(self) -> tuple[np.ndarray, np.ndarray]:
        """Per servo, the tendon angles [lo, hi] a command can actually reach (the position limits)."""
        a = self.to_tendon_deg(self.min_ticks)
        b = self.to_tendon_deg(self.max_ticks)
        return np.minimum(a, b), np.maximum(a, b)
