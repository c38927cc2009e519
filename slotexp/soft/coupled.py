"""The coupled step of a rigid torso and four soft legs, and of B such robots at once (numba kernels).

Each leg lives in the vertical plane through its corner along its yaw; its root
node follows the corner and its clamp angle follows the torso's tilt in that
plane. The force and moment the leg exerts on its root, rotated into 3D, act back
on the torso, so torso and legs share one step. Tendons are driven by servos
(first-order lag towards the commanded angle, tension capped by the stall torque
over the pulley radius). No fictitious force holds anything up.

Out of plane each leg is rigid by default (its width, 20 mm, is 1.5-6x its thickness); with
``robot.leg.out_of_plane=bending`` its pressed nodes' contact rides on a sideways spring, the
tapered strip's tip stiffness across its plane (about 31 N/m), in series with their friction
(:func:`_series_spring`): the foot can hold while the torso moves across the leg's plane. The
rigid assumption, which the rest of this paragraph describes either way for the legs' mass:
- a node moves across its leg's plane with the torso's rigid motion at the node,
  so the legs' mass across their planes belongs to the torso's inertia
  (:func:`augmented_inertia`: 7 % more sideways mass, about twice the yaw inertia);
- friction is one isotropic Coulomb law per pressed node on the node's whole slip:
  along the plane its own velocity, across it the torso's motion there; the part
  across the plane acts on the torso at the node, implicit in the torso's velocity;
- the plane stays vertical and turns with the torso's heading; when it turns, its
  nodes' in-plane momentum is re-expressed in the new directions and what leaves the
  plane goes to the torso (:func:`_sync_legs`), so no momentum is made or lost.
  Node positions keep the plane vertical: a tilt's sideways offset of the lower
  nodes (depth x tilt, about 1.4 mm at 2 deg) is not tracked.

The torso's state is its pose and the momentum of it and of the legs' motion across
their planes; its velocity follows from them (:func:`coupled_steps`). Without ground
and gravity the whole robot's momentum holds to round-off and its angular momentum
to the step's order (``tests/test_cosserat.py``).

The kernels take their arrays grouped, as named tuples numba compiles through: a robot's own
arrays (:class:`Robot`), its scratch and kept solver state (:class:`Work`), the torso's model
(:class:`TorsoModel`), the legs' (:class:`~slotexp.soft.rod.LegModel`) and the step's settings
(:class:`Settings`). :class:`slotexp.plants.cosserat.CosseratPlant` is the Plant around them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import prange

from ..body import advance_quaternion, quat_to_rot, solve_spd
from ..jit import njit
from .integrators import (
    JacobianState,
    LegState,
    StepWork,
    implicit_once,
    implicit_step,
    jacobian_state,
    root_response,
    symplectic_once,
)
from .loads import coulomb_friction, friction_slope, friction_tangent
from .params import O_DIV, O_FL, O_FX, O_FZ, O_M, O_T, O_TS, P_FSOLVE, P_MUS, P_VS
from .servo import servo_step

__all__ = ["TorsoModel", "Settings", "Robot", "Work", "new_work", "stacked", "row", "coupled_steps", "batch_steps"]


class TorsoModel(NamedTuple):
    """The torso as the legs see it: mass (kg), inertia (3, 3) about its centre (body frame), gravity
    (m/s^2), the legs' roots (4, 3, body frame, from the mass centre), their yaws (4,, rad) and the rest
    angle of each leg's first element (rad)."""

    mass: float
    inertia: np.ndarray
    gravity: float
    corners: np.ndarray
    yaw: np.ndarray
    rest_theta0: float


class Settings(NamedTuple):
    """What a step holds fixed: the servos' (time constant, stall torque, no-load speed, profile speed),
    the pulley radius, the legs' friction (mu, its regularisation speed), the integrator (implicit or
    symplectic), the Jacobian's age and the implicit step's passes (1: linearly implicit), the torso's
    underside points (P, 3, body) with their (stiffness, damping, mu, v_eps), and the legs' sideways
    stiffness (N/m, 0: rigid across their planes)."""

    servo_par: np.ndarray
    pulley: float
    mu: float
    v_eps: float
    implicit: bool
    max_age: int
    newton: int
    belly_points: np.ndarray
    belly_par: np.ndarray
    k_lat: float


class Robot(NamedTuple):
    """One robot's own arrays, its state and what a step reports (a batch stacks each along a first axis).

    The torso's pose and velocity (13,) and momentum (6,); per leg (first axis 4) its nodes (N, 2), their
    offsets across the plane (N,), velocities (N, 2), elements' angles and rates (E,), packed loads
    (:mod:`slotexp.soft.params`), servo angle and command (rad), the tendon's free length at servo zero,
    the corner's and the plane's direction at the last step (for :func:`_sync_legs`); then the nodes'
    normal forces (N,), each leg's outputs (``O_*``) and reaction on the torso (6,), the underside's
    force (3,), and each contact patch's sideways deflection and rate (2,)."""

    torso: np.ndarray
    momentum: np.ndarray
    pos: np.ndarray
    eta: np.ndarray
    vel: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    par: np.ndarray
    servo: np.ndarray
    servo_cmd: np.ndarray
    free0: np.ndarray
    prev_corner: np.ndarray
    prev_u: np.ndarray
    normal: np.ndarray
    out: np.ndarray
    reaction: np.ndarray
    belly: np.ndarray
    lateral: np.ndarray


# One robot's scratch and the solver state it keeps between steps, flat (a parallel loop takes named tuples
# one level deep only): the legs' shared StepWork (force, moment, rhs, vflat, used by each leg in turn) with
# each leg's directors (4, E), then each leg's implicit-step JacobianState (4, ...).
Work = NamedTuple("Work", [(name, np.ndarray) for name in StepWork._fields + JacobianState._fields])


