"""Time stepping of one leg: root boundary, two integrators, and the leg as an object (numba).

The root (node 0 and element 0) follows prescribed kinematics ``root`` =
[s, z, vs, vz, theta, omega], held over a step; the force and moment the leg
exerts on it are returned in ``out`` as the reaction on the torso. Two schemes
advance the rod under its elasticity (:mod:`slotexp.soft.rod`) and loads
(:mod:`slotexp.soft.loads`):

- symplectic (semi-implicit) Euler: v' = v + h M^-1 F(x), x' = x + h v', with the
  damping, contact damping and friction implicit; cheap per step but bounded by
  the rod's stiffest mode, h < 2 / omega_max (:func:`stable_dt`);
- linearly implicit Euler: (M - h^2 K - h C) dv = h F - h^2 K v with K and C the
  Jacobians of every load, solved by a banded LU (the tendon's rank-one term by
  Sherman-Morrison); stable at steps set by accuracy, not by the stiffest mode. The
  factored Jacobian may serve several steps (``jacobian_age``, a W-method): F is
  always current, and a change of contact, friction regime or tendon state, which
  would change the stiff modes, refactors it at once. Factoring is most of an exact
  step's cost; a reused factorisation leaves the forces, one product and one solve.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import ConfigError, DivergenceError
from ..jit import njit
from .friction import friction_dissipative, friction_work, solve_friction
from .loads import (
    conservative_forces,
    contact_force,
    contact_jacobian,
    contact_proximal,
    coulomb_friction,
    damping_reaction,
    dissipative_params,
    friction_slope,
    root_frame_velocity,
    root_reaction,
    tendon_jacobian,
    tendon_length,
)
from .params import (
    O_DIV,
    O_F,
    O_FX,
    O_FZ,
    O_M,
    O_N,
    O_T,
    O_TS,
    OUT,
    P_C,
    P_FSOLVE,
    P_G,
    P_GROUND,
    P_JTURN,
    P_K,
    P_PAPER,
    P_TFX,
    P_TFZ,
    P_TK,
    P_TM,
    P_TMAX,
    P_TPAIR,
)
from .rod import (
    LegModel,
    banded_factor,
    banded_multiply_subtract,
    banded_substitute,
    directors,
    elastic_energy,
    elastic_hessian_band,
    elastic_hessian_cs,
)

# The implicit step's Jacobian bookkeeping ``jmeta`` (:func:`jacobian_state`): each node's contact regime (N
# entries), then these, counted from N: the cable's state, the factorisation's age in steps, 1 + g^T W^-1 u,
# the step it was made with, how many factorisations the leg has made, the pulling cable's offset at the factoring,
# how many of its friction solves (plant.friction=solved) stopped unconverged (slotexp.soft.friction), and whether
# the factorisation's compliance at its pressed nodes is dissipative (friction_dissipative; 1 if so), and the
# elements' largest turn (rad) summed over the steps since the factorisation (plant.jacobian_turn refactors past it).
J_CABLE, J_AGE, J_GZ, J_STEP, J_COUNT, J_OFFSET, J_UNSOLVED, J_DISSIPATIVE, J_TURN = range(9)
# m: a Newton correction that moves no position by more than this ends the step's iterations (implicit_step)
NEWTON_TOL = 1e-7
TANGENT_PASSES = 4  # Newton corrections that linearise the friction by its tangent; later ones by its secant
MAX_HALVINGS = 6  # a step whose Newton corrections do not converge is retaken as up to 2^6 shorter ones


@njit(cache=True, allocates=False)
def _set_root(pos, vel, root):
    pos[0, 0] = root[0]
    pos[0, 1] = root[1]
    vel[0, 0] = root[2]
    vel[0, 1] = root[3]


@njit(cache=True, allocates=False)
def _finish_step(pos, tension, pair_upper, total_n, total_f, out):
    """Report the step's tension (and which cable pulls) and contact totals; flag a blown-up state
    (non-finite, or the tip 100 m away) so the caller can stop with the step and the stability limit named."""
    out[O_T] = tension
    out[O_TS] = 0.0 if tension <= 0.0 else (-1.0 if pair_upper else 1.0)
    out[O_N] = total_n
    out[O_F] = total_f
    tip = pos[pos.shape[0] - 1]
    if not (np.isfinite(tip[0]) and np.isfinite(tip[1]) and abs(tip[0]) < 100.0 and abs(tip[1]) < 100.0):
        out[O_DIV] = 1.0


@njit(cache=True, allocates=False)
def _normal_force(pos, vel, i, ground, k_c, d_c):
    """Node ``i``'s contact normal force, k depth - d v_z, or 0 above the ground or pulling."""
    if not ground or pos[i, 1] >= 0.0:
        return 0.0
    return max(0.0, -k_c * pos[i, 1] - d_c * vel[i, 1])


@njit(cache=True, allocates=False)
def _normal_rows(i, h, k_c, d_c, kband, band):
    """A pressed node's normal force in the step's matrix: h^2 k_c into ``kband``, h d_c into ``band``."""
    kband[3 * i + 1, 4] += h * h * k_c
    band[3 * i + 1, 4] += h * d_c


@njit(cache=True, allocates=False)
def _friction_newton_slope(vs, vlat, nrm, mu, v_eps, mu_s, v_s, tangent):
    """The slope along the plane of :func:`coulomb_friction` that a Newton correction uses: its tangent
    (``tangent``; quadratic convergence where the node stays sliding or sticking) or its secant (a
    majorise-minimise step on the friction's convex dissipation: slower, but it cannot cycle between
    sticking and sliding). Sliding, the tangent is mu N v_lat^2 / |v|^3 (zero along a straight slip);
    with a static coefficient it is the secant always."""
    speed = np.sqrt(vs * vs + vlat * vlat)
    if not tangent or speed < v_eps or mu_s > mu:
        return friction_slope(vs, vlat, nrm, mu, v_eps, mu_s, v_s)
    return mu * nrm * vlat * vlat / (speed * speed * speed)


