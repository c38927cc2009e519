"""Loads on one leg besides its elasticity (:mod:`slotexp.soft.rod`), as numba kernels.

- gravity on the node masses;
- viscous damping of the leg's deformation rate, rate ``c`` (1/s): each node's
  velocity relative to the rigid motion of the root frame (its translation and its
  turning in the plane) and each element's angular velocity relative to the root's,
  treated implicitly. Moving rigidly with the torso is not damped; the damping acts
  between leg and torso, so its reaction (force and moment) goes to the root;
- penalty ground contact at every node below z = 0, N = max(0, -k z - d dz/dt),
  with the damping term implicit so it stays stable at any step;
- regularised isotropic Coulomb friction, F = -mu N v / max(|v|, v_eps), on the
  actual normal force N and the node's whole slip velocity v (optionally with a static
  coefficient above the sliding one, :func:`friction_coefficient`): along the leg's plane
  (the node's own velocity, solved implicitly) and across it (the torso's rigid
  motion at the node: the leg is rigid out of its plane); the coupled plant applies
  the part across the plane to the torso;
- the tendon: a cable at ``offset`` below the centreline over the proximal
  elements 0..na-1, anchored at node na. Its length is
  L = sum_e a_e + offset (theta_{na-1} - theta_0) (a_e the elements' axial
  lengths), its tension T = min(k_t max(0, L - L_free), T_max) acts as -T grad L:
  an axial compression along the routed part and a distributed bending moment that
  curls the leg down. ``L_free`` is the cable length the servo leaves out: state,
  passed to the kernels as ``free_length``, not a packed parameter. With a pair
  (``robot.tendon.antagonist``, ``par[P_TPAIR]`` > 0) a second cable runs at the same
  offset above the centreline on the same pulley, so the servo lets it out as it
  winds the first in: its free length is ``P_TPAIR - free_length``, and when the lower
  cable is slack it pulls the leg up (:func:`tendon_cable`);
- or the tendon as a bowstring (``robot.tendon.routing``, ``par[P_TROUTE]`` = 1): a straight
  cable from a guide G fixed to the torso (``par[P_TGX]``, ``par[P_TGZ]``: its place relative
  to the root node in the root's frame) to its anchor A on the leg, node na at ``offset``
  below the centreline. L = |A - G|; the tension pulls the anchor towards the guide and the
  guide (the torso, through the root node) towards the anchor, -T grad L on both, so the
  cable is reacted where it bears on each (:func:`bowstring`);
- an optional static tip force and moment (for the leg experiment).

The force and moment the leg exerts on its root (node 0, which belongs to the
torso) are reported as the reaction on the torso.
"""

from __future__ import annotations

import numpy as np

from ..jit import njit
from .params import (
    O_FX,
    O_FZ,
    O_M,
    P_C,
    P_D,
    P_G,
    P_GROUND,
    P_K,
    P_KR,
    P_MU,
    P_MUS,
    P_NA,
    P_PAPER,
    P_TFX,
    P_TFZ,
    P_TGX,
    P_TGZ,
    P_TK,
    P_TM,
    P_TMAX,
    P_TOFF,
    P_TPAIR,
    P_TROUTE,
    P_VEPS,
    P_VS,
)
from .rod import LegModel, directors, elastic_forces_cs, element_kinematics, paper_elastic_forces


@njit(cache=True, allocates=False)
def routed_geometry(pos, theta, cth, sth, theta_root, par):
    """The routed part's axial length sum a_e and its turn theta_{na-1} - theta_0: a cable at offset d
    from the centreline is sum a_e + d turn long (d > 0 below it, < 0 above)."""
    na = int(par[P_NA])
    length = 0.0
    for e in range(na):
        _, _, a, _ = element_kinematics(pos, e, cth[e], sth[e])
        length += a
    return length, theta[na - 1] - theta_root