def new_work(theta: np.ndarray) -> Work:
    """A robot's :class:`Work` for legs whose element angles are ``theta`` (4, E): directors from it, an
    empty Jacobian (the first step factors)."""
    n = theta.shape[1] + 1
    nd = 3 * n - 1
    scratch = StepWork(np.zeros((n, 2)), np.zeros(n - 1), np.zeros(nd), np.zeros(nd), np.cos(theta), np.sin(theta))
    return Work(*scratch, *jacobian_state(n, 4))


def stacked(items: list) -> tuple:
    """Named tuples of arrays (nested ones too), one per robot, as one of the same kind with each array
    stacked along a new first axis (a batch's)."""
    first = items[0]
    if isinstance(first, tuple):
        return type(first)(*(stacked([item[k] for item in items]) for k in range(len(first))))
    return np.stack(items)


def row(batch: tuple, b: int) -> tuple:
    """Robot ``b``'s views of a batch's :func:`stacked` named tuple."""
    if isinstance(batch, tuple):
        return type(batch)(*(row(part, b) for part in batch))
    return batch[b]


@njit(cache=True, allocates=False)
def _leg_axes(rot, cy, sy):
    """A leg's direction in the world's vertical: its horizontal unit u = (ux, uy), the direction's height
    component and horizontal length (the leg plane is the vertical plane through the corner along u)."""
    dwx = rot[0, 0] * cy + rot[0, 1] * sy
    dwy = rot[1, 0] * cy + rot[1, 1] * sy
    dwz = rot[2, 0] * cy + rot[2, 1] * sy
    horiz = np.sqrt(dwx * dwx + dwy * dwy)
    return dwx / horiz, dwy / horiz, dwz, horiz


@njit(cache=True, allocates=False)
def _corner_offset(rot, corner):
    """A corner's offset from the torso centre in the world frame."""
    return (
        rot[0, 0] * corner[0] + rot[0, 1] * corner[1] + rot[0, 2] * corner[2],
        rot[1, 0] * corner[0] + rot[1, 1] * corner[1] + rot[1, 2] * corner[2],
        rot[2, 0] * corner[0] + rot[2, 1] * corner[1] + rot[2, 2] * corner[2],
    )


@njit(cache=True, allocates=False)
def augmented_inertia(torso, rot, torso_mass, inertia, corners, cy, sy, pos, mass, out):
    """The 6x6 inertia of the torso and the legs' motion across their planes, about the torso centre, world frame.

    A leg is rigid out of its plane, so each node (but the root, which rides in ``torso_mass``)
    moves across the plane at the torso's rigid velocity there: v_lat = j . (v, w) with
    j = (lat, (r - p) x lat), lat = e_z x u. Its mass adds m j j^T: the legs' share of the body's
    sideways mass and of its inertia about every axis (most of all about z). Along the plane the
    nodes are the legs' own degrees of freedom and carry their own momentum.
    """
    out[:, :] = 0.0
    for a in range(3):
        out[a, a] = torso_mass
        for b in range(3):
            acc = 0.0
            for k in range(3):
                acc += rot[a, k] * (inertia[k, 0] * rot[b, 0] + inertia[k, 1] * rot[b, 1] + inertia[k, 2] * rot[b, 2])
            out[3 + a, 3 + b] = acc
    n = pos.shape[1]
    for i in range(pos.shape[0]):
        ux, uy, _, _ = _leg_axes(rot, cy[i], sy[i])
        lx, ly = -uy, ux
        rcx, rcy, rcz = _corner_offset(rot, corners[i])
        # per node j = (lx, ly, 0, -ly z, lx z, w0 + s) with z the node's height above the centre and
        # w0 + s = lat x-component of (r - p) x lat; so the leg's share needs six sums over its nodes
        w0 = rcx * ly - rcy * lx
        m0 = ms = mz = mss = msz = mzz = 0.0
        for k in range(1, n):
            m = mass[k]
            s = pos[i, k, 0]
            z = pos[i, k, 1] - torso[2]
            m0 += m
            ms += m * s
            mz += m * z
            mss += m * s * s
            msz += m * s * z
            mzz += m * z * z
        mw = w0 * m0 + ms  # sum m (w0 + s)
        mww = w0 * w0 * m0 + 2.0 * w0 * ms + mss
        mzw = w0 * mz + msz
        out[0, 0] += m0 * lx * lx
        out[0, 1] += m0 * lx * ly
        out[1, 1] += m0 * ly * ly
        # sum m b = (-ly mz, lx mz, mw)
        out[0, 3] += lx * (-ly * mz)
        out[0, 4] += lx * (lx * mz)
        out[0, 5] += lx * mw
        out[1, 3] += ly * (-ly * mz)
        out[1, 4] += ly * (lx * mz)
        out[1, 5] += ly * mw
        out[3, 3] += ly * ly * mzz
        out[3, 4] += -lx * ly * mzz
        out[3, 5] += -ly * mzw
        out[4, 4] += lx * lx * mzz
        out[4, 5] += lx * mzw
        out[5, 5] += mww
    for a in range(6):
        for b in range(a):
            out[a, b] = out[b, a]