@njit(cache=True, allocates=False)
def _solve_w(lu, jvec, gz, taut, b):
    """``b`` := W^-1 ``b``: the factored band, then (the cable taut) its rank-one term by Sherman-Morrison, with
    ``jvec`` = (W^-1 u, grad L) and ``gz`` = 1 + g^T W^-1 u as the factorisation kept them."""
    banded_substitute(lu, b)
    if taut:
        smu, g = jvec[0], jvec[1]
        gy = 0.0
        for d in range(b.shape[0]):
            gy += g[d] * b[d]
        ratio = gy / gz
        for d in range(b.shape[0]):
            b[d] -= ratio * smu[d]


@njit(cache=True, allocates=False)
def _root_rows(kband, x):
    """The root node's two rows of the band ``kband`` (h^2 K) times ``x``: what moving the nodes by h x changes
    in the force on the root (its reaction, times -h)."""
    d0 = 0.0
    d1 = 0.0
    for k in range(4, 9):
        d0 += kband[0, k] * x[k - 4]
    for k in range(3, 9):
        d1 += kband[1, k] * x[k - 3]
    return d0, d1


class LegState(NamedTuple):
    """One leg's dynamic state: node positions and velocities (N, 2), element angles and rates (E,)."""

    pos: np.ndarray
    vel: np.ndarray
    theta: np.ndarray
    omega: np.ndarray


class StepWork(NamedTuple):
    """One leg's scratch for a step: node forces (N, 2), element moments (E,), the implicit step's two
    vectors (3N - 1), and the directors cos/sin theta (E,), which the symplectic step keeps current."""

    force: np.ndarray
    moment: np.ndarray
    rhs: np.ndarray
    vflat: np.ndarray
    cth: np.ndarray
    sth: np.ndarray


class JacobianState(NamedTuple):
    """The implicit step's factored Jacobian, kept between steps (:func:`implicit_once`): the banded LU of
    W, h^2 K, the tendon's W^-1 u and grad L then (``plant.friction=solved``) each pressed node i's column
    W^-1 e_x,i in row 2 + i, the regimes and counters (``J_*``), and the friction solve's scratch
    (:func:`slotexp.soft.friction.friction_work`)."""

    lu: np.ndarray
    kband: np.ndarray
    jvec: np.ndarray
    jmeta: np.ndarray
    fwork: np.ndarray


def step_work(n_nodes: int, legs: int | None = None) -> StepWork:
    """Zeroed scratch for one leg's step (or ``legs`` legs', stacked)."""
    lead = () if legs is None else (legs,)
    nd = 3 * n_nodes - 1
    return StepWork(
        np.zeros(lead + (n_nodes, 2)),
        np.zeros(lead + (n_nodes - 1,)),
        np.zeros(lead + (nd,)),
        np.zeros(lead + (nd,)),
        np.zeros(lead + (n_nodes - 1,)),
        np.zeros(lead + (n_nodes - 1,)),
    )


@njit(cache=True, allocates=False)
def rotate_directors(cth, sth, theta, omega, h):
    """theta += h omega, and turn the directors by the same angle without trig calls.

    Taylor series to delta^7 are exact to round-off for |delta| < 0.05 rad per step
    (far beyond any stable step); larger turns fall back to cos/sin.
    """
    for e in range(theta.shape[0]):
        d = h * omega[e]
        theta[e] += d
        if abs(d) < 0.05:
            d2 = d * d
            cd = 1.0 - d2 * (0.5 - d2 * (1.0 / 24.0 - d2 / 720.0))
            sd = d * (1.0 - d2 * (1.0 / 6.0 - d2 * (1.0 / 120.0 - d2 / 5040.0)))
            c = cth[e]
            cth[e] = c * cd - sth[e] * sd
            sth[e] = sth[e] * cd + c * sd
        else:
            cth[e] = np.cos(theta[e])
            sth[e] = np.sin(theta[e])


def _inline_in_the_leg_loop(expr, caller_ir, callee_ir) -> bool:
    """numba's inline cost model for :func:`symplectic_once`: inlined into :func:`step_symplectic` (as a call,
    its grouped arguments cost the 1 us leg step 11 %), a call from the coupled kernel (inlined there, the
    kernel grew and the robot's implicit step slowed 2-3 %)."""
    return caller_ir.func_id.func_name == "step_symplectic"