@njit(cache=True, allocates=False)
def bowstring(pos, cth, sth, theta_root, par):
    """The bowstring's anchor-to-guide geometry: (L, u_x, u_z, r_x, r_z, c, s) with L = |A - G|, u the unit
    vector from the guide to the anchor, r the guide's lever from the root node, (c, s) the anchor element's
    director. A = pos[na] + d (s, -c) (d below the centreline), G = pos[0] + R(theta_root) (g_x, g_z)."""
    na = int(par[P_NA])
    c = cth[na - 1]
    s = sth[na - 1]
    d = par[P_TOFF]
    ax = pos[na, 0] + d * s
    az = pos[na, 1] - d * c
    cr = np.cos(theta_root)
    sr = np.sin(theta_root)
    rx = cr * par[P_TGX] - sr * par[P_TGZ]
    rz = sr * par[P_TGX] + cr * par[P_TGZ]
    dx = ax - (pos[0, 0] + rx)
    dz = az - (pos[0, 1] + rz)
    length = np.sqrt(dx * dx + dz * dz)
    return length, dx / length, dz / length, rx, rz, c, s


@njit(cache=True, allocates=False)
def tendon_cable(pos, theta, cth, sth, theta_root, par, free_length):
    """(tension, offset) of the cable that pulls: the one below the centreline (offset ``par[P_TOFF]``);
    with a pair, the one above (offset ``-par[P_TOFF]``, free length ``P_TPAIR - free_length``) when the
    lower one is slack. The two cannot both be taut but through the routed part's axial strain. The second
    value is the cable's lever about the root, which is its offset for a cable along the leg: a bowstring
    (``par[P_TROUTE]``) returns (its tension, the lever r x u of its pull on the guide about the root)."""
    if par[P_TROUTE] > 0.5:
        length, ux, uz, rx, rz, _, _ = bowstring(pos, cth, sth, theta_root, par)
        return tendon_tension(length, free_length, par), rx * uz - rz * ux
    length, turn = routed_geometry(pos, theta, cth, sth, theta_root, par)
    offset = par[P_TOFF]
    tension = tendon_tension(length + offset * turn, free_length, par)
    if tension <= 0.0 and par[P_TPAIR] > 0.0:
        upper = tendon_tension(length - offset * turn, par[P_TPAIR] - free_length, par)
        if upper > 0.0:
            return upper, -offset
    return tension, offset


def pair_free_length(model: LegModel, par: np.ndarray, free0: float) -> float:
    """``par[P_TPAIR]`` for a pair on a leg whose lower cable's free length at servo zero is ``free0``: the
    upper cable is shorter by 2 offset x the rest shape's turn over the routed part, with the same slack."""
    na = int(par[P_NA])
    return 2.0 * free0 - 2.0 * par[P_TOFF] * (model.rest_theta[na - 1] - model.rest_theta[0])


@njit(cache=True)
def tendon_length(pos, theta, theta_root, par, side=1.0) -> float:
    """Length of the routed cable (see the module docstring); ``side`` -1: the pair's upper cable."""
    cth = np.empty(theta.shape[0])
    sth = np.empty(theta.shape[0])
    directors(theta, cth, sth)
    if par[P_TROUTE] > 0.5:
        return bowstring(pos, cth, sth, theta_root, par)[0]
    length, turn = routed_geometry(pos, theta, cth, sth, theta_root, par)
    return length + side * par[P_TOFF] * turn


def rest_free_length(model: LegModel, par: np.ndarray, slack: float) -> float:
    """L_free with the servo at zero: the cable length of the rest shape plus the slack."""
    return tendon_length(model.rest_pos, model.rest_theta, model.rest_theta[0], par) + slack


@njit(cache=True, allocates=False)
def tendon_tension(length, free_length, par) -> float:
    """T = min(k_t max(0, L - L_free), T_max)."""
    stretch = length - free_length
    if stretch <= 0.0:
        return 0.0
    return min(par[P_TK] * stretch, par[P_TMAX])


@njit(cache=True, allocates=False)
def add_tendon(pos, cth, sth, theta_root, tension, offset, par, force, moment) -> float:
    """-T grad L into force/moment, for the cable whose lever about the root is ``offset`` (:func:`tendon_cable`);
    returns the moment the cable puts on the root (the torso) beside the force it adds to the root node."""
    na = int(par[P_NA])
    if par[P_TROUTE] > 0.5:
        _, ux, uz, _, _, c, s = bowstring(pos, cth, sth, theta_root, par)
        force[na, 0] -= tension * ux  # the anchor is pulled towards the guide ...
        force[na, 1] -= tension * uz
        moment[na - 1] -= tension * par[P_TOFF] * (ux * c + uz * s)
        force[0, 0] += tension * ux  # ... and the guide, on the torso, towards the anchor
        force[0, 1] += tension * uz
        return tension * offset
    for e in range(na):
        c = cth[e]
        s = sth[e]
        force[e, 0] += tension * c
        force[e, 1] += tension * s
        force[e + 1, 0] -= tension * c
        force[e + 1, 1] -= tension * s
        _, _, _, b = element_kinematics(pos, e, c, s)
        moment[e] -= tension * b
    moment[na - 1] -= tension * offset
    return tension * offset  # the cable leaves the root at the offset