@njit(cache=True, allocates=False)
def _sync_legs(torso, momentum, rot, corners, cy, sy, pos, eta, vel, omega, mass, inertia_el, prev_corner, prev_u):
    """Bring every leg's plane to the torso's pose, every node keeping its world position and momentum.

    A step moves the nodes in the plane it started with (through the corner ``prev_corner`` along
    ``prev_u``): along it by their own velocity, across it (``eta``) by the torso's rigid motion
    at the node. Here each node is expressed in the plane through the corner now, along the leg's
    direction now: its distance along it, and its offset across it (the sideways displacement a
    leg rigid out of its plane takes when the torso tilts or turns). Its in-plane momentum is
    re-expressed in the new direction too; what no longer lies in the plane (m v_s sin of the
    turn) is momentum across it, which the leg's rigidity hands to the torso: it goes into
    ``momentum`` (P, and L about the world origin), so a turn neither makes nor loses momentum.
    """
    n = pos.shape[1]
    for i in range(pos.shape[0]):
        ux, uy, _, _ = _leg_axes(rot, cy[i], sy[i])
        lx, ly = -uy, ux
        rcx, rcy, rcz = _corner_offset(rot, corners[i])
        cwx = torso[0] + rcx
        cwy = torso[1] + rcy
        pux, puy = prev_u[i, 0], prev_u[i, 1]
        # the old frame's origin relative to the new one, and its axes in the new one
        ox = prev_corner[i, 0] - cwx
        oy = prev_corner[i, 1] - cwy
        cosd = pux * ux + puy * uy
        sind = pux * lx + puy * ly
        o_s = ox * ux + oy * uy
        o_l = ox * lx + oy * ly
        for k in range(1, n):
            s_old = pos[i, k, 0]
            e_old = eta[i, k]
            # world offset = o + s_old prev_u + e_old prev_lat, with prev_lat = (-puy, pux)
            pos[i, k, 0] = o_s + s_old * cosd - e_old * sind
            eta[i, k] = o_l + s_old * sind + e_old * cosd
        pos[i, 0, 0] = 0.0
        pos[i, 0, 1] = torso[2] + rcz
        eta[i, 0] = 0.0
        prev_corner[i, 0] = cwx
        prev_corner[i, 1] = cwy
        prev_corner[i, 2] = torso[2] + rcz
        if sind != 0.0:
            px = py = 0.0  # the leftover momentum, along lat
            lox = loy = loz = 0.0  # ... and its moment about the world origin
            for k in range(1, n):
                left = mass[k] * vel[i, k, 0] * sind
                vel[i, k, 0] *= cosd
                rx = cwx + pos[i, k, 0] * ux + eta[i, k] * lx
                ry = cwy + pos[i, k, 0] * uy + eta[i, k] * ly
                rz = pos[i, k, 1]
                px += left * lx
                py += left * ly
                lox += -rz * left * ly
                loy += rz * left * lx
                loz += (rx * ly - ry * lx) * left
            # the elements' spin about their in-plane axis a = u x e_z turns with the plane too
            spin = 0.0
            for e in range(omega.shape[1]):
                spin += inertia_el[e] * omega[i, e]
                omega[i, e] *= cosd
            momentum[0] += px
            momentum[1] += py
            momentum[3] += lox + spin * (puy - cosd * uy)
            momentum[4] += loy + spin * (-pux + cosd * ux)
            momentum[5] += loz
        prev_u[i, 0] = ux
        prev_u[i, 1] = uy


@njit(cache=True, allocates=False)
def velocity_from_momentum(torso, momentum, rot, aug, scratch, rhs, xi):
    """The torso's velocity (v, w) from the momentum state and the 6x6 inertia ``aug`` at this pose:
    written into ``torso[7:13]`` (w in the body frame) and ``xi`` (w in the world frame)."""
    p0, p1, p2 = torso[0], torso[1], torso[2]
    rhs[0], rhs[1], rhs[2] = momentum[0], momentum[1], momentum[2]
    # angular momentum about the torso centre
    rhs[3] = momentum[3] - (p1 * momentum[2] - p2 * momentum[1])
    rhs[4] = momentum[4] - (p2 * momentum[0] - p0 * momentum[2])
    rhs[5] = momentum[5] - (p0 * momentum[1] - p1 * momentum[0])
    for a in range(6):  # element by element: a slice copy would allocate (the kernel allocates nothing)
        for b in range(6):
            scratch[a, b] = aug[a, b]
    solve_spd(scratch, rhs, xi)
    torso[7], torso[8], torso[9] = xi[0], xi[1], xi[2]
    for a in range(3):
        torso[10 + a] = rot[0, a] * xi[3] + rot[1, a] * xi[4] + rot[2, a] * xi[5]


@njit(cache=True, allocates=False)
def _belly_contact(point, rot, pz, xi, par, h, load, damp, belly, implicit_normal):
    """One of the torso's underside points on the ground: penalty normal force and isotropic Coulomb friction
    (:func:`coulomb_friction`'s law in the plane of the floor), the friction linearised in the torso's velocity
    (its slope into ``damp``, h x the 6x6 on (v, w), as the legs' friction across their planes). With
    ``implicit_normal`` (backward Euler, ``plant.newton`` > 1) the normal force is taken at the step's end too,
    k (depth - h v_z') - d v_z': the penalty spring (1e5 N/m on a 1 kg torso) is stable at millisecond steps
    only so."""
    r0 = rot[0, 0] * point[0] + rot[0, 1] * point[1] + rot[0, 2] * point[2]
    r1 = rot[1, 0] * point[0] + rot[1, 1] * point[1] + rot[1, 2] * point[2]
    r2 = rot[2, 0] * point[0] + rot[2, 1] * point[1] + rot[2, 2] * point[2]
    depth = -(pz + r2)
    if depth <= 0.0:
        return
    w0, w1, w2 = xi[3], xi[4], xi[5]
    vx = xi[0] + w1 * r2 - w2 * r1
    vy = xi[1] + w2 * r0 - w0 * r2
    vz = xi[2] + w0 * r1 - w1 * r0
    nrm = par[0] * depth - par[1] * vz
    if nrm <= 0.0:
        return
    mu, v_eps = par[2], par[3]
    fx, fy = coulomb_friction(vx, vy, nrm, mu, v_eps, mu, 1.0)  # plain Coulomb: the torso is not the feet's TPU
    # the friction's slope in the floor's plane: its secant, alike in every direction, as the legs' (friction_slope)
    c = friction_slope(vx, vy, nrm, mu, v_eps, mu, 1.0)
    # the point's horizontal velocity is J (v, w): rows jx = (1, 0, 0, 0, r2, -r1), jy = (0, 1, 0, -r2, 0, r0)
    gx = fx + c * vx  # F0 + C v, so that load - C xi_new is the friction at the new velocity
    gy = fy + c * vy
    load[0] += gx
    load[1] += gy
    load[2] += nrm
    load[3] += r1 * nrm - r2 * gy
    load[4] += r2 * gx - r0 * nrm
    load[5] += r0 * gy - r1 * gx
    jx = (1.0, 0.0, 0.0, 0.0, r2, -r1)
    jy = (0.0, 1.0, 0.0, -r2, 0.0, r0)
    for a in range(6):
        for b in range(a, 6):
            damp[a, b] += h * (c * jx[a] * jx[b] + c * jy[a] * jy[b])
    if implicit_normal:
        # N' = N + (k h + d) (v_z - v_z'): the affine part into the load, the slope on jz = (0, 0, 1, r1, -r0, 0)
        cz = par[0] * h + par[1]
        gz = cz * vz
        load[2] += gz
        load[3] += r1 * gz
        load[4] -= r0 * gz
        jz = (0.0, 0.0, 1.0, r1, -r0, 0.0)
        for a in range(6):
            for b in range(a, 6):
                damp[a, b] += h * cz * jz[a] * jz[b]
    belly[0] += nrm
    belly[1] += fx
    belly[2] += fy


