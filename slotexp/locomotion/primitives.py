"""Gait primitives: one periodic tendon schedule per leg, on a phase clock shared by a gait style.

Per leg i (order FL, RL, RR, FR), at phase psi = f t (cycles):

    theta_i(psi) = clip(b_i + a_i w(psi + phi_i), 0, theta_max)      [deg]

with w a smoothed square wave in [0, 1], high for the fraction ``duty`` of the
cycle around psi = 0 and with edges as steep as ``sharpness`` makes them:

    w(u) = (tanh(k (cos 2 pi u - cos pi d)) - lo) / (hi - lo),   lo, hi: its values at cos = -1, +1

(small k: a sine; large k: a square). A leg presses harder while its tendon is
high: that is its stance (it tends to stick), the low part its swing (it slides).
A :class:`GaitStyle` fixes the clock and the waveform (f, d, k) for every primitive
of the style, so primitives can be mixed leg by leg at one clock (:func:`mix`):
the library steers by blending neighbouring directions and speeds up or slows
down by mixing towards standing still.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..config import PrimitiveConfig

# mirror images of a gait: the torso is symmetric about its x and y axes
MIRROR_X = (3, 2, 1, 0)  # about the body x axis: FL<->FR, RL<->RR (heading h -> -h, yaw rate -> -yaw rate)
MIRROR_Y = (1, 0, 3, 2)  # about the body y axis: FL<->RL, FR<->RR (heading h -> 180 - h, yaw rate -> -yaw rate)
# a quarter turn to the left: each leg does what the leg a quarter turn clockwise of it did (FL what FR did, ...).
# The legs point out at 45 deg + k 90 deg, so this maps a gait for heading h to one for h + 90 up to the
# torso's aspect ratio (125.5 x 85.5 mm): an approximate symmetry, good for starting a search.
ROTATE_LEFT = (3, 0, 1, 2)


@dataclass(frozen=True)
class GaitStyle:
    """The clock and waveform shared by every primitive of a style."""

    frequency_hz: float
    duty: float
    sharpness: float

    def wave(self, u: np.ndarray | float) -> np.ndarray:
        """The waveform w(u) in [0, 1] at phase ``u`` (cycles)."""
        c = math.cos(math.pi * self.duty)
        lo = math.tanh(self.sharpness * (-1.0 - c))
        hi = math.tanh(self.sharpness * (1.0 - c))
        return (np.tanh(self.sharpness * (np.cos(2.0 * np.pi * np.asarray(u, dtype=float)) - c)) - lo) / (hi - lo)


@dataclass(frozen=True)
class Primitive:
    """One periodic schedule of a style, with what it was measured to do on the plant."""

    name: str
    base_deg: np.ndarray  # (4,)
    amplitude_deg: np.ndarray  # (4,)
    phase: np.ndarray  # (4,) cycles
    heading_deg: float | None = None  # direction of travel in the body frame; None: turning or standing
    speed_mps: float = 0.0  # measured mean speed along ``heading_deg``
    yaw_rate_dps: float = 0.0  # measured mean yaw rate
    # its angles over one whole cycle, by (style, top, samples): the stance plan reads them every MPC step
    _cycles: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def from_config(cls, p: PrimitiveConfig) -> Primitive:
        return cls(
            p.name,
            np.asarray(p.base_deg, float),
            np.asarray(p.amplitude_deg, float),
            np.asarray(p.phase, float),
            p.heading_deg,
            p.speed_mps,
            p.yaw_rate_dps,
        )

    def angles(self, style: GaitStyle, psi: np.ndarray | float, top: float) -> np.ndarray:
        """Tendon angles (..., 4) at phase(s) ``psi`` (cycles), clipped to [0, ``top``]."""
        psi = np.asarray(psi, dtype=float)[..., None]
        return np.clip(self.base_deg + self.amplitude_deg * style.wave(psi + self.phase), 0.0, top)

    def cycle(self, style: GaitStyle, top: float, samples: int) -> np.ndarray:
        """Tendon angles (samples, 4) at the phases k / ``samples`` of one cycle (:meth:`angles`), made once per
        style, top and sample count and kept (read-only): a primitive does not change, and the stance plan
        (:func:`stance`) takes its cycle's mean every MPC step."""
        key = (style, top, samples)
        found = self._cycles.get(key)
        if found is None:
            found = self.angles(style, np.arange(samples) / samples, top)
            found.flags.writeable = False
            self._cycles[key] = found
        return found

    def mirrored(self, axis: str) -> Primitive:
        """The mirror image about the body ``"x"`` or ``"y"`` axis (legs swapped, heading and turn reflected)."""
        perm = list(MIRROR_X if axis == "x" else MIRROR_Y)
        heading = None
        if self.heading_deg is not None:
            heading = -self.heading_deg if axis == "x" else 180.0 - self.heading_deg
            heading = (heading + 180.0) % 360.0 - 180.0
        return Primitive(
            f"{self.name}_m{axis}",
            self.base_deg[perm],
            self.amplitude_deg[perm],
            self.phase[perm],
            heading,
            self.speed_mps,
            -self.yaw_rate_dps,
        )

    def glide_symmetric(self, axis: str) -> Primitive:
        """This gait made its own mirror image about the body ``axis`` half a cycle later: each leg's base and
        amplitude averaged with its mirror leg's, and their phases set half a cycle apart about their mean.

        Why: on a robot that is symmetric about ``axis``, such a gait's periodic motion is its own mirror image
        half a cycle on, so over a whole cycle it can turn the body neither way and drift it neither way across
        that axis, on every model, whatever its friction, stiffness or damping. A searched gait that is not
        symmetric walks straight only where its asymmetry happens to cancel the model's response to it: the
        searched forward gait (amplitudes 84/76 deg on its front legs) yawed 0.06 deg/s on the default model and
        -0.13 to -0.24 deg/s on stiffer or less grippy ones; made glide-symmetric, within 0.03 deg/s on all five
        at the same speed. The travel along ``axis`` is what the gait is for, so ``axis`` is the one it travels
        along (``"x"`` for forward and backward, ``"y"`` for sideways)."""
        perm = list(MIRROR_X if axis == "x" else MIRROR_Y)
        # each leg's phase moved halfway to its mirror leg's plus half a cycle (the difference wrapped into
        # [-0.5, 0.5) cycles): the pair ends half a cycle apart
        phase = self.phase + 0.5 * ((self.phase[perm] - self.phase + 1.0) % 1.0 - 0.5)
        return replace(
            self,
            base_deg=0.5 * (self.base_deg + self.base_deg[perm]),
            amplitude_deg=0.5 * (self.amplitude_deg + self.amplitude_deg[perm]),
            phase=phase,
        )

    def along_axis(self, tolerance_deg: float = 10.0) -> str | None:
        """The body axis (``"x"`` or ``"y"``) this translating gait travels along, within ``tolerance_deg``
        (None: a diagonal heading, or turning)."""
        if self.heading_deg is None:
            return None
        h = self.heading_deg % 180.0
        if min(h, 180.0 - h) < tolerance_deg:
            return "x"
        return "y" if abs(h - 90.0) < tolerance_deg else None

    def rotated_left(self) -> Primitive:
        """The same gait a quarter turn to the left (approximate: see ``ROTATE_LEFT``)."""
        perm = list(ROTATE_LEFT)
        heading = None if self.heading_deg is None else (self.heading_deg + 270.0) % 360.0 - 180.0
        return Primitive(
            f"{self.name}_r90",
            self.base_deg[perm],
            self.amplitude_deg[perm],
            self.phase[perm],
            heading,
            self.speed_mps,
            self.yaw_rate_dps,
        )

    def shifted(self, cycles: float) -> Primitive:
        """The same gait with its clock ``cycles`` ahead: every leg's phase moves alike, so alone it
        walks exactly as before; only its timing against other primitives changes."""
        return replace(self, phase=self.phase + cycles)

    def aligned_to(self, other: Primitive, style: GaitStyle, top: float, samples: int = 240) -> Primitive:
        """This gait shifted in time (:meth:`shifted`) so that its legs' schedules agree best with
        ``other``'s: the shift that maximises the summed circular cross-correlation of the legs'
        tendon angles about their cycle means, to 1/``samples`` of a cycle."""
        psi = np.arange(samples) / samples
        mine = self.angles(style, psi, top)
        theirs = other.angles(style, psi, top)
        mine = mine - mine.mean(axis=0)
        theirs = theirs - theirs.mean(axis=0)
        # corr[k] = sum_i sum_n mine_i(n + k) theirs_i(n): mine delayed by k samples matches theirs
        corr = np.fft.irfft(np.fft.rfft(mine, axis=0) * np.conj(np.fft.rfft(theirs, axis=0)), n=samples, axis=0)
        k = int(np.argmax(corr.sum(axis=1)))
        return self.shifted(k / samples)

    @staticmethod
    def still(name: str, angle_deg: float) -> Primitive:
        """Standing: every tendon held at ``angle_deg``."""
        return Primitive(name, np.full(4, angle_deg), np.zeros(4), np.zeros(4))


