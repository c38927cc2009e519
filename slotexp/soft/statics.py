"""One leg clamped at its root, driven to equilibrium (experiments ``leg`` and ``calibrate``)."""

from __future__ import annotations

import numpy as np

from ..config import SlotConfig
from .integrators import LegSim
from .loads import pair_free_length, rest_free_length
from .params import O_N, O_T, P_TPAIR, leg_params
from .rod import build_leg


def clamped_leg(cfg: SlotConfig, root_height: float | None = None) -> LegSim:
    """A leg from ``cfg.robot`` with the loads of ``cfg.leg_load`` (tendon at 0 until set)."""
    leg = cfg.robot.leg
    load = cfg.leg_load
    model = build_leg(leg, anchor_fraction=cfg.robot.tendon.routed_fraction)
    par = leg_params(cfg, ground=load.ground, tip_force=load.tip_force, tip_moment=load.tip_moment)
    free0 = rest_free_length(model, par, cfg.robot.tendon.slack)
    if cfg.robot.tendon.antagonist:
        par[P_TPAIR] = pair_free_length(model, par, free0)
    sim = LegSim(model, par, free0)
    height = load.root_height if root_height is None else root_height
    if height is not None:
        shift = height - model.rest_pos[0, 1]
        sim.pos[:, 1] += shift
        sim.root[1] += shift
    set_tendon(sim, load.tendon_deg, leg.pulley_radius)
    return sim


def set_tendon(sim: LegSim, angle_deg: float, pulley_radius: float) -> None:
    """Wind ``pulley_radius * angle`` of cable in."""
    sim.free_length = sim.free0 - pulley_radius * np.deg2rad(angle_deg)


def settle(sim: LegSim, cfg: SlotConfig, seconds: float | None = None) -> dict[str, float]:
    """Run the damped dynamics to equilibrium; return the tip and the loads at the end."""
    load = cfg.leg_load
    seconds = load.settle_time if seconds is None else seconds
    sim.step(load.dt, int(round(seconds / load.dt)), load.integrator)
    root = sim.pos[0]
    return {
        "tip_x": float(sim.pos[-1, 0] - root[0]),
        "tip_z": float(sim.pos[-1, 1] - root[1]),
        "tip_angle": float(sim.theta[-1]),
        "tension_n": float(sim.out[O_T]),
        "normal_force_n": float(sim.out[O_N]),
        "residual_speed_m_s": float(np.max(np.abs(sim.vel))),
    }