@njit(cache=True, allocates=False)
def _series_spring(k_lat, deflection, slope_sum, h):
    """A leg's contact patch on a sideways spring ``k_lat`` in series with its friction (slopes summing to C).

    The patch is massless: the spring's force k (d + h d'), taken implicitly, equals the friction
    at the patch's slip, G - c (j . xi + d') summed over its nodes. Solved for d' and put back,
    the force the leg passes to the torso is alpha (G - sum c j . xi) + C k d / (k h + C) with
    alpha = k h / (k h + C): each node's affine part and slope scaled by ``alpha``, plus its share
    c ``hold`` of the spring's pre-load (``hold`` = k d / (k h + C)). Sticking (C large) the torso
    feels the spring; sliding (C small) the friction. Rigid (``k_lat`` = 0): alpha 1, hold 0.
    """
    if k_lat <= 0.0:
        return 1.0, 0.0
    denominator = k_lat * h + slope_sum
    return k_lat * h / denominator, k_lat * deflection / denominator


LATERAL_ITERATIONS = 30  # Newton iterations at most for the friction across the planes (plant.friction=solved)
LATERAL_TOLERANCE = 1e-12  # its residual, relative to the momentum the torso's step moves


@njit(cache=True, allocates=False)
def _lateral_residual(system, rhs6, x, pos, vel, normal, par, axes, p2, mu, v_eps, h, g, across, hess, tangent):
    """G(x) = system x - rhs6 - h sum_k F_k(j_k . x) j_k over the pressed nodes, each one's friction across its
    leg's plane at the slip the torso's velocity ``x`` gives it (its slip along the plane after its leg's step
    held), into ``g``; ``across`` (legs,) receives each leg's friction sum. With ``tangent``, ``hess`` receives
    G's Jacobian, system - h sum_k t_k j_k j_k^T (t_k the law's tangent). Returns |G|^2."""
    for a in range(6):
        acc = -rhs6[a]
        for b in range(6):
            acc += system[a, b] * x[b]
            if tangent:
                hess[a, b] = system[a, b]
        g[a] = acc
    for i in range(pos.shape[0]):
        lx, ly, w0 = axes[i, 0], axes[i, 1], axes[i, 2]
        lat_v = lx * x[0] + ly * x[1]
        turn = lx * x[4] - ly * x[3]
        total = 0.0
        for k in range(1, pos.shape[1]):
            nrm = normal[i, k]
            if nrm <= 0.0:
                continue
            z = pos[i, k, 1] - p2
            w = w0 + pos[i, k, 0]
            slip = lat_v + z * turn + w * x[5]
            _, f = coulomb_friction(vel[i, k, 0], slip, nrm, mu, v_eps, par[i, P_MUS], par[i, P_VS])
            total += f
            hf = h * f
            g[0] -= hf * lx
            g[1] -= hf * ly
            g[3] += hf * ly * z
            g[4] -= hf * lx * z
            g[5] -= hf * w
            if tangent:
                t = -h * friction_tangent(slip, vel[i, k, 0], nrm, mu, v_eps, par[i, P_MUS], par[i, P_VS])
                j0, j1, j3, j4 = lx, ly, -ly * z, lx * z  # j_k = (j0, j1, 0, j3, j4, w)
                for a, ja in ((0, j0), (1, j1), (3, j3), (4, j4), (5, w)):
                    hess[a, 0] += t * ja * j0
                    hess[a, 1] += t * ja * j1
                    hess[a, 3] += t * ja * j3
                    hess[a, 4] += t * ja * j4
                    hess[a, 5] += t * ja * w
        across[i] = total
    merit = 0.0
    for a in range(6):
        merit += g[a] * g[a]
    return merit


@njit(cache=True, allocates=False)
def _solve_lateral(system, rhs6, xi_new, pos, vel, normal, par, axes, p2, mu, v_eps, h, scratch, across):
    """The torso's step with the pressed nodes' friction across the planes taken at its end (plant.friction=solved).

    Newton on G(xi_new) = 0 (:func:`_lateral_residual`) from the guess in ``xi_new``; each iteration's matrix is
    ``system`` - h sum_k t_k j_k j_k^T, t_k the law's tangent (<= 0 for plain friction, so positive definite), and a
    backtracking line search keeps the residual falling. Each trial point is evaluated with its Jacobian, so the
    accepted one (nearly always the full step) is not evaluated again. ``scratch`` (16, 6): four vectors and two
    6 x 6 matrices; ``across`` (legs,) receives each leg's friction across its plane at the end."""
    g, step, trial, gt = scratch[0], scratch[1], scratch[2], scratch[3]
    hess = scratch[4:10]
    hess_trial = scratch[10:16]
    args = (pos, vel, normal, par, axes, p2, mu, v_eps, h)
    # |G| at which the step is solved: far below the momentum a step moves (rhs6 ~ M v + h M g)
    size = 0.0
    for a in range(6):
        size += rhs6[a] * rhs6[a]
    tol2 = LATERAL_TOLERANCE * LATERAL_TOLERANCE * size
    merit = _lateral_residual(system, rhs6, xi_new, *args, g, across, hess, True)
    for _ in range(LATERAL_ITERATIONS):
        if merit <= tol2:  # (sticking, the law is linear and one iteration solves it)
            break
        for a in range(6):
            gt[a] = -g[a]
        solve_spd(hess, gt, step)
        lam = 1.0
        while True:  # backtracking: the full step, or the first half that lowers the residual enough
            for a in range(6):
                trial[a] = xi_new[a] + lam * step[a]
            value = _lateral_residual(system, rhs6, trial, *args, gt, across, hess_trial, True)
            if value < (1.0 - 1e-4 * lam) * merit or lam < 1e-6:
                break
            lam *= 0.5
        # G, its Jacobian and each leg's friction at the new velocity (what the caller reads when this is the last)
        merit = value
        for a in range(6):
            xi_new[a] = trial[a]
            g[a] = gt[a]
            for b in range(6):
                hess[a, b] = hess_trial[a, b]