@njit(cache=True, inline=_inline_in_the_leg_loop, allocates=False)
def symplectic_once(state, leg, inv_mass, inv_inertia, par, free_length, root, vlat, h, normal, out, work):
    """One symplectic (semi-implicit) Euler step with implicit damping, contact and friction.

    ``root`` = [s, z, vs, vz, theta, omega] of the root over the step; ``free_length``
    is the tendon's L_free over the step (state, not in ``par``: the servo changes it);
    ``vlat`` (N,) each node's velocity across the leg's plane, which its friction sees
    (the torso's motion there; zeros for a clamped leg).
    ``state`` is the leg's :class:`LegState`, ``leg`` its :class:`~slotexp.soft.rod.LegModel`,
    ``inv_mass``/``inv_inertia`` its reciprocal node masses and element inertias. ``work.cth``/``sth``
    must hold the current directors (kept current here). ``normal`` (N,) receives each node's contact
    normal force; the rest of ``work`` is scratch.
    """
    pos, vel, theta, omega = state
    rest_pos, _, l0, voronoi, dtheta0, ea, ga, ei, mass, inertia = leg
    force, moment, _, _, cth, sth = work
    n = pos.shape[0]
    n_el = theta.shape[0]
    c, k_c, d_c, mu, v_eps, ground, _, _ = dissipative_params(par)  # plain Coulomb here (config.validate)
    _set_root(pos, vel, root)
    tension, m_root, offset = conservative_forces(
        pos,
        theta,
        root[4],
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
        False,
    )
    root_reaction(force, m_root, mass, par, out)
    damp = 1.0 / (1.0 + h * c)
    hc = h * c
    total_n = 0.0
    total_f = 0.0
    rx = 0.0
    rz = 0.0
    rm = 0.0
    for i in range(1, n):
        hm = h * inv_mass[i]
        gx, gz = root_frame_velocity(pos, i, root)  # damped towards the root frame's rigid motion
        vx = (vel[i, 0] + hm * force[i, 0] + hc * gx) * damp
        vz = (vel[i, 1] + hm * force[i, 1] + hc * gz) * damp
        nrm = 0.0
        if ground and pos[i, 1] < 0.0:
            vx, vz, nrm, fric = contact_proximal(
                vx, vz, vel[i, 1], force[i, 1], -pos[i, 1], hm, hc, damp, gz, vlat[i], k_c, d_c, mu, v_eps
            )
            total_f += fric
        normal[i] = nrm
        total_n += nrm
        vel[i, 0] = vx
        vel[i, 1] = vz
        px = mass[i] * (vx - gx)
        pz = mass[i] * (vz - gz)
        rx += px
        rz += pz
        rm += (pos[i, 0] - pos[0, 0]) * pz - (pos[i, 1] - pos[0, 1]) * px
        pos[i, 0] += h * vx
        pos[i, 1] += h * vz
    for e in range(n_el):
        w = (omega[e] + h * inv_inertia[e] * moment[e] + hc * root[5]) * damp
        omega[e] = w
        rm += inertia[e] * (w - root[5])
    # the damping acts between leg and torso: its reaction (force, moment about the root) goes to the root
    out[O_FX] += c * rx
    out[O_FZ] += c * rz
    out[O_M] += c * rm
    rotate_directors(cth, sth, theta, omega, h)
    _finish_step(pos, tension, offset < 0.0 and par[P_TPAIR] > 0.0, total_n, total_f, out)


@njit(cache=True)
def step_symplectic(state, leg, par, free_length, root, h, n_steps, normal, out):
    """``n_steps`` of :func:`symplectic_once` with the root held (nothing slips across the plane)."""
    pos, _, theta, _ = state
    vlat = np.zeros(pos.shape[0])
    work = StepWork(
        np.zeros(pos.shape), np.zeros(theta.shape[0]), np.zeros(0), np.zeros(0),
        np.zeros(theta.shape[0]), np.zeros(theta.shape[0]),
    )  # fmt: skip
    directors(theta, work.cth, work.sth)
    inv_mass = 1.0 / leg.mass
    inv_inertia = 1.0 / leg.inertia
    for _ in range(n_steps):
        symplectic_once(state, leg, inv_mass, inv_inertia, par, free_length, root, vlat, h, normal, out, work)
        if out[O_DIV] > 0.0:
            return
    _set_root(pos, state.vel, root)