@njit(cache=True, allocates=False)
def tendon_jacobian(pos, cth, sth, theta_root, tension, offset, par, scale, band, grad_l):
    """Add grad L into ``grad_l`` and ``scale`` * T * hess L into ``band`` (the implicit step's layout).

    The tendon's stiffness is T hess L + k_t grad L grad L^T: the first part is banded,
    the second rank-one (the implicit step handles it by Sherman-Morrison). A bowstring's L depends on the
    anchor's three coordinates (node na's x, z and the anchor element's angle) and on the root's.
    """
    na = int(par[P_NA])
    if par[P_TROUTE] > 0.5:
        # grad L: the anchor's x, z and angle, and the root node's x, z (the guide moves with it). The bowstring's
        # geometric stiffness T hess L is left explicit: it couples the anchor with the root, outside the band,
        # and the torso's share must match the anchor's exactly; it is T / L (under 1e3 N/m at the servo's
        # stall), explicitly stable on the anchor node's mass up to steps of about 2 ms.
        _, ux, uz, _, _, c, s = bowstring(pos, cth, sth, theta_root, par)
        d = par[P_TOFF]
        grad_l[3 * na] += ux
        grad_l[3 * na + 1] += uz
        grad_l[3 * (na - 1) + 2] += d * (ux * c + uz * s)
        grad_l[0] -= ux
        grad_l[1] -= uz
        return
    for e in range(na):
        ce = cth[e]
        se = sth[e]
        _, _, a, b = element_kinematics(pos, e, ce, se)
        grad_l[3 * e] -= ce
        grad_l[3 * e + 1] -= se
        grad_l[3 * e + 3] += ce
        grad_l[3 * e + 4] += se
        grad_l[3 * e + 2] += b
        # Hessian of a_e: d2a/dDelta dtheta = d1, d2a/dtheta2 = -a
        th = 3 * e + 2
        for comp in range(2):
            d1 = -se if comp == 0 else ce
            for node, sg in ((3 * e + comp, -1.0), (3 * e + 3 + comp, 1.0)):
                band[node, 4 + th - node] += scale * tension * sg * d1
                band[th, 4 + node - th] += scale * tension * sg * d1
        band[th, 4] += scale * tension * (-a)
    grad_l[3 * (na - 1) + 2] += offset


@njit(cache=True, allocates=False, inline="always")
def conservative_forces(
    pos,
    theta,
    theta_root,
    l0,
    voronoi,
    dtheta0,
    ea,
    ga,
    ei,
    mass,
    par,
    free_length,
    force,
    moment,
    cth,
    sth,
    rest_pos,
    refresh,
):
    """Elastic + tendon + gravity + tip load (no contact, no damping); ``free_length`` is the tendon's L_free.

    With ``refresh`` the directors ``cth``/``sth`` are recomputed from theta; otherwise
    the caller keeps them current. Returns (tension, moment on the root, the pulling cable's offset).
    """
    force[:] = 0.0
    moment[:] = 0.0
    if refresh:
        directors(theta, cth, sth)
    if par[P_PAPER] > 0.5:
        m_root = paper_elastic_forces(
            pos, theta, cth, sth, theta_root, rest_pos, l0, voronoi, dtheta0, ea, ei, par[P_KR], force, moment
        )
    else:
        m_root = elastic_forces_cs(pos, theta, cth, sth, theta_root, l0, voronoi, dtheta0, ea, ga, ei, force, moment)
    tension, offset = tendon_cable(pos, theta, cth, sth, theta_root, par, free_length)
    if tension > 0.0:
        m_root += add_tendon(pos, cth, sth, theta_root, tension, offset, par, force, moment)
    n = pos.shape[0]
    for i in range(n):
        force[i, 1] -= mass[i] * par[P_G]
    force[n - 1, 0] += par[P_TFX]
    force[n - 1, 1] += par[P_TFZ]
    moment[theta.shape[0] - 1] += par[P_TM]
    return tension, m_root, offset


