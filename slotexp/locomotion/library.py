"""The gait library of a style, and how a commanded body velocity and yaw rate become a gait.

A command (v_x, v_y) in the body frame and a yaw rate becomes a weighted mix of
primitives at the style's clock (:func:`.primitives.mix`):

- the direction of travel picks the two translating primitives whose measured
  headings bracket it, blended in proportion to the angle between them: their
  schedules mixed (``blend="schedules"``, the default), or one primitive with their
  parameters interpolated (``blend="parameters"``, :func:`.primitives.interpolate`);
- the speed, as a fraction s of what that blend measured, sets its weight: the rest
  goes to standing still (every tendon at the standing angle), so a slower gait
  is the same gait with smaller tendon strokes;
- the yaw rate, as a fraction r of the turning primitive's, sets the turning
  primitive's weight; when s + |r| would exceed 1 both are scaled down.

The mix is not exactly linear in what it does on the plant; the controller's
feedback closes that gap (:mod:`slotexp.controllers.gait_mpc`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import GaitStyleConfig
from ..errors import ConfigError
from .primitives import GaitStyle, Primitive, interpolate


@dataclass
class GaitCommand:
    parts: list[tuple[float, Primitive]]
    speed_fraction: float
    yaw_fraction: float
    max_speed: float  # m/s the blend of this direction measured


class GaitLibrary:
    """One style's primitives: translation in measured directions, turning left and right, standing."""

    def __init__(
        self,
        style: GaitStyle,
        primitives: list[Primitive],
        standing_deg: float,
        top_deg: float,
        blend: str = "schedules",
    ) -> None:
        if blend not in ("schedules", "parameters"):
            raise ValueError(f"blend must be 'schedules' or 'parameters', not {blend!r}")
        self.style = style
        self.blend = blend
        self.top = top_deg
        self.still = Primitive.still("still", standing_deg)
        moving = [p for p in primitives if p.heading_deg is not None and p.speed_mps > 0]
        self.translation = sorted(moving, key=lambda p: p.heading_deg)
        self.turn_left = max(
            (p for p in primitives if p.heading_deg is None), key=lambda p: p.yaw_rate_dps, default=None
        )
        self.turn_right = min(
            (p for p in primitives if p.heading_deg is None), key=lambda p: p.yaw_rate_dps, default=None
        )
        if len(self.translation) < 2:
            raise ConfigError(
                "the gait library needs translating primitives in at least two directions: "
                "run slot run experiment=gait_search (see the README)"
            )

    @classmethod
    def from_config(
        cls, cfg: GaitStyleConfig, standing_deg: float, top_deg: float, blend: str = "schedules"
    ) -> GaitLibrary:
        prims = [Primitive.from_config(p) for p in cfg.primitives]
        return cls(GaitStyle(cfg.frequency_hz, cfg.duty, cfg.sharpness), prims, standing_deg, top_deg, blend)

    def _bracket(self, heading_deg: float) -> tuple[Primitive, Primitive, float]:
        """The two primitives whose headings bracket ``heading_deg`` (cyclically) and the blend fraction."""
        h = np.asarray([p.heading_deg for p in self.translation], float)
        x = (heading_deg - h[0]) % 360.0
        rel = (h - h[0]) % 360.0
        j = int(np.searchsorted(rel, x, side="right") - 1)
        k = (j + 1) % len(h)
        span = (rel[k] - rel[j]) % 360.0 if k != j else 360.0
        span = span or 360.0
        return self.translation[j], self.translation[k], float((x - rel[j]) / span)

    def max_speed(self, heading_deg: float) -> float:
        """Speed (m/s) the blend for this body-frame direction measured: the envelope."""
        a, b, lam = self._bracket(heading_deg)
        return (1.0 - lam) * a.speed_mps + lam * b.speed_mps

    @property
    def max_yaw_rate_dps(self) -> float:
        rates = [abs(p.yaw_rate_dps) for p in (self.turn_left, self.turn_right) if p is not None]
        return min(rates) if rates else 0.0

    def command(self, velocity_body: np.ndarray, yaw_rate_dps: float) -> GaitCommand:
        """The mix for a body-frame velocity (m/s) and a yaw rate (deg/s)."""
        v = np.asarray(velocity_body, float)
        speed = float(np.hypot(v[0], v[1]))
        heading = float(np.degrees(np.arctan2(v[1], v[0])))
        a, b, lam = self._bracket(heading)
        top = (1.0 - lam) * a.speed_mps + lam * b.speed_mps
        s = min(1.0, speed / top) if top > 0 else 0.0
        r = 0.0
        turn = None
        if yaw_rate_dps > 0 and self.turn_left is not None:
            turn, r = self.turn_left, min(1.0, yaw_rate_dps / self.turn_left.yaw_rate_dps)
        elif yaw_rate_dps < 0 and self.turn_right is not None:
            turn, r = self.turn_right, min(1.0, yaw_rate_dps / self.turn_right.yaw_rate_dps)
        if s + r > 1.0:
            s, r = s / (s + r), r / (s + r)
        if self.blend == "parameters":
            parts = [(s, interpolate(a, b, lam)), (1.0 - s - r, self.still)]
        else:
            parts = [(s * (1.0 - lam), a), (s * lam, b), (1.0 - s - r, self.still)]
        if turn is not None:
            parts.append((r, turn))
        return GaitCommand(parts, s, r if yaw_rate_dps >= 0 else -r, top)
