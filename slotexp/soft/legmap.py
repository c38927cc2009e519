"""Leg maps: what one quasi-static leg does as a function of its tendon angle (paper eq. 11, generalised).

Eq. 11 maps a normal force to a tendon angle at one root height, for a foot that
presses only. A controller that walks needs more of the leg, and these maps give
it, from the quasi-static Cosserat leg clamped at its root (level, as under a level
torso), settled to equilibrium at each point:

- **free foot** (frictionless ground: the foot slides to where the leg puts it):
  the ground's normal force ``N(theta, h)`` and the foot's radial position
  ``r(theta, h)`` (tip, horizontally from the root, outwards positive), against
  tendon angle theta and root height h;
- **stuck foot** (held in place by friction): the radial force ``F_r(theta, dr)``
  the ground exerts on the foot (outwards positive) and the normal force
  ``N(theta, dr)``, against theta and the foot's radial offset dr from where it
  would rest free at that angle, at the stance root height. The holding force is
  applied at the foot on frictionless ground (the same equilibrium, without the
  stick-slip of regularised friction), over a range of forces, and the offset it
  produces is measured. F_r grows with dr at the leg's radial stiffness: a foot
  stuck while the tendon winds on ends up outside its free position (dr > 0), the
  ground holds it with F_r > 0, and the leg pulls the body towards the foot.
  Coulomb friction, |F_r| <= mu N, bounds how far a foot can be held.

Each map is fitted by a polynomial in the two variables (tensor product, powers
up to ``degrees``: the stuck foot's stiffness falls fivefold with the angle, which
needs up to theta^5 times dr^3); :class:`PolyFit` holds the coefficients with their R^2 and the
largest error, both on the grid and on held-out points between the grid points.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..config import SlotConfig
from .integrators import LegSim
from .params import O_N, P_MU, P_MUS, P_TFX
from .statics import clamped_leg, set_tendon


@dataclass
class PolyFit:
    """z = sum_ij c_ij u^i v^j (i <= degrees[0], j <= degrees[1]), u and v scaled to [-1, 1] over the fitted ranges."""

    names: tuple[str, str]
    ranges: tuple[tuple[float, float], tuple[float, float]]
    degrees: tuple[int, int]
    coefficients: list[float]
    r2: float = float("nan")
    rmse: float = float("nan")
    max_error: float = float("nan")
    holdout_max_error: float = float("nan")
    extra: dict = field(default_factory=dict)

    def _features(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        (u0, u1), (v0, v1) = self.ranges
        us = (2.0 * (np.asarray(u, float) - u0) / (u1 - u0)) - 1.0
        vs = (2.0 * (np.asarray(v, float) - v0) / (v1 - v0)) - 1.0
        return np.stack([us**i * vs**j for i, j in _powers(self.degrees)], axis=-1)

    def __call__(self, u: np.ndarray | float, v: np.ndarray | float) -> np.ndarray:
        return self._features(u, v) @ np.asarray(self.coefficients)

    @classmethod
    def fit(
        cls, names: tuple[str, str], u: np.ndarray, v: np.ndarray, z: np.ndarray, degrees: tuple[int, int]
    ) -> PolyFit:
        u, v, z = (np.asarray(a, float).ravel() for a in (u, v, z))
        out = cls(names, ((float(u.min()), float(u.max())), (float(v.min()), float(v.max()))), tuple(degrees), [])
        coef, *_ = np.linalg.lstsq(out._features(u, v), z, rcond=None)
        out.coefficients = coef.tolist()
        residual = out(u, v) - z
        out.rmse = float(np.sqrt(np.mean(residual**2)))
        out.max_error = float(np.max(np.abs(residual)))
        ss_tot = float(np.sum((z - z.mean()) ** 2))
        out.r2 = 1.0 - float(np.sum(residual**2)) / ss_tot if ss_tot > 0 else float("nan")
        return out

    def as_dict(self) -> dict:
        return {
            "variables": list(self.names),
            "ranges": [list(r) for r in self.ranges],
            "degrees": list(self.degrees),
            "powers": [list(p) for p in _powers(self.degrees)],
            "coefficients": self.coefficients,
            "r2": self.r2,
            "rmse": self.rmse,
            "max_error": self.max_error,
            "holdout_max_error": self.holdout_max_error,
            **self.extra,
        }

    @classmethod
    def from_dict(cls, d: dict) -> PolyFit:
        return cls(
            tuple(d["variables"]),
            tuple(tuple(r) for r in d["ranges"]),
            tuple(d["degrees"]),
            list(d["coefficients"]),
            d.get("r2", float("nan")),
            d.get("rmse", float("nan")),
            d.get("max_error", float("nan")),
            d.get("holdout_max_error", float("nan")),
        )


def _powers(degrees: tuple[int, int]) -> list[tuple[int, int]]:
    return list(itertools.product(range(degrees[0] + 1), range(degrees[1] + 1)))


def _settle(sim: LegSim, cfg: SlotConfig, seconds: float) -> None:
    load = cfg.leg_load
    sim.step(load.dt, max(1, int(round(seconds / load.dt))), load.integrator)


def free_foot(cfg: SlotConfig, angles: np.ndarray, heights: np.ndarray, settle_s: float, progress=None) -> list[dict]:
    """Normal force and foot position on frictionless ground, for every (angle, root height)."""
    rows = []
    for h in heights:
        sim = clamped_leg(cfg, root_height=float(h))
        sim.par[P_MU] = sim.par[P_MUS] = 0.0
        _settle(sim, cfg, settle_s)  # under its own weight first
        for theta in angles:  # continuation in the angle: each point starts from the last
            set_tendon(sim, float(theta), cfg.robot.leg.pulley_radius)
            _settle(sim, cfg, settle_s)
            rows.append(
                {
                    "angle_deg": float(theta),
                    "root_height_m": float(h),
                    "normal_n": float(sim.out[O_N]),
                    "foot_radial_m": float(sim.pos[-1, 0] - sim.pos[0, 0]),
                    "residual_speed_m_s": float(np.max(np.abs(sim.vel))),
                }
            )
            if progress is not None:
                progress()
    return rows


def stuck_foot(
    cfg: SlotConfig, angles: np.ndarray, forces: np.ndarray, root_height: float, settle_s: float, progress=None
) -> list[dict]:
    """Radial offset and normal force of a foot on which the ground pushes radially with ``force``.

    A stuck foot is one the ground holds with a radial (friction) force; applying that
    force at the foot on frictionless ground gives the same equilibrium without the
    stick-slip of regularised friction, so each (angle, force) point is exact. The
    offset is measured from where the foot rests free at that angle.
    """
    rows = []
    for theta in angles:
        free = clamped_leg(cfg, root_height=root_height)
        free.par[P_MU] = free.par[P_MUS] = 0.0
        set_tendon(free, float(theta), cfg.robot.leg.pulley_radius)
        _settle(free, cfg, 2.0 * settle_s)
        r_free = float(free.pos[-1, 0] - free.pos[0, 0])
        sim = _copy(free)
        for force in forces:  # continuation in the force from the free rest
            sim.par[P_TFX] = float(force)
            _settle(sim, cfg, settle_s)
            foot = float(sim.pos[-1, 0] - sim.pos[0, 0])
            rows.append(
                {
                    "angle_deg": float(theta),
                    "radial_force_n": float(force),
                    "offset_m": foot - r_free,
                    "free_radial_m": r_free,
                    "foot_radial_m": foot,
                    "normal_n": float(sim.out[O_N]),
                    "residual_speed_m_s": float(np.max(np.abs(sim.vel))),
                }
            )
            if progress is not None:
                progress()
    return rows


def _copy(sim: LegSim) -> LegSim:
    out = LegSim(sim.model, sim.par.copy(), sim.free0)
    out.free_length = sim.free_length
    for name in ("pos", "vel", "theta", "omega", "root", "normal", "out"):
        setattr(out, name, getattr(sim, name).copy())
    return out