@njit(cache=True, allocates=False)
def root_frame_velocity(pos, i, root):
    """The velocity node ``i`` would have moving rigidly with the root frame: the root's velocity
    (root[2], root[3]) plus its turning root[5] in the plane about the root node, at ``pos``."""
    return root[2] - root[5] * (pos[i, 1] - pos[0, 1]), root[3] + root[5] * (pos[i, 0] - pos[0, 0])


@njit(cache=True, allocates=False)
def damping_reaction(pos, vel, omega, mass, inertia, par, root):
    """The damping acts between leg and torso: its reaction on the root (force along the plane, vertical
    force, moment about the root).

    Node i feels -c m_i (v_i - v_rigid,i) at ``pos`` (the step's start, where the damping
    was evaluated) and element e -c I_e (omega_e - root[5]); the torso feels the opposite
    forces at the same points, so damping exchanges momentum and angular momentum exactly.
    """
    c = par[P_C]
    if c == 0.0:
        return 0.0, 0.0, 0.0
    fx = 0.0
    fz = 0.0
    m = 0.0
    for i in range(1, vel.shape[0]):
        rx, rz = root_frame_velocity(pos, i, root)
        px = mass[i] * (vel[i, 0] - rx)
        pz = mass[i] * (vel[i, 1] - rz)
        fx += px
        fz += pz
        m += (pos[i, 0] - pos[0, 0]) * pz - (pos[i, 1] - pos[0, 1]) * px
    for e in range(omega.shape[0]):
        m += inertia[e] * (omega[e] - root[5])
    return c * fx, c * fz, c * m


@njit(cache=True, allocates=False)
def root_reaction(force, m_root, mass, par, out):
    # node 0 belongs to the torso: its own weight is not a leg load
    out[O_FX] = force[0, 0]
    out[O_FZ] = force[0, 1] + mass[0] * par[P_G]
    out[O_M] = m_root


@njit(cache=True, allocates=False)
def dissipative_params(par):
    """Settings of the loads both integrators treat implicitly (damping, contact, friction).

    Returns (damping rate c, contact stiffness, contact damping, mu, v_eps, ground on, mu_static, v_stribeck).
    """
    return par[P_C], par[P_K], par[P_D], par[P_MU], par[P_VEPS], par[P_GROUND] > 0.5, par[P_MUS], par[P_VS]


# The implicit step's friction Jacobian is kept in levels a factor of 4 apart (a level is the largest slope it
# stands for, so the factored W damps at least as much as the friction's secant: stable at any step, and a
# slip is never reversed by its own friction); below the last level (slips faster than 4^FRICTION_LEVELS v_eps,
# 65 m/s at the default 1 mm/s) the slope is left out, at most mu N / v_eps / 4^FRICTION_LEVELS, far below a
# node's m / h.
FRICTION_LEVELS = 8


@njit(cache=True, allocates=False)
def friction_coefficient(speed, mu, mu_s, v_s):
    """The friction coefficient at a slip ``speed``: ``mu`` while sliding, rising to ``mu_s`` at rest.

    mu(s) = mu + (mu_s - mu) exp(-(s / v_s)^2), the Gaussian Stribeck curve (Olsson et al.,
    "Friction models and friction compensation", Eur. J. Control 4, 1998): a rubber-like pad
    holds more before it slips than it drags once sliding. With ``mu_s`` <= ``mu`` it is
    plain Coulomb friction, ``mu`` itself (the same arithmetic as without the option).
    """
    if mu_s <= mu:
        return mu
    x = speed / v_s
    return mu + (mu_s - mu) * np.exp(-x * x)