def from_steps(name: str, steps_deg: np.ndarray, top: float) -> Primitive:
    """A primitive shaped like a step schedule (steps, 4) of tendon angles, stretched over one gait cycle:
    per leg the base is its lowest angle and the amplitude its range (clipped to [0, ``top``]), and the phase puts
    the waveform's high part at the middle of the steps where the leg is high. A seed for the gait search (the
    robot's own gaits hold each angle for a step; the waveform is smooth), not a copy of the schedule."""
    steps = np.clip(np.asarray(steps_deg, dtype=float), 0.0, top)
    n = steps.shape[0]
    lo, hi = steps.min(axis=0), steps.max(axis=0)
    centres = (np.arange(n) + 0.5) / n  # each step's middle, cycles
    phase = np.zeros(steps.shape[1])
    for leg in range(steps.shape[1]):
        if hi[leg] - lo[leg] < 1e-9:
            continue
        high = steps[:, leg] > 0.5 * (lo[leg] + hi[leg])
        angle = np.angle(np.exp(2j * np.pi * centres[high]).sum()) / (2.0 * np.pi)  # circular mean, cycles
        phase[leg] = -angle  # w(psi + phase) peaks at psi = -phase
    phase -= phase[0]
    return Primitive(name, lo, hi - lo, phase)


