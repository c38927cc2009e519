"""Packed leg parameters and step outputs: index constants and the packer.

The numba kernels take every load and contact setting of one leg in one float
array ``par`` (indices ``P_*``, names in :data:`PAR`), so they keep one flat
signature however many loads there are; each step reports the reaction on the
root, the tendon tension and the contact totals in ``out`` (indices ``O_*``,
names in :data:`OUT`). Flags (``ground``, ``paper_model``) are stored as 0/1 and
the tendon's anchor node ``n_anchor`` as a float.

``par`` holds what a run does not change; kernels only read it. What the servo
changes, the tendon's free length (the cable it leaves out), is state: an argument
of the step kernels, kept by their caller (:class:`~slotexp.soft.integrators.LegSim`,
the coupled plant's servo loop).

:func:`leg_params` is the one place a leg's parameters are read from the config,
for the clamped leg (:mod:`slotexp.soft.statics`) and the four legs of the coupled
plant (:mod:`slotexp.plants.cosserat`) alike.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..config import SlotConfig
from .rod import node_arclengths

PAR = (
    "gravity",
    "k_contact",
    "d_contact",
    "mu",
    "v_eps",
    "ground",
    "damping",
    "tendon_k",
    "tendon_offset",
    "tendon_max",
    "tip_fx",
    "tip_fz",
    "tip_m",
    "n_anchor",
    "paper_model",
    "k_restore",
    "mu_static",
    "v_stribeck",
    "tendon_pair",
    "tendon_route",
    "tendon_guide_x",
    "tendon_guide_z",
    "friction_solved",
    "jacobian_turn",
)
(P_G, P_K, P_D, P_MU, P_VEPS, P_GROUND, P_C, P_TK, P_TOFF, P_TMAX, P_TFX, P_TFZ, P_TM, P_NA, P_PAPER, P_KR) = range(16)
P_MUS, P_VS = 16, 17  # the feet's friction at rest and the speed over which it falls to mu (robot.contact)
# robot.tendon.antagonist: the two cables' free lengths summed (constant as the servo turns); 0: one cable
P_TPAIR = 18
# robot.tendon.routing: 0 the cable along the leg at its offset, 1 a bowstring from a guide on the torso to the anchor;
# the guide's position relative to the root node in the root's frame (m: along the root's tangent, and its normal up)
P_TROUTE, P_TGX, P_TGZ = 19, 20, 21
# plant.friction: 1 the implicit step solves the pressed nodes' friction along the plane at the step's end
# (slotexp.soft.friction), 0 it takes the friction's secant slope at the step's start (a plant setting: the
# coupled plant sets it, the clamped leg's statics leave it 0)
P_FSOLVE = 22
# plant.jacobian_turn: the implicit step's Jacobians are made afresh once an element turned this far (rad) since
# they were made (0: by age, contact and cable only)
P_JTURN = 23
# friction: along the leg's plane (the leg's own step); friction_lateral: across it (the coupled plant's torso step)
# tendon_side: which cable pulls (1: below the centreline, -1: above it, robot.tendon.antagonist; 0: neither)
OUT = ("root_fx", "root_fz", "root_m", "tension", "normal", "friction", "diverged", "friction_lateral", "tendon_side")
O_FX, O_FZ, O_M, O_T, O_N, O_F, O_DIV, O_FL, O_TS = range(9)


def make_par(**kw: float) -> np.ndarray:
    """Pack loads and contact settings; unspecified entries are zero (no ground, no tendon)."""
    par = np.zeros(len(PAR))
    par[P_VEPS] = 1e-3
    par[P_TMAX] = np.inf
    par[P_NA] = 1
    par[P_VS] = 1.0  # mu_static 0 (not above mu): plain Coulomb friction
    for key, value in kw.items():
        par[PAR.index(key)] = value
    return par


def leg_params(
    cfg: SlotConfig, *, ground: bool = True, tip_force: Sequence[float] = (0.0, 0.0), tip_moment: float = 0.0
) -> np.ndarray:
    """The packed parameters of one leg of ``cfg.robot`` (``robot.leg``, ``contact``, ``tendon``, ``servo``).

    ``ground`` and the static tip load are the caller's: the plant's legs stand on
    the ground with no tip load, the clamped leg takes them from ``cfg.leg_load``.
    The tendon is anchored at the node ``routed_fraction`` of the way down the leg (of the mesh
    :func:`~slotexp.soft.rod.build_leg` makes with that fraction);
    its tension is capped at the servo's stall torque over the pulley radius.
    """
    leg, contact, tendon = cfg.robot.leg, cfg.robot.contact, cfg.robot.tendon
    return make_par(
        gravity=cfg.sim.gravity,
        k_contact=contact.stiffness,
        d_contact=contact.damping,
        mu=contact.friction,
        v_eps=contact.slip_velocity,
        ground=1.0 if ground else 0.0,
        damping=leg.damping_per_s,
        tendon_k=tendon.stiffness,
        tendon_offset=tendon.offset,
        tendon_max=cfg.robot.servo.stall_torque / leg.pulley_radius,
        tip_fx=tip_force[0],
        tip_fz=tip_force[1],
        tip_m=tip_moment,
        n_anchor=node_arclengths(leg, tendon.routed_fraction)[1],
        paper_model=1.0 if leg.model == "paper" else 0.0,
        k_restore=leg.restoring_stiffness,
        mu_static=0.0 if contact.static_friction is None else contact.static_friction,  # 0: plain Coulomb
        v_stribeck=contact.stribeck_velocity,
        tendon_route=1.0 if tendon.routing == "bowstring" else 0.0,
        tendon_guide_x=tendon.guide_out,
        tendon_guide_z=tendon.guide_height,
    )