@njit(cache=True, allocates=False)
def coulomb_friction(vs, vlat, nrm, mu, v_eps, mu_s, v_s):
    """Isotropic regularised Coulomb friction on a node pressed with ``nrm`` and slipping at (``vs``, ``vlat``).

    F = -mu(|v|) N v / max(|v|, v_eps): it opposes the slip, its magnitude is mu(|v|) N while
    the node slides (|v| >= v_eps) and falls linearly to zero below the slip velocity, in every
    direction alike; mu(|v|) is :func:`friction_coefficient` (``mu`` unless ``mu_s`` > ``mu``).
    ``vs`` is the velocity along the leg's plane, ``vlat`` across it. Returns (F_s, F_lat).
    """
    speed = np.sqrt(vs * vs + vlat * vlat)
    scale = friction_coefficient(speed, mu, mu_s, v_s) * nrm / max(speed, v_eps)
    return -scale * vs, -scale * vlat


@njit(cache=True, allocates=False)
def friction_slope(v, v_other, nrm, mu, v_eps, mu_s, v_s):
    """The slope the linearly implicit steps give :func:`coulomb_friction` along ``v`` (``v_other`` the
    slip's other component): its secant mu N / max(|v|, v_eps), alike in every direction.

    Below the slip velocity this is the law's own slope. While the node slides it is the
    friction's size over the slip's, so the step takes F(v') = -mu N v' / |v|: exact while the
    slip holds, and a friction that can stop a slip within a step but never reverse it. The
    tangent (zero along a straight slip) would leave the friction explicit along the slip,
    and a light node sliding at less than h mu N / m would be thrown back and forth each step.
    With a static coefficient (``mu_s`` > ``mu``) it is the secant of mu(|v|) N, as large as
    mu_s N / v_eps at rest.
    """
    speed = np.sqrt(v * v + v_other * v_other)
    return friction_coefficient(speed, mu, mu_s, v_s) * nrm / max(speed, v_eps)


@njit(cache=True, allocates=False)
def friction_tangent(v, v_other, nrm, mu, v_eps, mu_s, v_s):
    """dF/dv of :func:`coulomb_friction`'s component along ``v`` (``v_other`` the slip's other component, held):
    the law's own slope, which :mod:`slotexp.soft.friction`'s Newton iteration takes.

    With s = |(v, v_other)|, m = max(s, v_eps) and F = -mu(s) N v / m: below the slip velocity
    -mu(s) N / m - mu'(s) N v^2 / (s m); sliding, -mu(s) N v_other^2 / s^3 - mu'(s) N v^2 / (s m), zero
    along a straight slip of plain Coulomb friction. The Stribeck fall of a static coefficient
    (mu' < 0) can make it positive: the law is then not monotone.
    """
    speed = np.sqrt(v * v + v_other * v_other)
    slope_over_s = 0.0  # mu'(s) / s
    if mu_s > mu:
        slope_over_s = -2.0 * (mu_s - mu) * np.exp(-(speed / v_s) * (speed / v_s)) / (v_s * v_s)
    mu_now = friction_coefficient(speed, mu, mu_s, v_s)
    if speed < v_eps:
        return -nrm * (mu_now + slope_over_s * v * v) / v_eps
    return -nrm * (mu_now * v_other * v_other / (speed * speed) + slope_over_s * v * v) / speed


@njit(cache=True, allocates=False)
def friction_level(slope, nrm, mu, v_eps):
    """The Jacobian level of a sliding node's friction slope: 0 for the sticking slope mu N / v_eps, k for
    slopes in (4^-(k+1), 4^-k] of it, -1 below the last level (the slope is left out). ``mu`` is the
    largest coefficient (the static one where it is larger)."""
    top = mu * nrm / v_eps
    level = 0
    bound = top
    while level < FRICTION_LEVELS:
        if slope > 0.25 * bound:
            return level
        bound *= 0.25
        level += 1
    return -1