@njit(cache=True, allocates=False)
def _root_map(ux, uy, rcx, rcy, rcz, jmap):
    """The map J (3, 6) from the torso's velocity (v, w world) to a leg root's (v_s along u, v_z, omega about
    u x e_z) at the corner offset ``rc``; its transpose takes the root's reaction (f_s, f_z, m) to the torso's
    generalised force (force, moment about the centre)."""
    jmap[:, :] = 0.0
    jmap[0, 0] = ux
    jmap[0, 1] = uy
    jmap[0, 3] = -uy * rcz
    jmap[0, 4] = ux * rcz
    jmap[0, 5] = uy * rcx - ux * rcy
    jmap[1, 2] = 1.0
    jmap[1, 3] = rcy
    jmap[1, 4] = -rcx
    jmap[2, 3] = uy
    jmap[2, 4] = -ux


@njit(cache=True, allocates=False)
def _add_leg_answer(jmap, response, h, xi, system, rhs6):
    """Put a leg's reaction change S J (xi_new - xi) into the torso's step: system -= h J^T S J, rhs -= h J^T S J xi."""
    for a in range(6):
        for b in range(6):
            g = 0.0
            for r in range(3):
                for c in range(3):
                    g += jmap[r, a] * response[r, c] * jmap[c, b]
            system[a, b] -= h * g
            rhs6[a] -= h * g * xi[b]


@njit(cache=True, allocates=False)
def _answer(jmap, response, dxi, du, load, out, reaction):
    """A leg's reaction at the torso's new velocity: R += S du with du = J dxi, into the torso's ``load``, the
    leg's ``out`` (f_s, f_z, m) and its world ``reaction`` (force, moment)."""
    for r in range(3):
        du[r] = 0.0
        for a in range(6):
            du[r] += jmap[r, a] * dxi[a]
    for r in range(3):
        d = 0.0
        for c in range(3):
            d += response[r, c] * du[c]
        out[r] += d  # O_FX, O_FZ, O_M
        for a in range(6):
            load[a] += jmap[r, a] * d
        ux, uy = jmap[0, 0], jmap[0, 1]
        if r == 0:
            reaction[0] += d * ux
            reaction[1] += d * uy
        elif r == 1:
            reaction[2] += d
        else:
            reaction[3] += d * uy
            reaction[4] -= d * ux


@njit(cache=True, allocates=False)
def _follow_root(zcols, du, h, pos, vel, theta, omega):
    """Move a leg's free nodes and elements by its answer to its root's change ``du``: velocities by z du,
    positions and angles by h z du (the root node follows the corner at the next step)."""
    n = pos.shape[0]
    for i in range(1, n):
        dvx = zcols[0, 3 * i] * du[0] + zcols[1, 3 * i] * du[1] + zcols[2, 3 * i] * du[2]
        dvz = zcols[0, 3 * i + 1] * du[0] + zcols[1, 3 * i + 1] * du[1] + zcols[2, 3 * i + 1] * du[2]
        vel[i, 0] += dvx
        vel[i, 1] += dvz
        pos[i, 0] += h * dvx
        pos[i, 1] += h * dvz
    for e in range(theta.shape[0]):
        dw = zcols[0, 3 * e + 2] * du[0] + zcols[1, 3 * e + 2] * du[1] + zcols[2, 3 * e + 2] * du[2]
        omega[e] += dw
        theta[e] += h * dw