@njit(cache=True, allocates=False)
def implicit_once(state, leg, par, free_length, root, vlat, h, normal, out, work, jac, max_age, correction, vstart):
    """One linearly implicit Euler step, W (M - h^2 K - h C) dv = h F(x, v) - h^2 K v, v' = v + dv.

    Arguments as :func:`symplectic_once` (``work.cth``/``sth`` are set from theta here: one libm
    ``sincos`` an element, not vectorised without SVML, about a tenth of the plant's time under
    ``perf``; turning them instead would change the bits); ``jac`` is the :class:`JacobianState`.
    K and C are the Jacobians of every load (elasticity, tendon, contact, friction, damping); the tendon adds a
    rank-one term to K, handled by Sherman-Morrison around the banded solve. The root
    node's rows are rows of the identity (its velocity is prescribed). ``work.rhs`` and
    ``work.vflat`` are scratch (3N - 1).

    The factored W and h^2 K are the leg's own state: ``lu``, ``kband``; ``jvec`` = the
    tendon's W^-1 u and grad L; ``jmeta`` = each node's contact regime, then the entries
    ``J_*`` (the cable's state: slack, taut or at the stall; the age; 1 + g^T W^-1 u; the
    step; the count of factorisations; the largest element turn summed over the steps since, J_TURN). They are
    refreshed when the step changes, a node's contact regime or the cable's state changes, they are ``max_age``
    steps old, or (``par[P_JTURN]`` > 0, ``plant.jacobian_turn``) an element may have turned more than that many
    radians since they were made: the rod's stiffness turns with its elements.
    ``max_age`` = 1 is the exact linearly implicit Euler step; with larger ages the
    Jacobians are those of up to ``max_age`` - 1 steps earlier (a W-method: still
    consistent, since F is always current; the structural changes that would make it
    unstable refresh them at once).

    With ``par[P_FSOLVE]`` (``plant.friction=solved``) W leaves out the friction along the plane: the pressed
    nodes' friction is solved at the step's end through W's columns at them, kept with the factorisation
    (:mod:`slotexp.soft.friction`), and a node's regime is only whether it is pressed. Without it the friction
    enters at its value at the step's start and its secant slope (:func:`slotexp.soft.loads.friction_slope`).

    With ``correction`` the pass is a Newton correction of a step already taken (:func:`implicit_step`):
    the state is the step's end (x_k = x_0 + h v_k, ``root`` the root at the step's end), ``vstart`` (3N - 1)
    the velocities at the step's start, and the pass solves W delta = h F(x_k, v_k) - M (v_k - v_0) for
    the backward Euler step's residual, moving velocities by delta and positions by h delta. The reaction
    on the root is the same linearisation about x_k, so momentum is exchanged exactly at every pass.
    Returns the largest velocity change of the pass (m/s or rad/s).
    """
    pos, vel, theta, omega = state
    rest_pos, _, l0, voronoi, dtheta0, ea, ga, ei, mass, inertia = leg
    force, moment, rhs, vflat, cth, sth = work
    lu, kband, jvec, jmeta, fwork = jac
    n = pos.shape[0]
    n_el = theta.shape[0]
    nd = 3 * n - 1
    c, k_c, d_c, mu, v_eps, ground, mu_s, v_s = dissipative_params(par)
    mu_top = max(mu, mu_s)
    solved = par[P_FSOLVE] > 0.5  # the friction along the plane solved at the step's end (slotexp.soft.friction)
    h2 = h * h
    _set_root(pos, vel, root)
    tension, m_root, offset = conservative_forces(
        pos,
        theta,
        root[4],
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
        True,
    )
    root_reaction(force, m_root, mass, par, out)
    taut = tension > 0.0 and tension < par[P_TMAX]
    cable = 0.0 if tension <= 0.0 else (1.0 if taut else 2.0)  # slack, taut, at the servo's stall
    if offset < 0.0 and par[P_TPAIR] > 0.0:
        cable = -cable  # the pair's upper cable
    i_cable, i_age, i_gz, i_step = n + J_CABLE, n + J_AGE, n + J_GZ, n + J_STEP
    fresh = jmeta[i_age] >= max_age or jmeta[i_step] != h or jmeta[i_cable] != cable
    if par[P_JTURN] > 0.0 and jmeta[n + J_TURN] > par[P_JTURN]:
        fresh = True  # the elements turned too far since the Jacobians were made
    # the velocity-dependent forces at the start of the step: damping towards the root frame's rigid motion, contact
    for i in range(n):
        gx, gz = root_frame_velocity(pos, i, root)
        rhs[3 * i] = h * (force[i, 0] + c * mass[i] * (gx - vel[i, 0]))
        rhs[3 * i + 1] = h * (force[i, 1] + c * mass[i] * (gz - vel[i, 1]))
        vflat[3 * i] = vel[i, 0]
        vflat[3 * i + 1] = vel[i, 1]
    for e in range(n_el):
        d = 3 * e + 2
        rhs[d] = h * (moment[e] + c * inertia[e] * (root[5] - omega[e]))
        vflat[d] = omega[e]
    if correction:  # the backward Euler residual's inertia: - M (v_k - v_0)
        for i in range(1, n):
            rhs[3 * i] -= mass[i] * (vflat[3 * i] - vstart[3 * i])
            rhs[3 * i + 1] -= mass[i] * (vflat[3 * i + 1] - vstart[3 * i + 1])
        for e in range(n_el):
            rhs[3 * e + 2] -= inertia[e] * (vflat[3 * e + 2] - vstart[3 * e + 2])
    total_n = 0.0
    total_f = 0.0
    for i in range(1, n):
        if correction:
            # the normal force at x_k; the friction's at the step's start (``normal``, kept), as in the first pass
            nrm = _normal_force(pos, vel, i, ground, k_c, d_c)
            fx = 0.0
            if normal[i] > 0.0:
                fx, _ = coulomb_friction(vel[i, 0], vlat[i], normal[i], mu, v_eps, mu_s, v_s)
            rhs[3 * i] += h * fx
            rhs[3 * i + 1] += h * nrm
            total_n += nrm
            total_f += fx
            continue
        nrm, fx, regime = 0.0, 0.0, 0
        if ground and pos[i, 1] < 0.0:
            if solved:  # only whether the node is pressed: its friction is solved at the step's end (below)
                nrm = _normal_force(pos, vel, i, ground, k_c, d_c)
                regime = 1 if nrm > 0.0 else 0
            else:
                nrm, fx, _, regime = contact_force(
                    -pos[i, 1], vel[i, 0], vel[i, 1], vlat[i], k_c, d_c, mu, v_eps, mu_s, v_s
                )
                rhs[3 * i] += h * fx
            rhs[3 * i + 1] += h * nrm
        normal[i] = nrm
        total_n += nrm
        total_f += fx
        if regime != jmeta[i]:
            fresh = True
    if correction:
        fresh = True  # a Newton correction linearises at x_k, v_k
    g = jvec[1]
    smu = jvec[0]
    if fresh:
        # h^2 K (elastic, tendon band part, contact) into kband; W = M (1 + h c) + kband + h C into lu
        kband[:, :] = 0.0
        lu[:, :] = 0.0
        elastic_hessian_cs(pos, theta, cth, sth, l0, voronoi, ea, ga, ei, kband, h2)
        g[:] = 0.0
        if tension > 0.0:
            tendon_jacobian(pos, cth, sth, root[4], tension, offset, par, h2, kband, g)
        for i in range(1, n):
            if correction:
                # Newton on the normal force; on the friction (its normal force held) the secant at v_k, whose
                # iteration is a majorise-minimise one on the friction's convex dissipation: it cannot cycle
                if _normal_force(pos, vel, i, ground, k_c, d_c) > 0.0:
                    _normal_rows(i, h, k_c, d_c, kband, lu)
                if normal[i] > 0.0:
                    lu[3 * i, 4] += h * _friction_newton_slope(
                        vel[i, 0], vlat[i], normal[i], mu, v_eps, mu_s, v_s, correction <= TANGENT_PASSES
                    )
                jmeta[i] = -1.0  # the next step's first pass factors afresh
                continue
            regime = 0
            if solved:
                if _normal_force(pos, vel, i, ground, k_c, d_c) > 0.0:
                    _normal_rows(i, h, k_c, d_c, kband, lu)
                    regime = 1
            elif ground and pos[i, 1] < 0.0:
                nrm, _, g_x, regime = contact_force(
                    -pos[i, 1], vel[i, 0], vel[i, 1], vlat[i], k_c, d_c, mu, v_eps, mu_s, v_s
                )
                contact_jacobian(i, nrm, g_x, regime, h, k_c, d_c, mu_top, v_eps, kband, lu)
            jmeta[i] = regime
        lu += kband
        for i in range(n):
            lu[3 * i, 4] += mass[i] * (1.0 + h * c)
            lu[3 * i + 1, 4] += mass[i] * (1.0 + h * c)
        for e in range(n_el):
            lu[3 * e + 2, 4] += inertia[e] * (1.0 + h * c)
        # prescribed root node: identity rows
        for d in range(2):
            for k in range(9):
                lu[d, k] = 0.0
            lu[d, 4] = 1.0
        banded_factor(lu)
        if taut:
            # Sherman-Morrison for the rank-one part h^2 k_t g g^T on the free rows: W^-1 u, u = h^2 k_t g
            smu[0] = 0.0
            smu[1] = 0.0
            for d in range(2, nd):
                smu[d] = h2 * par[P_TK] * g[d]
            banded_substitute(lu, smu)
            gz = 1.0
            for d in range(nd):
                gz += g[d] * smu[d]
            jmeta[i_gz] = gz
        if solved:  # each pressed node's column of W^-1 at its along-plane velocity, for the friction solve
            for i in range(1, n):
                if jmeta[i] == 1.0:
                    col = jvec[2 + i]
                    for d in range(nd):
                        col[d] = 0.0
                    col[3 * i] = 1.0
                    _solve_w(lu, jvec, jmeta[i_gz], taut, col)
            jmeta[n + J_DISSIPATIVE] = 1.0 if friction_dissipative(jvec, jmeta, fwork) else 0.0
        jmeta[i_cable] = cable
        jmeta[i_step] = h
        jmeta[i_age] = 0.0
        jmeta[n + J_TURN] = 0.0
        jmeta[n + J_COUNT] += 1.0
        jmeta[n + J_OFFSET] = offset
    jmeta[i_age] += 1.0
    if not correction:
        # - h^2 K v, with the K the factorisation was made with
        banded_multiply_subtract(kband, vflat, rhs)
        # the clamp angle moves at root[5] over the step: its spring acts on theta_0
        rhs[2] += h2 * ei[0] / voronoi[0] * root[5]
    if taut and not correction:
        gv = 0.0
        for d in range(nd):
            gv += g[d] * vflat[d]
        # the tendon's rank-one stiffness, and its tension's change as the root angle turns over the step
        coef = h2 * par[P_TK] * (offset * root[5] - gv)
        for d in range(2, nd):
            rhs[d] += coef * g[d]
    rhs[0] = 0.0
    rhs[1] = 0.0
    _solve_w(lu, jvec, jmeta[i_gz], taut, rhs)
    if solved and not correction:
        total_f, _, converged = solve_friction(jvec, jmeta, vflat, rhs, normal, vlat, h, mu, v_eps, mu_s, v_s, fwork)
        if not converged:
            jmeta[n + J_UNSOLVED] += 1.0
        if jmeta[n + J_DISSIPATIVE] == 0.0:  # W indefinite at the feet: a step too large, taken as a blow-up
            out[O_DIV] = 1.0
    change = 0.0
    for d in range(2, nd):
        vflat[d] += rhs[d]
        change = max(change, abs(rhs[d]))
    # what moved the positions over the step: the new velocity, or (a correction) its change
    x = rhs if correction else vflat
    for i in range(n):
        vel[i, 0] = vflat[3 * i]
        vel[i, 1] = vflat[3 * i + 1]
    for e in range(n_el):
        omega[e] = vflat[3 * e + 2]
    damp_x, damp_z, damp_m = damping_reaction(pos, vel, omega, mass, inertia, par, root)  # where it was applied
    for i in range(n):
        pos[i, 0] += h * x[3 * i]
        pos[i, 1] += h * x[3 * i + 1]
    turn = 0.0
    for e in range(n_el):
        theta[e] += h * x[3 * e + 2]
        turn = max(turn, abs(h * x[3 * e + 2]))
    jmeta[n + J_TURN] += turn
    # reaction on the root, consistent with the implicit step (momentum is exchanged exactly): the root
    # rows of h^2 (elastic + tendon) K
    d0, d1 = _root_rows(kband, x)
    out[O_FX] -= d0 / h
    out[O_FZ] -= d1 / h
    tension_end = tension
    if taut:
        gx = 0.0
        for d in range(nd):
            gx += g[d] * x[d]
        # the tension's change over the step, as the nodes move and the root angle turns (the same change the
        # nodes felt through the rank-one term): the root's share of it
        stretch_rate = gx if correction else gx - offset * root[5]
        out[O_FX] -= h * par[P_TK] * g[0] * stretch_rate
        out[O_FZ] -= h * par[P_TK] * g[1] * stretch_rate
        tension_end = tension + par[P_TK] * h * stretch_rate
    k0 = ei[0] / voronoi[0]
    out[O_M] = k0 * (theta[0] - root[4] - (0.0 if correction else h * root[5]))
    if tension > 0.0:
        out[O_M] += tension_end * offset
    out[O_FX] += damp_x
    out[O_FZ] += damp_z
    out[O_M] += damp_m
    _finish_step(pos, tension, offset < 0.0 and par[P_TPAIR] > 0.0, total_n, total_f, out)
    return change