def interpolate(a: Primitive, b: Primitive, lam: float) -> Primitive:
    """The primitive a fraction ``lam`` of the way from ``a`` to ``b`` in its parameters: bases and
    amplitudes linearly, each leg's phase along the shorter arc of the cycle. Unlike a mix of the
    two schedules, it keeps one leg sequence, so it stays a gait when ``a`` and ``b`` are phased differently."""
    dphi = (b.phase - a.phase + 0.5) % 1.0 - 0.5
    return Primitive(
        f"{a.name}~{b.name}",
        (1.0 - lam) * a.base_deg + lam * b.base_deg,
        (1.0 - lam) * a.amplitude_deg + lam * b.amplitude_deg,
        a.phase + lam * dphi,
    )


def _weighted(parts: list[tuple[float, Primitive]], angles_of, top: float) -> np.ndarray:
    """``clip(sum w_j angles_of(p_j), 0, top)`` over the parts of nonzero weight, in their order."""
    out = 0.0
    for weight, prim in parts:
        if weight != 0.0:
            out = out + weight * angles_of(prim)
    return np.clip(out, 0.0, top)


def mix(style: GaitStyle, parts: list[tuple[float, Primitive]], psi: np.ndarray | float, top: float) -> np.ndarray:
    """Tendon angles (..., 4) of the weighted mix ``sum w_j theta_j(psi)`` of primitives at one clock."""
    return _weighted(parts, lambda prim: prim.angles(style, psi, top), top)


def stance(
    style: GaitStyle,
    parts: list[tuple[float, Primitive]],
    psi: np.ndarray,
    top: float,
    samples: int = 48,
    angles: np.ndarray | None = None,
) -> np.ndarray:
    """Stance flags (len(psi), 4): legs whose tendon is at or above its mean over the cycle (pressing
    harder than on average, so they tend to stick); a leg that hardly moves (< 1 deg) is always in stance.
    ``angles``: the mix at ``psi`` (len(psi), 4), where the caller has it already."""
    # the cycle's mix from each primitive's kept cycle (the same sum :func:`mix` makes, in the same order)
    cycle = _weighted(parts, lambda prim: prim.cycle(style, top, samples), top)
    here = mix(style, parts, np.atleast_1d(psi), top) if angles is None else angles
    mean = cycle.mean(axis=0)
    still = np.ptp(cycle, axis=0) < 1.0
    return (here >= mean) | still