@njit(cache=True)
def coupled_steps(robot, work, torso_model, leg, settings, f_ext, h, n_steps, hold_torso):
    """Advance one robot (:class:`Robot`, its scratch :class:`Work`) ``n_steps`` steps of ``h``: its torso
    (:class:`TorsoModel`), four legs of the model ``leg`` (:class:`~slotexp.soft.rod.LegModel`), the
    :class:`Settings`, and a constant external force ``f_ext`` (3,) on the torso.

    The torso's state is its pose (``torso[0:7]``: p, q) and ``momentum`` (6: linear momentum
    and angular momentum about the world origin) of itself and of the legs' motion across their
    planes (:func:`augmented_inertia`); ``torso[7:13]`` (v, w_body) is derived from them at every
    step. Each step: the legs' planes follow the torso (:func:`_sync_legs`); each leg steps in its
    plane with its root on the corner; the leg's root force and moment, and the friction its
    pressed nodes feel across the plane (implicit in the torso's velocity), change the momentum;
    the pose moves with the new velocity. Every exchange between a leg and the torso is applied
    to both, so without ground and gravity the robot's momentum holds to round-off.

    ``work.cth``/``sth`` (4, E) are each leg's directors, kept current by the symplectic step;
    ``work.lu``, ``kband``, ``jvec``, ``jmeta``, ``fwork`` each leg's Jacobian state for the implicit step,
    whose factorisation serves up to ``settings.max_age`` steps (:func:`implicit_once`).

    ``robot.eta`` (4, N) is each node's offset across its leg's plane (:func:`_sync_legs`).
    ``reaction`` (4, 6) receives each leg's force and moment on the torso (world) at the last
    step, its friction across the plane included. ``belly_points`` (P, 3) are the torso's points that
    touch the ground (body frame; none: no torso contact), ``belly_par`` their (stiffness, damping, mu,
    v_eps), and ``belly`` (3,) receives their normal and friction force (x, y) at the last step.
    ``lateral`` (4, 2) is each leg's contact patch's deflection across its plane and its rate, on a
    spring of ``k_lat`` N/m in series with the patch's friction (:func:`_series_spring`; 0: rigid, the
    patch moves with the torso and ``lateral`` stays zero). With ``hold_torso`` the torso stays where it
    is, at rest (the legs settle under it). Returns the number of steps done (< n_steps on divergence).
    """
    torso, momentum, pos, eta, vel, theta, omega, par, servo, servo_cmd, free0, prev_corner, prev_u = robot[:13]
    normal, out, reaction, belly, lateral = robot[13:]
    force, moment, rhs, vflat, cth, sth, lu, kband, jvec, jmeta, fwork = work
    torso_mass, inertia, gravity, corners, yaw, rest_theta0 = torso_model
    servo_par, pulley, mu, v_eps, implicit, max_age, newton, belly_points, belly_par, k_lat = settings
    mass = leg.mass
    inertia_el = leg.inertia
    n_legs = pos.shape[0]
    n_nodes = pos.shape[1]
    inv_mass = 1.0 / mass
    inv_inertia = 1.0 / inertia_el
    root = np.zeros(6)
    vlat = np.zeros(n_nodes)
    saved = np.zeros((4, 3 * n_nodes - 1))  # the implicit step's Newton corrections and halvings (implicit_step)
    roots = np.zeros((3, 6))
    # backward Euler (newton > 1): the torso takes each leg's answer to its root's velocity into its own step
    # (root_response): the legs' velocity response (3 per leg), their reaction's (3 x 3), the map from the
    # torso's velocity (v, w world) to the root's (v_s, v_z, omega)
    answering = implicit and newton > 1 and not hold_torso
    zcols = np.zeros((n_legs, 3, 3 * n_nodes - 1))
    responses = np.zeros((n_legs, 3, 3))
    jroot = np.zeros((n_legs, 3, 6))
    sub_h = np.zeros(n_legs)  # the step the answer is of (h, or h / m for a step retaken as m)
    dxi = np.zeros(6)
    du = np.zeros((n_legs, 3))  # each answering leg's root change over the step, J dxi
    f0s = np.zeros(n_nodes)  # a leg's pressed nodes' friction across the plane, and its slope
    slopes = np.zeros((n_legs, n_nodes))
    pulls = np.zeros(n_legs)  # per leg, the sum of its nodes' F0 + c v (the friction's affine part) ...
    grips = np.zeros(n_legs)  # ... and of their slopes c
    cy = np.cos(yaw)
    sy = np.sin(yaw)
    aug = np.empty((6, 6))  # the torso's 6x6 inertia at this step's pose
    system = np.empty((6, 6))
    damp = np.zeros((6, 6))  # h x the lateral friction's slope, as a 6x6 on the torso's velocity
    load = np.zeros(6)  # generalised force on the torso (world force, moment about its centre)
    rhs6 = np.empty(6)
    xi = np.empty(6)  # torso velocity (v, w world) at the step's start
    xi_new = np.empty(6)
    # plant.friction=solved with rigid patches (no series spring): the friction across the planes at the step's end
    solve_across = par[0, P_FSOLVE] > 0.5 and k_lat <= 0.0 and not answering
    axes = np.zeros((n_legs, 3))  # each leg's (lx, ly, w0): its nodes' j vectors (_lateral_residual)
    lateral_scratch = np.zeros((16, 6))
    across_end = np.zeros(n_legs)
    for step in range(n_steps + 1):
        rot = quat_to_rot(torso[3:7])
        _sync_legs(torso, momentum, rot, corners, cy, sy, pos, eta, vel, omega, mass, inertia_el, prev_corner, prev_u)
        if hold_torso:
            momentum[:] = 0.0
            torso[7:13] = 0.0
            xi[:] = 0.0
        else:
            augmented_inertia(torso, rot, torso_mass, inertia, corners, cy, sy, pos, mass, aug)
            velocity_from_momentum(torso, momentum, rot, aug, system, rhs6, xi)
        if step == n_steps:
            break  # the state is consistent: legs in the torso's planes, velocity from the momentum
        p0, p1, p2 = torso[0], torso[1], torso[2]
        ww0, ww1, ww2 = xi[3], xi[4], xi[5]
        load[0] = f_ext[0]
        load[1] = f_ext[1]
        load[2] = f_ext[2] - torso_mass * gravity
        load[3] = load[4] = load[5] = 0.0
        damp[:, :] = 0.0
        for i in range(n_legs):
            ux, uy, dwz, horiz = _leg_axes(rot, cy[i], sy[i])
            lx, ly = -uy, ux
            rcx, rcy, rcz = _corner_offset(rot, corners[i])
            vcx = xi[0] + ww1 * rcz - ww2 * rcy
            vcy = xi[1] + ww2 * rcx - ww0 * rcz
            vcz = xi[2] + ww0 * rcy - ww1 * rcx
            root[0] = 0.0
            root[1] = p2 + rcz
            root[2] = vcx * ux + vcy * uy
            root[3] = vcz
            root[4] = rest_theta0 + np.arctan2(dwz, horiz)
            root[5] = ww0 * uy - ww1 * ux  # omega . (u x e_z)
            # each node's velocity across the plane: the torso's rigid motion there, j . (v, w)
            w0 = rcx * ly - rcy * lx
            lat_v = lx * xi[0] + ly * xi[1] + lateral[i, 1]  # the patch's own sideways rate on top
            turn = lx * ww1 - ly * ww0
            for k in range(1, n_nodes):
                vlat[k] = lat_v + (pos[i, k, 1] - p2) * turn + (w0 + pos[i, k, 0]) * ww2
            # servo: first-order lag towards the command, at most as fast as its load allows
            cable_torque = out[i, O_T] * pulley  # the cable's torque on the servo, against winding it in
            if out[i, O_TS] < 0.0:
                cable_torque = -cable_torque  # the pair's upper cable resists the other way
            servo[i] = servo_step(
                servo[i], servo_cmd[i], h, servo_par[0], cable_torque, servo_par[1], servo_par[2], servo_par[3]
            )
            free_length = free0[i] - pulley * servo[i]  # the cable the servo leaves out
            state = LegState(pos[i], vel[i], theta[i], omega[i])
            scratch = StepWork(force, moment, rhs, vflat, cth[i], sth[i])
            if implicit:
                jac = JacobianState(lu[i], kband[i], jvec[i], jmeta[i], fwork[i])
                if newton <= 1:  # the linearly implicit step, called directly (one call's arguments fewer)
                    implicit_once(
                        state, leg, par[i], free_length, root, vlat, h, normal[i], out[i], scratch, jac, max_age, 0,
                        saved[0],
                    )  # fmt: skip
                    taken = 1
                else:
                    taken = implicit_step(
                        state, leg, par[i], free_length, root, vlat, h, normal[i], out[i], scratch, jac, max_age,
                        newton, saved, roots,
                    )  # fmt: skip
                # a step retaken as m shorter ones answers through its last: the leg's velocities by z du, its
                # positions by h / m z du, the torso by the last one's reaction change over 1 / m of the step
                if answering:
                    sub_h[i] = h / taken
                    root_response(state, leg, par[i], sub_h[i], jac, zcols[i], responses[i])
                    responses[i] *= 1.0 / taken
                    _root_map(ux, uy, rcx, rcy, rcz, jroot[i])
            else:
                symplectic_once(
                    state, leg, inv_mass, inv_inertia, par[i], free_length, root, vlat, h, normal[i], out[i], scratch
                )
            if out[i, O_DIV] > 0.0:
                return step
            fwx = out[i, O_FX] * ux
            fwy = out[i, O_FX] * uy
            fwz = out[i, O_FZ]
            mwx = out[i, O_M] * uy
            mwy = -out[i, O_M] * ux
            load[0] += fwx
            load[1] += fwy
            load[2] += fwz
            load[3] += rcy * fwz - rcz * fwy + mwx
            load[4] += rcz * fwx - rcx * fwz + mwy
            load[5] += rcx * fwy - rcy * fwx
            # friction across the plane on the pressed nodes (coulomb_friction with the node's slip along the
            # plane after its step), linearised in the torso's velocity: F = F0 - c j . (xi_new - xi). With
            # j = (lat, -ly z, lx z, w) per node, the leg's share of the load and of C = sum c j j^T needs
            # only sums over its nodes of f, f z, f w and of c, c z, c w, c z z, c z w, c w w.
            # With a compliant patch each node's F0 + c v and c pass through the series spring first.
            across = 0.0
            csum = gsum = 0.0
            # (plant.friction=solved: taken at the step's end with the torso's own, _solve_lateral; none here)
            axes[i, 0], axes[i, 1], axes[i, 2] = lx, ly, w0
            for k in range(1, n_nodes):
                f0s[k] = 0.0
                slopes[i, k] = 0.0
                nrm = normal[i, k]
                if nrm <= 0.0 or solve_across:
                    continue
                vs = vel[i, k, 0]
                _, f0 = coulomb_friction(vs, vlat[k], nrm, mu, v_eps, par[i, P_MUS], par[i, P_VS])
                f0s[k] = f0
                slopes[i, k] = friction_slope(vlat[k], vs, nrm, mu, v_eps, par[i, P_MUS], par[i, P_VS])
                csum += slopes[i, k]
                gsum += f0s[k] + slopes[i, k] * vlat[k]
            pulls[i] = gsum
            grips[i] = csum
            alpha, hold = _series_spring(k_lat, lateral[i, 0], csum, h)
            sf = sfz = sfw = sc = scz = scw = sczz = sczw = scww = 0.0
            for k in range(1, n_nodes):
                if normal[i, k] <= 0.0 or solve_across:
                    continue
                f0 = f0s[k]
                c = slopes[i, k]
                across += alpha * (f0 + c * lateral[i, 1]) + c * hold
                # vlat = j . xi (+ the patch's rate), the slip it was taken at
                f = alpha * (f0 + c * vlat[k]) + c * hold
                c *= alpha
                z = pos[i, k, 1] - p2
                w = w0 + pos[i, k, 0]
                sf += f
                sfz += f * z
                sfw += f * w
                sc += c
                scz += c * z
                scw += c * w
                sczz += c * z * z
                sczw += c * z * w
                scww += c * w * w
            if sc > 0.0 or sf != 0.0:
                load[0] += sf * lx
                load[1] += sf * ly
                load[3] += -ly * sfz
                load[4] += lx * sfz
                load[5] += sfw
                sc *= h
                scz *= h
                scw *= h
                sczz *= h
                sczw *= h
                scww *= h
                damp[0, 0] += sc * lx * lx
                damp[0, 1] += sc * lx * ly
                damp[1, 1] += sc * ly * ly
                damp[0, 3] += -lx * ly * scz
                damp[0, 4] += lx * lx * scz
                damp[0, 5] += lx * scw
                damp[1, 3] += -ly * ly * scz
                damp[1, 4] += lx * ly * scz
                damp[1, 5] += ly * scw
                damp[3, 3] += ly * ly * sczz
                damp[3, 4] += -lx * ly * sczz
                damp[3, 5] += -ly * sczw
                damp[4, 4] += lx * lx * sczz
                damp[4, 5] += lx * sczw
                damp[5, 5] += scww
            out[i, O_FL] = across
            reaction[i, 0] = fwx + across * lx
            reaction[i, 1] = fwy + across * ly
            reaction[i, 2] = fwz
            reaction[i, 3] = mwx
            reaction[i, 4] = mwy
            reaction[i, 5] = 0.0
        if hold_torso:
            continue
        belly[:] = 0.0
        for j in range(belly_points.shape[0]):
            _belly_contact(belly_points[j], rot, torso[2], xi, belly_par, h, load, damp, belly, answering)
        # momentum about the torso centre, plus the step's impulse; the friction's slope implicit:
        # (A + h C) xi_new = A xi + h (load - C xi)... written with load holding F0 + C xi
        for a in range(6):
            for b in range(a):
                damp[a, b] = damp[b, a]
        for a in range(6):
            acc = 0.0
            for b in range(6):
                acc += aug[a, b] * xi[b]
                system[a, b] = aug[a, b] + damp[a, b]
            rhs6[a] = acc + h * load[a]
        if answering:
            # the legs' reactions at the torso's new velocity: R + S J (xi_new - xi), each as J^T R on the torso
            for i in range(n_legs):
                _add_leg_answer(jroot[i], responses[i], h, xi, system, rhs6)
            xi_new[:] = np.linalg.solve(system, rhs6)
            for a in range(6):
                dxi[a] = xi_new[a] - xi[a]
            for i in range(n_legs):
                _answer(jroot[i], responses[i], dxi, du[i], load, out[i], reaction[i])
        elif solve_across:
            for a in range(6):
                xi_new[a] = xi[a]
            _solve_lateral(system, rhs6, xi_new, pos, vel, normal, par, axes, p2, mu, v_eps, h, lateral_scratch,
                           across_end)  # fmt: skip
            for i in range(n_legs):
                out[i, O_FL] = across_end[i]
                reaction[i, 0] += across_end[i] * axes[i, 0]
                reaction[i, 1] += across_end[i] * axes[i, 1]
            # the friction's force at the step's end, sum_k F_k j_k, into the load: from G = system xi_new - rhs6 -
            # h sum F_k j_k, the residual the solve left (lateral_scratch[0])
            for a in range(6):
                acc = 0.0
                for b in range(6):
                    acc += system[a, b] * xi_new[b]
                load[a] += (acc - rhs6[a] - lateral_scratch[0, a]) / h
        else:
            solve_spd(system, rhs6, xi_new)
        # the impulse applied, friction at the velocity it ends with: h load - h C xi_new
        for a in range(6):
            acc = 0.0
            for b in range(6):
                acc += damp[a, b] * xi_new[b]
            load[a] = h * load[a] - acc
        momentum[0] += load[0]
        momentum[1] += load[1]
        momentum[2] += load[2]
        # its moment about the world origin: about the centre, plus p x impulse
        momentum[3] += load[3] + p1 * load[2] - p2 * load[1]
        momentum[4] += load[4] + p2 * load[0] - p0 * load[2]
        momentum[5] += load[5] + p0 * load[1] - p1 * load[0]
        # the nodes move across their planes with the torso's new velocity there (positions follow the
        # velocities the momentum was counted with)
        for i in range(n_legs):
            ux, uy, _, _ = _leg_axes(rot, cy[i], sy[i])
            lx, ly = -uy, ux
            rcx, rcy, _ = _corner_offset(rot, corners[i])
            w0 = rcx * ly - rcy * lx
            lat_v = lx * xi_new[0] + ly * xi_new[1]
            turn = lx * xi_new[4] - ly * xi_new[3]
            pulled = 0.0  # sum of c j . xi_new over the pressed nodes
            for k in range(1, n_nodes):
                u = lat_v + (pos[i, k, 1] - p2) * turn + (w0 + pos[i, k, 0]) * xi_new[5]
                eta[i, k] += h * u
                pulled += slopes[i, k] * u
            if answering:  # the leg follows its root's change over the step, as its answer said
                _follow_root(zcols[i], du[i], sub_h[i], pos[i], vel[i], theta[i], omega[i])
            if k_lat > 0.0:
                # the massless patch: spring k (d + h d') = friction sum(F0 + c v) - sum(c j . xi_new) - C d'
                rate = (pulls[i] - pulled - k_lat * lateral[i, 0]) / (k_lat * h + grips[i])
                lateral[i, 0] += h * rate
                lateral[i, 1] = rate
        torso[0] += h * xi_new[0]
        torso[1] += h * xi_new[1]
        torso[2] += h * xi_new[2]
        wb0 = rot[0, 0] * xi_new[3] + rot[1, 0] * xi_new[4] + rot[2, 0] * xi_new[5]
        wb1 = rot[0, 1] * xi_new[3] + rot[1, 1] * xi_new[4] + rot[2, 1] * xi_new[5]
        wb2 = rot[0, 2] * xi_new[3] + rot[1, 2] * xi_new[4] + rot[2, 2] * xi_new[5]
        advance_quaternion(torso, wb0, wb1, wb2, h)
    return n_steps