@njit(cache=True, allocates=False)
def contact_proximal(vx, vz, vel_z, force_z, depth, hm, hc, damp, vrig_z, vlat, k_c, d_c, mu, v_eps):
    """Contact and friction of one node below the ground in the symplectic step, both implicit.

    (``vx``, ``vz``) is the node's new velocity without contact, ``vel_z`` its old
    vertical velocity, ``force_z`` the vertical force on it, ``hm`` = h / m,
    ``hc`` = h c, ``damp`` = 1 / (1 + h c), ``vrig_z`` the vertical velocity the damping
    pulls it towards, ``vlat`` its velocity across the leg's plane (the torso's, held over
    the step). The normal force uses the new vertical velocity (implicit contact damping);
    the friction is :func:`coulomb_friction`'s isotropic law solved as a proximal step on the
    slip (vx, vlat): v + beta v / max(|v|, v_eps) = v_free, beta = h mu N / m, which keeps the
    slip's direction and shortens it. Returns the new velocity, the normal force and the
    friction force along the plane (0, 0 when the node is not pressed).
    """
    vz_c = (vel_z + hm * (force_z + k_c * depth) + hc * vrig_z) / (1.0 + hc + hm * d_c)
    nrm = k_c * depth - d_c * vz_c
    if nrm > 0.0:
        beta = hm * mu * nrm * damp
        free = np.sqrt(vx * vx + vlat * vlat)
        if free <= v_eps + beta:
            vx = vx / (1.0 + beta / v_eps)
        else:
            vx = vx * (1.0 - beta / free)
        fric, _ = coulomb_friction(vx, vlat, nrm, mu, v_eps, mu, 1.0)  # plain Coulomb (config.validate)
        return vx, vz_c, nrm, fric
    return vx, vz, 0.0, 0.0


@njit(cache=True, allocates=False)
def contact_force(depth, vx, vz, vlat, k_c, d_c, mu, v_eps, mu_s, v_s):
    """Contact and friction of a node ``depth`` below the ground, for the implicit step.

    N = k depth - d vz and (F_x, F_lat) = :func:`coulomb_friction` at the slip (vx, ``vlat``).
    Returns (N, F_x, g, regime) with g = F_x / (-mu_top N), mu_top the largest coefficient
    (``max(mu, mu_s)``; how much of the friction acts along the plane) and the regime that fixes
    the Jacobian's structure: 0 not pressed (N, F_x = 0), 1 sticking (|v| < v_eps: a stiff
    viscous law), 4 + 2 k (+ 1 backwards) sliding with its secant slope (:func:`friction_slope`)
    at level k (:func:`friction_level`), 2 or 3 sliding forwards or backwards so fast that the
    slope is left out. The implicit step refactors its Jacobian when a node's regime changes.
    """
    nrm = k_c * depth - d_c * vz
    if nrm <= 0.0:
        return 0.0, 0.0, 0.0, 0
    fx, _ = coulomb_friction(vx, vlat, nrm, mu, v_eps, mu_s, v_s)
    top = max(mu, mu_s)
    g = -fx / (top * nrm) if top > 0.0 else 0.0
    if vx * vx + vlat * vlat < v_eps * v_eps:
        return nrm, fx, g, 1
    back = 1 if vx < 0.0 else 0
    level = friction_level(friction_slope(vx, vlat, nrm, mu, v_eps, mu_s, v_s), nrm, top, v_eps) if top > 0.0 else -1
    if level < 0:
        return nrm, fx, g, 2 + back
    return nrm, fx, g, 4 + 2 * level + back


@njit(cache=True, allocates=False)
def contact_jacobian(i, nrm, g, regime, h, k_c, d_c, mu, v_eps, kband, band):
    """Node ``i``'s contact and friction Jacobians for the implicit step (:func:`contact_force`'s law):
    h^2 (-dF/dx) into ``kband`` and h (-dF/dv) into ``band``, in the step's banded layout. ``mu`` is
    the largest coefficient, the one ``g`` is a share of (:func:`contact_force`).

    The friction's slope along the plane is the largest its regime stands for (mu N / v_eps
    sticking, the level's bound sliding), so the factored matrix damps at least as much as
    the friction's secant."""
    if regime == 0:
        return
    h2 = h * h
    dz = 3 * i + 1
    dx = 3 * i
    kband[dz, 4] += h2 * k_c  # dN/dz = -k
    band[dz, 4] += h * d_c  # dN/dvz = -d
    if regime == 1:
        band[dx, 4] += h * mu * nrm / v_eps  # dF_x/dvx on the sticking branch
    elif regime >= 4:
        level = (regime - 4) // 2
        band[dx, 4] += h * mu * nrm / v_eps * 0.25**level
    # through N: dF_x/dz = mu k g, dF_x/dvz = mu d g
    kband[dx, 5] -= h2 * mu * k_c * g
    band[dx, 5] -= h * mu * d_c * g
