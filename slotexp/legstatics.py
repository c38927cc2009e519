"""One leg clamped at its root, driven to equilibrium (experiments ``leg`` and ``calibrate``)."""

from __future__ import annotations

import numpy as np

from .config import SlotConfig
from .leg import build_leg
from .legsim import O_N, O_T, P_TFREE, LegSim, make_par, tendon_length


def clamped_leg(cfg: SlotConfig, root_height: float | None = None) -> LegSim:
    """A leg from ``cfg.robot`` with the loads of ``cfg.leg_load`` (tendon at 0 until set)."""
    leg, contact, tendon = cfg.robot.leg, cfg.robot.contact, cfg.robot.tendon
    load = cfg.leg_load
    model = build_leg(leg)
    n = model.n_nodes
    par = make_par(gravity=cfg.sim.gravity, k_contact=contact.stiffness, d_contact=contact.damping,
                   mu=contact.friction, v_eps=contact.slip_velocity, ground=1.0 if load.ground else 0.0,
                   damping=leg.damping_per_s, tendon_k=tendon.stiffness, tendon_offset=tendon.offset,
                   tendon_max=cfg.robot.servo.stall_torque / leg.pulley_radius,
                   tip_fx=load.tip_force[0], tip_fz=load.tip_force[1], tip_m=load.tip_moment,
                   n_anchor=max(1, int(round(tendon.routed_fraction * (n - 1)))),
                   paper_model=1.0 if leg.model == "paper" else 0.0, k_restore=leg.restoring_stiffness)
    sim = LegSim(model, par)
    height = load.root_height if root_height is None else root_height
    if height is not None:
        shift = height - model.rest_pos[0, 1]
        sim.pos[:, 1] += shift
        sim.root[1] += shift
    sim.free0 = tendon_length(model.rest_pos, model.rest_theta, model.rest_theta[0], par) + tendon.slack
    set_tendon(sim, load.tendon_deg, leg.pulley_radius)
    return sim


def set_tendon(sim: LegSim, angle_deg: float, pulley_radius: float) -> None:
    """Wind ``pulley_radius * angle`` of cable in."""
    sim.par[P_TFREE] = sim.free0 - pulley_radius * np.deg2rad(angle_deg)


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