@njit(cache=True)
def _robot_row(robots, b):
    """Robot ``b`` of a batch's stacked :class:`Robot` (views)."""
    return Robot(
        robots.torso[b], robots.momentum[b], robots.pos[b], robots.eta[b], robots.vel[b], robots.theta[b],
        robots.omega[b], robots.par[b], robots.servo[b], robots.servo_cmd[b], robots.free0[b],
        robots.prev_corner[b], robots.prev_u[b], robots.normal[b], robots.out[b], robots.reaction[b],
        robots.belly[b], robots.lateral[b],
    )  # fmt: skip


@njit(cache=True)
def _work_row(works, b):
    """Robot ``b``'s scratch of a batch's stacked :class:`Work` (views)."""
    return Work(
        works.force[b], works.moment[b], works.rhs[b], works.vflat[b], works.cth[b], works.sth[b],
        works.lu[b], works.kband[b], works.jvec[b], works.jmeta[b], works.fwork[b],
    )  # fmt: skip


@njit(cache=True, parallel=True)
def batch_steps(robots, works, torso_model, leg, settings, f_ext, h, n_steps, done):
    """:func:`coupled_steps` for B robots of one model at once, one thread per robot: every array of
    ``robots`` and ``works`` has a leading axis of length B, as has ``f_ext`` (B, 3); ``done`` (B,)
    receives each robot's completed steps."""
    for b in prange(robots.torso.shape[0]):
        done[b] = coupled_steps(
            _robot_row(robots, b), _work_row(works, b), torso_model, leg, settings, f_ext[b], h, n_steps, False
        )