@njit(cache=True, allocates=False)
def _save(state, saved):
    """The state's velocities into ``saved[0]`` and positions into ``saved[1]``, in the step's layout (3N - 1)."""
    pos, vel, theta, omega = state
    for i in range(pos.shape[0]):
        saved[0, 3 * i] = vel[i, 0]
        saved[0, 3 * i + 1] = vel[i, 1]
        saved[1, 3 * i] = pos[i, 0]
        saved[1, 3 * i + 1] = pos[i, 1]
    for e in range(theta.shape[0]):
        saved[0, 3 * e + 2] = omega[e]
        saved[1, 3 * e + 2] = theta[e]


@njit(cache=True, allocates=False)
def _restore(state, saved):
    """The state :func:`_save` kept in ``saved``."""
    pos, vel, theta, omega = state
    for i in range(pos.shape[0]):
        vel[i, 0] = saved[0, 3 * i]
        vel[i, 1] = saved[0, 3 * i + 1]
        pos[i, 0] = saved[1, 3 * i]
        pos[i, 1] = saved[1, 3 * i + 1]
    for e in range(theta.shape[0]):
        omega[e] = saved[0, 3 * e + 2]
        theta[e] = saved[1, 3 * e + 2]


@njit(cache=True, allocates=False)
def _newton_step(state, leg, par, free_length, root, vlat, h, normal, out, work, jac, max_age, newton, saved, end):
    """One backward Euler step of ``h`` from ``root``: the linearly implicit pass and up to ``newton`` - 1
    corrections. Returns whether the corrections converged (a correction moved no position by more than
    ``NEWTON_TOL``)."""
    _save(state, saved)
    implicit_once(state, leg, par, free_length, root, vlat, h, normal, out, work, jac, max_age, 0, saved[0])
    for k in range(6):  # the root at the step's end: where the corrections evaluate the loads
        end[k] = root[k]
    end[0] += h * root[2]
    end[1] += h * root[3]
    end[4] += h * root[5]
    for k in range(1, newton):
        if out[O_DIV] > 0.0:
            return False
        change = implicit_once(state, leg, par, free_length, end, vlat, h, normal, out, work, jac, max_age, k, saved[0])
        if h * change <= NEWTON_TOL:
            return out[O_DIV] == 0.0
    return False


