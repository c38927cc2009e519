"""The gait library of a style, and how a commanded body velocity and yaw rate become a gait.

A command (v_x, v_y) in the body frame and a yaw rate becomes a weighted mix of
primitives at the style's clock (:func:`.primitives.mix`):

- the direction of travel picks the two translating primitives whose measured
  headings bracket it. They combine in one of three ways (``blend``):

  - ``"cycles"`` (the default): whole gait cycles of one or the other, chosen at
    each cycle's start so that the running sum of the chosen primitives' velocities
    across the commanded direction stays near zero (error diffusion, as in a
    sigma-delta modulator). Every cycle is a gait the search found and measured;
    the average velocity points where commanded. The two gaits may phase their legs
    differently: a mix of them, sample by sample, is not a gait between them. Each
    choice holds for ``hold`` cycles: a switch costs a transient while the legs'
    loads rebuild, and more cycles per choice zigzag wider across the path;
  - ``"schedules"``: their schedules mixed sample by sample, in proportion to the
    angle between them (right for neighbours with the same leg sequence);
  - ``"parameters"``: one primitive with their parameters interpolated
    (:func:`.primitives.interpolate`);
- the speed, as a fraction s of what that blend measured, sets its weight: the rest
  goes to standing still (every tendon at the standing angle), so a slower gait
  is the same gait with smaller tendon strokes;
- the yaw rate, as a fraction r of the turning primitive's, sets the turning
  primitive's weight; when s + |r| would exceed 1 both are scaled down.

Every primitive is timed to its neighbours when the library is built
(:meth:`GaitLibrary._aligned`): shifting a gait's whole clock changes nothing it
does alone, but both blends pass from one primitive to the next, and only legs
that move together make a gait between them. A robot starting from rest starts
the clock where the search started the primitive nearest its command
(:meth:`GaitLibrary.start_phase`), so the library's measurements hold from the start.

The mix is not exactly linear in what it does on the plant; the controller's
feedback closes that gap (:mod:`slotexp.controllers.gait_mpc`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import GaitStyleConfig
from ..errors import ConfigError
from .primitives import GaitStyle, Primitive, interpolate

BLENDS = ("cycles", "schedules", "parameters")
# blend="cycles": within this fraction of the gap between two primitives (about 11 deg of 45), mix their
# schedules instead, so that a small steering correction near a primitive does not interrupt it with whole
# cycles of a neighbour. Measured on Table I (soft plant, 15 mm/s): at 0.1 a lateral command of 3-4 mm/s on the
# forward walk inserted a -44-deg cycle every few cycles, each dropping the body 10-15 mm and pitching it 10 deg,
# and Pitch never settled; at 0.25 all six settle. (0.25 once spoiled 135 and 225 deg, with a library whose
# diagonal gait walked at 132 deg: those headings are now within 1 deg of a primitive.)
NEAR = 0.25
MIN_SEPARATION_DEG = 10.0  # of two translating primitives closer than this in heading, the faster is kept


@dataclass
class GaitCommand:
    parts: list[tuple[float, Primitive]]
    speed_fraction: float
    yaw_fraction: float
    max_speed: float  # m/s the blend of this direction measured
    by_cycles: bool = False  # whether whole cycles of two primitives alternate (blend="cycles" between them)


class GaitLibrary:
    """One style's primitives: translation in measured directions, turning left and right, standing."""

    def __init__(
        self,
        style: GaitStyle,
        primitives: list[Primitive],
        standing_deg: float,
        top_deg: float,
        blend: str = "cycles",
        hold: int = 1,
    ) -> None:
        if blend not in BLENDS:
            raise ValueError(f"blend must be one of {', '.join(BLENDS)}, not {blend!r}")
        if hold < 1:
            raise ValueError(f"hold must be at least one cycle, not {hold}")
        self.style = style
        self.blend = blend
        self.hold = hold
        self.top = top_deg
        self.still = Primitive.still("still", standing_deg)
        moving = sorted(
            (p for p in primitives if p.heading_deg is not None and p.speed_mps > 0), key=lambda p: -p.speed_mps
        )
        kept: list[Primitive] = []
        for p in moving:  # fastest first: a slower gait in nearly the same direction adds nothing to steer with
            if all(abs((p.heading_deg - q.heading_deg + 180.0) % 360.0 - 180.0) >= MIN_SEPARATION_DEG for q in kept):
                kept.append(p)
        if len(kept) < 2:
            raise ConfigError(
                "the gait library needs translating primitives in at least two directions: "
                "run slot run experiment=gait_search (docs/soft.md)"
            )
        self.translation = self._aligned(sorted(kept, key=lambda p: p.heading_deg), kept[0], style, top_deg)
        # the ring of headings :meth:`_bracket` searches, relative to the first (deg): made once, not per call
        # (the path loop's envelope bisection asks for a bracket some thirty times a control period)
        headings = np.asarray([p.heading_deg for p in self.translation], float)
        self._ring_first = headings[0]
        self._ring = (headings - headings[0]) % 360.0
        measured = {p.name: p for p in kept}
        # how far each primitive's clock was moved, cycles: a robot that starts on it starts where the search did
        self._shift = {p.name: float(p.phase[0] - measured[p.name].phase[0]) for p in self.translation}
        turning = [p.aligned_to(kept[0], style, top_deg) for p in primitives if p.heading_deg is None]
        self.turn_left = max(turning, key=lambda p: p.yaw_rate_dps, default=None)
        self.turn_right = min(turning, key=lambda p: p.yaw_rate_dps, default=None)
        # blend="cycles": the cycle whose primitive is chosen, that choice, and the running sum (m/s x cycles)
        # of the chosen primitives' velocities across the commanded direction
        self._cycle: int | None = None
        self._second = False
        self._owed = 0.0

    @staticmethod
    def _aligned(ring: list[Primitive], fastest: Primitive, style: GaitStyle, top: float) -> list[Primitive]:
        """The primitives (sorted by heading) shifted in time so that neighbours agree (:meth:`Primitive.aligned_to`),
        chained outward both ways from the fastest, which keeps its clock. A primitive's timing does not
        change what it does alone, but a mix of two schedules, or a switch from one to the other at a
        cycle's start, is a gait between them only when their legs move together: the mirror image of the
        44-deg gait ran its legs about half a cycle from the forward gait's, and 6 % of it mixed into the
        forward walk as a steering correction cost a fifth of its speed (measured: 31 -> 25 mm/s)."""
        n = len(ring)
        start = ring.index(fastest)
        out: list[Primitive | None] = [None] * n
        out[start] = fastest
        for k in range(1, n // 2 + 1):  # up the ring, then down it, one step further out each time
            up, down = (start + k) % n, (start - k) % n
            if out[up] is None:
                out[up] = ring[up].aligned_to(out[(up - 1) % n], style, top)
            if out[down] is None:
                out[down] = ring[down].aligned_to(out[(down + 1) % n], style, top)
        return [p for p in out if p is not None]

    @classmethod
    def from_config(
        cls, cfg: GaitStyleConfig, standing_deg: float, top_deg: float, blend: str = "cycles", hold: int = 1
    ) -> GaitLibrary:
        prims = [Primitive.from_config(p) for p in cfg.primitives]
        return cls(GaitStyle(cfg.frequency_hz, cfg.duty, cfg.sharpness), prims, standing_deg, top_deg, blend, hold)

    def _bracket(self, heading_deg: float) -> tuple[Primitive, Primitive, float]:
        """The two primitives whose headings bracket ``heading_deg`` (cyclically) and the blend fraction."""
        rel = self._ring
        x = (heading_deg - self._ring_first) % 360.0
        j = int(np.searchsorted(rel, x, side="right") - 1)
        k = (j + 1) % len(rel)
        span = (rel[k] - rel[j]) % 360.0 if k != j else 360.0
        span = span or 360.0
        return self.translation[j], self.translation[k], float((x - rel[j]) / span)

    @staticmethod
    def _across_along(p: Primitive, heading_deg: float) -> tuple[float, float]:
        """The primitive's measured velocity (m/s) across (to the left of) and along a direction."""
        rel = np.radians(p.heading_deg - heading_deg)
        return p.speed_mps * float(np.sin(rel)), p.speed_mps * float(np.cos(rel))

    def _share(self, heading_deg: float) -> tuple[Primitive, Primitive, float, bool, float]:
        """The bracketing primitives, the share of the second, whether it is a share of whole cycles
        (``blend="cycles"`` away from both primitives: the share whose mean velocity points along
        ``heading_deg``) rather than of the schedules' weights (by angle), and the speed (m/s) along
        ``heading_deg`` that this blend makes at full weight."""
        a, b, lam = self._bracket(heading_deg)
        if self.blend == "cycles" and NEAR < lam < 1.0 - NEAR:
            (across_a, along_a), (across_b, along_b) = (self._across_along(p, heading_deg) for p in (a, b))
            if across_a * across_b < 0.0:
                lam = across_a / (across_a - across_b)
            return a, b, lam, True, (1.0 - lam) * along_a + lam * along_b
        return a, b, lam, False, (1.0 - lam) * a.speed_mps + lam * b.speed_mps

    def max_speed(self, heading_deg: float) -> float:
        """Speed (m/s) along this body-frame direction that the blend for it makes at full weight: the envelope."""
        return self._share(heading_deg)[4]

    def _cycle_choice(self, a: Primitive, b: Primitive, heading_deg: float, cycle: int) -> Primitive:
        """``a`` or ``b`` for this cycle (decided at the start of each run of ``hold`` cycles): the one that keeps
        the running sum of the chosen velocities across ``heading_deg`` nearer zero (error diffusion)."""
        cycle //= self.hold  # a choice holds for `hold` cycles: each is one step of the diffusion
        if cycle != self._cycle:
            across_a = self._across_along(a, heading_deg)[0]
            across_b = self._across_along(b, heading_deg)[0]
            self._cycle = cycle
            self._second = abs(self._owed + across_b) < abs(self._owed + across_a)
            # bounded: a command that turns or a bracket that changes starts over within one cycle
            bound = max(abs(across_a), abs(across_b))
            self._owed = float(np.clip(self._owed + (across_b if self._second else across_a), -bound, bound))
        return b if self._second else a

    def start_phase(self, velocity_body: np.ndarray) -> float:
        """Where the gait clock starts (cycles in [0, 1)) for a robot commanded ``velocity_body`` from rest:
        so that the primitive nearest the command starts at the point of its cycle at which the search
        started and measured it, however far :meth:`_aligned` moved its clock. (The two mirror-image
        lateral gaits otherwise started half a cycle apart, and settled into different stick-slip
        patterns: 90 deg 14.9 mm/s, 270 deg 12.1.)"""
        v = np.asarray(velocity_body, float)
        if not np.any(v):
            return 0.0
        a, b, lam = self._bracket(float(np.degrees(np.arctan2(v[1], v[0]))))
        return float(-self._shift[(a if lam < 0.5 else b).name] % 1.0)

    @property
    def max_yaw_rate_dps(self) -> float:
        rates = [abs(p.yaw_rate_dps) for p in (self.turn_left, self.turn_right) if p is not None]
        return min(rates) if rates else 0.0

    def command(self, velocity_body: np.ndarray, yaw_rate_dps: float, cycle: int = 0) -> GaitCommand:
        """The mix for a body-frame velocity (m/s) and a yaw rate (deg/s) in gait cycle number ``cycle``."""
        v = np.asarray(velocity_body, float)
        speed = float(np.hypot(v[0], v[1]))
        heading = float(np.degrees(np.arctan2(v[1], v[0])))
        a, b, lam, by_cycles, top = self._share(heading)
        s = min(1.0, speed / top) if top > 0 else 0.0
        r = 0.0
        turn = None
        if yaw_rate_dps > 0 and self.turn_left is not None:
            turn, r = self.turn_left, min(1.0, yaw_rate_dps / self.turn_left.yaw_rate_dps)
        elif yaw_rate_dps < 0 and self.turn_right is not None:
            turn, r = self.turn_right, min(1.0, yaw_rate_dps / self.turn_right.yaw_rate_dps)
        if s + r > 1.0:
            s, r = s / (s + r), r / (s + r)
        if by_cycles:
            parts = [(s, self._cycle_choice(a, b, heading, cycle)), (1.0 - s - r, self.still)]
        elif self.blend == "parameters":
            parts = [(s, interpolate(a, b, lam)), (1.0 - s - r, self.still)]
        else:
            parts = [(s * (1.0 - lam), a), (s * lam, b), (1.0 - s - r, self.still)]
        if turn is not None:
            parts.append((r, turn))
        return GaitCommand(parts, s, r if yaw_rate_dps >= 0 else -r, top, by_cycles)
