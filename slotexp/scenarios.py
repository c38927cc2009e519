"""A scenario's perturbations as objects: what each does to the plant over one MPC period.

A perturbation answers :meth:`Perturbation.over` with a :class:`Disturbance`: a force on the
torso held over the period and instantaneous kicks at given times inside it.
:func:`advance` steps any plant through a period under them, cut at each kick, through the
two things every plant has (``step`` with an external force, ``apply_impulse``), so a new
kind of perturbation is a class here, not an edit of every plant. The state offsets and the
measurement noise act on the start and on what the controller sees, in the closed loop.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from .config import Impulse, ScenarioConfig

if TYPE_CHECKING:
    from .plants import Command, Plant

_EPS_S = 1e-12  # times closer than this are the same instant


@dataclass(frozen=True)
class Kick:
    """An instantaneous push at ``t``: linear (N s, world) and angular (N m s, about the mass centre)."""

    t: float
    linear: np.ndarray
    angular: np.ndarray


@dataclass
class Disturbance:
    """What a perturbation does over a period: a force (3,) N on the torso held over it (None: none)
    and kicks inside it."""

    force: np.ndarray | None = None
    kicks: list[Kick] = field(default_factory=list)


class Perturbation(Protocol):
    def over(self, t0: float, t1: float, rng: np.random.Generator) -> Disturbance:
        """What happens to the plant in [t0, t1) (called once per MPC period, in order)."""
        ...


class Impulses:
    """The scenario's pushes (``impulses``), each given once, in the period it falls in."""

    def __init__(self, impulses: Sequence[Impulse]) -> None:
        self.pending = sorted(impulses, key=lambda imp: imp.t)

    def over(self, t0: float, t1: float, rng: np.random.Generator) -> Disturbance:
        kicks = []
        while self.pending and self.pending[0].t < t1 - _EPS_S:
            imp = self.pending.pop(0)
            kicks.append(Kick(imp.t, np.asarray(imp.linear, float), np.asarray(imp.angular, float)))
        return Disturbance(kicks=kicks)


@dataclass
class ProcessNoise:
    """A Gaussian force on the torso (``noise.process_force_sigma`` N per axis), drawn once per period."""

    sigma: float

    def over(self, t0: float, t1: float, rng: np.random.Generator) -> Disturbance:
        return Disturbance(force=rng.normal(0.0, self.sigma, 3))


def perturbations(scenario: ScenarioConfig) -> list[Perturbation]:
    """The perturbations a scenario's config describes (those that act)."""
    out: list[Perturbation] = []
    if scenario.impulses:
        out.append(Impulses(scenario.impulses))
    if scenario.noise.process_force_sigma > 0:
        out.append(ProcessNoise(scenario.noise.process_force_sigma))
    return out


def advance(
    plant: Plant,
    command: Command,
    t: float,
    period: float,
    acting: Sequence[Perturbation],
    rng: np.random.Generator,
) -> None:
    """One MPC period of ``plant`` under ``command`` and the perturbations, cut exactly at each kick."""
    end = t + period
    force = None
    kicks: list[Kick] = []
    for p in acting:
        d = p.over(t, end, rng)
        if d.force is not None:
            force = d.force if force is None else force + d.force
        kicks.extend(d.kicks)
    now = t
    for kick in sorted(kicks, key=lambda k: k.t):
        if kick.t > now + _EPS_S:
            plant.step(command, kick.t - now, force)
            now = kick.t
        plant.apply_impulse(kick.linear, kick.angular)
    if end - now > _EPS_S:
        plant.step(command, end - now, force)