@njit(cache=True, allocates=False)
def implicit_step(state, leg, par, free_length, root, vlat, h, normal, out, work, jac, max_age, newton, saved, roots):
    """One implicit Euler step of ``h`` with the root moving as ``root`` says.

    ``newton`` = 1: the linearly implicit step (:func:`implicit_once`). More: backward Euler, solved by the
    linearly implicit pass and up to ``newton`` - 1 Newton corrections; where they do not converge (a foot
    landing, a cable snapping taut), the step is taken again as 2, 4, ... steps, the root moving on between
    them, and the reaction on the root is their mean (the same impulse); the last resort is 2^``MAX_HALVINGS``
    linearly implicit steps.

    Why: the linearly implicit step linearises contact, friction and the cable once, at the step's start,
    and a switch within the step (a node landing, a foot sticking, a cable going slack) it sees only a step
    late: at millisecond steps the overshoot grew from step to step (the loaded leg diverged at 1.5 ms).
    Backward Euler itself is stable there; the corrections solve it, and the halving keeps a switch the
    corrections cannot resolve from spoiling the step. ``saved`` (4, 3N - 1) and ``roots`` (3, 6: a shorter
    step's root, the step's end, the reactions' sums) are scratch. Returns the number of steps taken (1 unless
    halved).
    """
    if newton <= 1:
        implicit_once(state, leg, par, free_length, root, vlat, h, normal, out, work, jac, max_age, 0, saved[0])
        return 1
    start = saved[2:4]  # the step's start, kept while a halving retakes it (saved[0:2] serve each step)
    sub_root, end, sums = roots[0], roots[1], roots[2]
    _save(state, start)
    for level in range(MAX_HALVINGS + 1):
        if level > 0:
            _restore(state, start)
            out[O_DIV] = 0.0  # a failed try's blow-up is undone with it
        m = 1 << level
        hs = h / m
        sums[:] = 0.0
        converged = True
        for k in range(m):
            for j in range(6):
                sub_root[j] = root[j]
            sub_root[0] += k * hs * root[2]
            sub_root[1] += k * hs * root[3]
            sub_root[4] += k * hs * root[5]
            if level == MAX_HALVINGS:  # the last resort: linearly implicit steps, stable below about 1 ms
                implicit_once(
                    state, leg, par, free_length, sub_root, vlat, hs, normal, out, work, jac, max_age, 0, saved[0]
                )
            elif not _newton_step(
                state, leg, par, free_length, sub_root, vlat, hs, normal, out, work, jac, max_age, newton, saved, end
            ):
                converged = False
                break
            sums[0] += out[O_FX]
            sums[1] += out[O_FZ]
            sums[2] += out[O_M]
        if converged:  # always at the last level, whose linearly implicit steps do not iterate
            break
    out[O_FX] = sums[0] / m
    out[O_FZ] = sums[1] / m
    out[O_M] = sums[2] / m
    return m


@njit(cache=True)
def root_response(state, leg, par, h, jac, zcols, response):
    """How the leg's step just taken answers a change of its root's velocity over the step, to first order.

    For a unit change of each of the root's (v_s, v_z, omega) (the columns): ``zcols`` (3, 3N - 1) the
    leg's velocities (root rows: the change itself) and ``response`` (3, 3) the reaction on the root
    (f_s, f_z, m; rows). They come from the step's last linearisation (the factored W kept in ``jac``):
    the root node's velocity, the clamp's angle, the damping's rigid motion and the cable's length at
    the root all move with the root, W z = b solves for the nodes, and the reaction is the step's own
    reaction formula on that change. So a torso that takes the legs' answer into its own step
    (:func:`slotexp.soft.coupled.coupled_steps`) and moves each leg by z times its root's change
    exchanges momentum with them exactly, and sees the legs' stiffness and damping within the step.
    """
    pos, _, theta, _ = state
    _, _, _, voronoi, _, _, _, ei, mass, inertia = leg
    lu, kband, jvec, jmeta, _ = jac
    n = pos.shape[0]
    n_el = theta.shape[0]
    nd = 3 * n - 1
    c = par[P_C]
    k0 = ei[0] / voronoi[0]
    taut = abs(jmeta[n + J_CABLE]) == 1.0
    offset = jmeta[n + J_OFFSET]
    k_t = par[P_TK]
    g = jvec[1]
    zvel = np.empty((n, 2))  # a column's node velocities and element rates, and the root's change, for the
    zomega = np.empty(n_el)  # damping's reaction (loads.damping_reaction)
    droot = np.zeros(6)
    for col in range(3):
        z = zcols[col]
        z[:] = 0.0
        dvs = 1.0 if col == 0 else 0.0
        dvz = 1.0 if col == 1 else 0.0
        dw = 1.0 if col == 2 else 0.0
        z[0] = dvs
        z[1] = dvz
        for i in range(1, n):  # the damping pulls towards the root frame's rigid motion
            z[3 * i] += h * c * mass[i] * (dvs - dw * (pos[i, 1] - pos[0, 1]))
            z[3 * i + 1] += h * c * mass[i] * (dvz + dw * (pos[i, 0] - pos[0, 0]))
        for e in range(n_el):
            z[3 * e + 2] += h * c * inertia[e] * dw
        z[2] += h * h * k0 * dw  # the clamp turns
        if taut:  # the cable's length at the root turns with it
            for d in range(2, nd):
                z[d] += h * h * k_t * offset * dw * g[d]
        _solve_w(lu, jvec, jmeta[n + J_GZ], taut, z)
        # the reaction: the root rows of h^2 K, the damping's reaction, the cable's share, the clamp's moment
        d0, d1 = _root_rows(kband, z)
        for i in range(n):
            zvel[i, 0] = z[3 * i]
            zvel[i, 1] = z[3 * i + 1]
        for e in range(n_el):
            zomega[e] = z[3 * e + 2]
        droot[2], droot[3], droot[5] = dvs, dvz, dw
        damp_s, damp_z, damp_m = damping_reaction(pos, zvel, zomega, mass, inertia, par, droot)
        fs = -d0 / h + damp_s
        fz = -d1 / h + damp_z
        m_root = damp_m + k0 * h * (z[2] - dw)
        if taut:
            gz = 0.0
            for d in range(nd):
                gz += g[d] * z[d]
            stretch = gz - offset * dw
            fs -= h * k_t * g[0] * stretch
            fz -= h * k_t * g[1] * stretch
            m_root += k_t * h * stretch * offset
        response[0, col] = fs
        response[1, col] = fz
        response[2, col] = m_root


def jacobian_state(n_nodes: int, legs: int | None = None) -> JacobianState:
    """A leg's (or ``legs`` legs', stacked) implicit-step Jacobian state for :func:`implicit_once`, empty:
    the first step factors."""
    nd = 3 * n_nodes - 1
    lead = () if legs is None else (legs,)
    meta = np.zeros(lead + (n_nodes + J_TURN + 1,))
    meta[..., n_nodes + J_AGE] = np.inf  # refresh at the first step
    return JacobianState(
        np.zeros(lead + (nd, 9)),
        np.zeros(lead + (nd, 9)),
        np.zeros(lead + (2 + n_nodes, nd)),
        meta,
        friction_work(n_nodes, lead),
    )


@njit(cache=True)
def step_implicit(state, leg, par, free_length, root, h, n_steps, normal, out, jac, max_age, newton=1):
    """``n_steps`` of :func:`implicit_once` with the root held (the Jacobian state ``jac`` is the caller's;
    nothing slips across the plane)."""
    pos, _, theta, _ = state
    nd = 3 * pos.shape[0] - 1
    vlat = np.zeros(pos.shape[0])
    work = StepWork(
        np.zeros(pos.shape), np.zeros(theta.shape[0]), np.zeros(nd), np.zeros(nd),
        np.zeros(theta.shape[0]), np.zeros(theta.shape[0]),
    )  # fmt: skip
    saved = np.zeros((4, nd))
    roots = np.zeros((3, 6))
    for _ in range(n_steps):
        implicit_step(
            state, leg, par, free_length, root, vlat, h, normal, out, work, jac, max_age, newton, saved, roots
        )
        if out[O_DIV] > 0.0:
            return
    _set_root(pos, state.vel, root)


def divergence_message(
    what: str,
    t: float,
    h: float,
    integrator: str,
    explicit_limit: float,
    keys: tuple[str, str],
    loads: str,
    configured: float | None = None,
    retaken_to: float | None = None,
) -> str:
    """One line for a blown-up simulation that names the step and integrator actually used and a fix that
    changes something: ``keys`` are the config keys of the step and of the integrator, ``loads`` what
    else could have driven it, ``configured`` the step the config asked for if ``h`` differs from it (a
    period that is not a whole number of steps is split into equal shorter ones), ``retaken_to`` the
    shortest step the period was taken again with by backward Euler, if it was."""
    step_key, integrator_key = keys
    used = (
        f"{h:.3g} s"
        if configured is None or abs(configured - h) <= 1e-12
        else f"{configured:.3g} s, steps of {h:.3g} s"
    )
    head = f"{what} diverged at t = {t:.4g} s with {step_key} = {used} ({integrator})"
    if retaken_to is not None:
        head += f", and again when retaken by backward Euler at steps down to {retaken_to:.3g} s"
    if integrator != "implicit" and h > explicit_limit:
        fix = (
            f"the symplectic step's stability limit for this leg is about {explicit_limit:.3g} s: lower {step_key} "
            f"below it or use {integrator_key}=implicit"
        )
    elif integrator != "implicit":
        fix = (
            f"the step is below the symplectic stability limit ({explicit_limit:.3g} s), so the loads drove it: "
            f"check {loads}, or use {integrator_key}=implicit"
        )
    else:
        fix = f"the implicit step has no stability limit, so the loads or too coarse a step drove it: check {loads}"
        fix += f", or lower {step_key}"
    return f"{head}; {fix}"


def stable_dt(model: LegModel, k_contact: float = 0.0) -> float:
    """Largest stable symplectic-Euler step: 2 / omega_max of M^-1 K at rest (contact on every node).

    Contact damping is implicit in both integrators, so it does not limit the step.
    """
    from scipy.linalg import eigh

    n = model.n_nodes
    nd = 3 * n - 1
    band = np.zeros((nd, 9))
    elastic_hessian_band(
        model.rest_pos,
        model.rest_theta,
        model.rest_theta[0],
        model.l0,
        model.voronoi,
        model.dtheta0,
        model.ea,
        model.ga,
        model.ei,
        band,
        1.0,
    )
    k = np.zeros((nd, nd))
    for i in range(nd):
        for j in range(max(0, i - 4), min(nd, i + 5)):
            k[i, j] = band[i, 4 + j - i]
    m = np.zeros(nd)
    m[0::3] = model.mass
    m[1::3] = model.mass
    m[2::3] = model.inertia
    for i in range(n):
        k[3 * i + 1, 3 * i + 1] += k_contact
    free = np.arange(2, nd)  # the root node is clamped; its angle is the clamp vertex's reference
    lam = eigh(k[np.ix_(free, free)], np.diag(m[free]), eigvals_only=True)
    return float(2.0 / np.sqrt(lam.max()))


class LegSim:
    """One leg's state and parameters, stepped by either integrator.

    ``free0`` is the tendon's free length with the servo at zero (infinite: no
    tendon); ``free_length``, the free length now, is state the caller winds in or
    out between steps (:func:`slotexp.soft.statics.set_tendon`).
    """

    def __init__(self, model: LegModel, par: np.ndarray, free0: float = np.inf) -> None:
        self.model = model
        self.par = np.asarray(par, dtype=float)
        self.free0 = float(free0)
        self.free_length = self.free0
        self.pos = model.rest_pos.copy()
        self.vel = np.zeros_like(self.pos)
        self.theta = model.rest_theta.copy()
        self.omega = np.zeros_like(self.theta)
        self.root = np.array([self.pos[0, 0], self.pos[0, 1], 0.0, 0.0, self.theta[0], 0.0])
        self.normal = np.zeros(model.n_nodes)
        self.out = np.zeros(len(OUT))
        self.time = 0.0
        self.jacobian_age = 1  # steps the implicit step may reuse its factored Jacobian (1: none)
        self.newton = 1  # passes of the implicit step (1: linearly implicit; more: Newton corrections)
        self.jacobian = jacobian_state(model.n_nodes)

    @property
    def factorisations(self) -> int:
        """How many Jacobians the implicit step has factored for this leg."""
        return int(self.jacobian.jmeta[self.model.n_nodes + J_COUNT])

    @property
    def unsolved_frictions(self) -> int:
        """How many of this leg's friction solves (``plant.friction=solved``) stopped before converging."""
        return int(self.jacobian.jmeta[self.model.n_nodes + J_UNSOLVED])

    def step(self, h: float, n_steps: int = 1, integrator: str = "symplectic") -> None:
        m = self.model
        implicit = integrator == "implicit"
        if implicit and self.par[P_PAPER] > 0.5:
            raise ConfigError("the paper's leg model has no Jacobian: use the symplectic integrator with it")
        state = LegState(self.pos, self.vel, self.theta, self.omega)
        args = (state, m, self.par, float(self.free_length), self.root, h, n_steps, self.normal, self.out)
        if implicit:
            step_implicit(*args, self.jacobian, self.jacobian_age, self.newton)
        else:
            step_symplectic(*args)
        self.time += h * n_steps
        if self.out[O_DIV] > 0.0:
            limit = stable_dt(m, self.par[P_K] if self.par[P_GROUND] > 0.5 else 0.0)
            raise DivergenceError(
                divergence_message(
                    "the leg simulation",
                    self.time,
                    h,
                    integrator,
                    limit,
                    ("leg_load.dt", "leg_load.integrator"),
                    "leg_load.tip_force, leg_load.tip_moment and leg_load.root_height",
                )
            )

    def energy(self) -> float:
        """Kinetic + elastic + gravitational + tendon energy (no contact), J."""
        m = self.model
        kin = 0.5 * np.sum(m.mass[:, None] * self.vel**2) + 0.5 * np.sum(m.inertia * self.omega**2)
        el = elastic_energy(self.pos, self.theta, self.root[4], m.l0, m.voronoi, m.dtheta0, m.ea, m.ga, m.ei)
        grav = self.par[P_G] * np.sum(m.mass * self.pos[:, 1])
        stretch = max(0.0, tendon_length(self.pos, self.theta, self.root[4], self.par) - self.free_length)
        tendon = 0.5 * self.par[P_TK] * stretch**2
        if self.par[P_TPAIR] > 0.0:  # the pair's upper cable, at the offset above the centreline
            upper = tendon_length(self.pos, self.theta, self.root[4], self.par, -1.0)
            tendon += 0.5 * self.par[P_TK] * max(0.0, upper - (self.par[P_TPAIR] - self.free_length)) ** 2
        work = -(
            self.par[P_TFX] * self.pos[-1, 0] + self.par[P_TFZ] * self.pos[-1, 1] + self.par[P_TM] * self.theta[-1]
        )
        return float(kin + el + grav + tendon + work)

    @property
    def tip(self) -> np.ndarray:
        return self.pos[-1].copy()
