"""The soft-leg plant: a rigid torso and four Cosserat legs, coupled both ways (``plant=cosserat``).

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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import prange

from .. import telemetry as T
from ..actuation import tendon_angle_deg
from ..body import advance_quaternion, euler_to_quat, horizontal, quat_to_euler, quat_to_rot, solve_spd
from ..config import PlantConfig, SlotConfig, TorsoConfig, choice_field, num_field
from ..errors import ConfigError, DivergenceError
from ..jit import njit
from ..robot import RobotModel
from ..soft.integrators import divergence_message, implicit_once, jacobian_state, stable_dt, symplectic_once
from ..soft.loads import coulomb_friction, friction_slope, rest_free_length
from ..soft.params import O_DIV, O_F, O_FL, O_FX, O_FZ, O_M, O_N, O_T, OUT, P_MUS, P_VS, leg_params
from ..soft.rod import LegModel, build_leg, lateral_stiffness
from ..soft.servo import RPM_TO_RAD_S, servo_step
from . import PLANTS, TendonCommand

SETTLE_S = 0.4  # s the legs get to settle under the held torso before a run starts
SETTLE_ITERATIONS = 8  # ... in this many steps towards the servo angle that carries the weight
LOWERING_MOVES = 25  # per settling step in the first half, in which the torso is lowered onto its initial pose


def belly_points(torso: TorsoConfig) -> np.ndarray:
    """The torso's points that can touch the ground (body frame): its bottom face's corners, edge midpoints
    and centre with ``robot.torso.ground_contact``, else none."""
    if not torso.ground_contact:
        return np.zeros((0, 3))
    lx, ly, lz = torso.size
    points = np.array([[a * lx / 2, b * ly / 2, -lz / 2] for a in (-1.0, 0.0, 1.0) for b in (-1.0, 0.0, 1.0)])
    return points - horizontal(torso.com_offset)


def pose_between(start: np.ndarray, end: np.ndarray, s: float) -> np.ndarray:
    """Torso position and quaternion (7,) a fraction ``s`` of the way between two poses given as
    position and roll, pitch, yaw (6,)."""
    pose = (1.0 - s) * np.asarray(start, dtype=float) + s * np.asarray(end, dtype=float)
    return np.concatenate([pose[0:3], euler_to_quat(*pose[3:6])])


@njit(cache=True)
def _leg_axes(rot, cy, sy):
    """A leg's direction in the world's vertical: its horizontal unit u = (ux, uy), the direction's height
    component and horizontal length (the leg plane is the vertical plane through the corner along u)."""
    dwx = rot[0, 0] * cy + rot[0, 1] * sy
    dwy = rot[1, 0] * cy + rot[1, 1] * sy
    dwz = rot[2, 0] * cy + rot[2, 1] * sy
    horiz = np.sqrt(dwx * dwx + dwy * dwy)
    return dwx / horiz, dwy / horiz, dwz, horiz


@njit(cache=True)
def _corner_offset(rot, corner):
    """A corner's offset from the torso centre in the world frame."""
    return (
        rot[0, 0] * corner[0] + rot[0, 1] * corner[1] + rot[0, 2] * corner[2],
        rot[1, 0] * corner[0] + rot[1, 1] * corner[1] + rot[1, 2] * corner[2],
        rot[2, 0] * corner[0] + rot[2, 1] * corner[1] + rot[2, 2] * corner[2],
    )


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def _velocity_from_momentum(torso, momentum, rot, aug, scratch, rhs, xi):
    """The torso's velocity (v, w) from the momentum state and the 6x6 inertia ``aug`` at this pose:
    written into ``torso[7:13]`` (w in the body frame) and ``xi`` (w in the world frame)."""
    p0, p1, p2 = torso[0], torso[1], torso[2]
    rhs[0], rhs[1], rhs[2] = momentum[0], momentum[1], momentum[2]
    # angular momentum about the torso centre
    rhs[3] = momentum[3] - (p1 * momentum[2] - p2 * momentum[1])
    rhs[4] = momentum[4] - (p2 * momentum[0] - p0 * momentum[2])
    rhs[5] = momentum[5] - (p0 * momentum[1] - p1 * momentum[0])
    scratch[:, :] = aug
    solve_spd(scratch, rhs, xi)
    torso[7], torso[8], torso[9] = xi[0], xi[1], xi[2]
    for a in range(3):
        torso[10 + a] = rot[0, a] * xi[3] + rot[1, a] * xi[4] + rot[2, a] * xi[5]


@njit(cache=True)
def _belly_contact(point, rot, pz, xi, par, h, load, damp, belly):
    """One of the torso's underside points on the ground: penalty normal force and isotropic Coulomb friction
    (:func:`coulomb_friction`'s law in the plane of the floor), the friction linearised in the torso's velocity
    (its slope into ``damp``, h x the 6x6 on (v, w), as the legs' friction across their planes)."""
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
    belly[0] += nrm
    belly[1] += fx
    belly[2] += fy


@njit(cache=True)
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


@njit(cache=True)
def coupled_steps(
    torso,
    momentum,
    torso_mass,
    inertia,
    gravity,
    corners,
    yaw,
    rest_theta0,
    pos,
    eta,
    vel,
    theta,
    omega,
    rest_pos,
    l0,
    voronoi,
    dtheta0,
    ea,
    ga,
    ei,
    mass,
    inertia_el,
    par,
    servo,
    servo_cmd,
    servo_par,
    pulley,
    free0,
    prev_corner,
    prev_u,
    f_ext,
    mu,
    v_eps,
    implicit,
    max_age,
    h,
    n_steps,
    normal,
    out,
    force,
    moment,
    rhs,
    vflat,
    cth,
    sth,
    lu,
    kband,
    jvec,
    jmeta,
    reaction,
    belly_points,
    belly_par,
    belly,
    lateral,
    k_lat,
    hold_torso,
):
    """Advance torso and four legs ``n_steps`` steps of ``h``.

    The torso's state is its pose (``torso[0:7]``: p, q) and ``momentum`` (6: linear momentum
    and angular momentum about the world origin) of itself and of the legs' motion across their
    planes (:func:`augmented_inertia`); ``torso[7:13]`` (v, w_body) is derived from them at every
    step. Each step: the legs' planes follow the torso (:func:`_sync_legs`); each leg steps in its
    plane with its root on the corner; the leg's root force and moment, and the friction its
    pressed nodes feel across the plane (implicit in the torso's velocity), change the momentum;
    the pose moves with the new velocity. Every exchange between a leg and the torso is applied
    to both, so without ground and gravity the robot's momentum holds to round-off.

    ``cth``/``sth`` (4, E) are each leg's directors, kept current by the symplectic step;
    ``lu``, ``kband``, ``jvec``, ``jmeta`` each leg's Jacobian state for the implicit step,
    whose factorisation serves up to ``max_age`` steps (:func:`implicit_once`).

    ``eta`` (4, N) is each node's offset across its leg's plane (:func:`_sync_legs`).
    ``reaction`` (4, 6) receives each leg's force and moment on the torso (world) at the last
    step, its friction across the plane included. ``belly_points`` (P, 3) are the torso's points that
    touch the ground (body frame; none: no torso contact), ``belly_par`` their (stiffness, damping, mu,
    v_eps), and ``belly`` (3,) receives their normal and friction force (x, y) at the last step.
    ``lateral`` (4, 2) is each leg's contact patch's deflection across its plane and its rate, on a
    spring of ``k_lat`` N/m in series with the patch's friction (:func:`_series_spring`; 0: rigid, the
    patch moves with the torso and ``lateral`` stays zero). With ``hold_torso`` the torso stays where it
    is, at rest (the legs settle under it). Returns the number of steps done (< n_steps on divergence).
    """
    n_legs = pos.shape[0]
    n_nodes = pos.shape[1]
    inv_mass = 1.0 / mass
    inv_inertia = 1.0 / inertia_el
    root = np.zeros(6)
    vlat = np.zeros(n_nodes)
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
    for step in range(n_steps + 1):
        rot = quat_to_rot(torso[3:7])
        _sync_legs(torso, momentum, rot, corners, cy, sy, pos, eta, vel, omega, mass, inertia_el, prev_corner, prev_u)
        if hold_torso:
            momentum[:] = 0.0
            torso[7:13] = 0.0
            xi[:] = 0.0
        else:
            augmented_inertia(torso, rot, torso_mass, inertia, corners, cy, sy, pos, mass, aug)
            _velocity_from_momentum(torso, momentum, rot, aug, system, rhs6, xi)
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
            servo[i] = servo_step(
                servo[i], servo_cmd[i], h, servo_par[0], out[i, O_T] * pulley, servo_par[1], servo_par[2], servo_par[3]
            )
            free_length = free0[i] - pulley * servo[i]  # the cable the servo leaves out
            if implicit:
                implicit_once(
                    pos[i],
                    vel[i],
                    theta[i],
                    omega[i],
                    rest_pos,
                    l0,
                    voronoi,
                    dtheta0,
                    ea,
                    ga,
                    ei,
                    mass,
                    inertia_el,
                    par[i],
                    free_length,
                    root,
                    vlat,
                    h,
                    normal[i],
                    out[i],
                    force,
                    moment,
                    lu[i],
                    kband[i],
                    jvec[i],
                    jmeta[i],
                    max_age,
                    rhs,
                    vflat,
                    cth[i],
                    sth[i],
                )
            else:
                symplectic_once(
                    pos[i],
                    vel[i],
                    theta[i],
                    omega[i],
                    rest_pos,
                    l0,
                    voronoi,
                    dtheta0,
                    ea,
                    ga,
                    ei,
                    mass,
                    inertia_el,
                    inv_mass,
                    inv_inertia,
                    par[i],
                    free_length,
                    root,
                    vlat,
                    h,
                    normal[i],
                    out[i],
                    force,
                    moment,
                    cth[i],
                    sth[i],
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
            for k in range(1, n_nodes):
                f0s[k] = 0.0
                slopes[i, k] = 0.0
                nrm = normal[i, k]
                if nrm <= 0.0:
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
                if normal[i, k] <= 0.0:
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
            _belly_contact(belly_points[j], rot, torso[2], xi, belly_par, h, load, damp, belly)
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


@njit(cache=True, parallel=True)
def batch_steps(
    torso,
    momentum,
    torso_mass,
    inertia,
    gravity,
    corners,
    yaw,
    rest_theta0,
    pos,
    eta,
    vel,
    theta,
    omega,
    rest_pos,
    l0,
    voronoi,
    dtheta0,
    ea,
    ga,
    ei,
    mass,
    inertia_el,
    par,
    servo,
    servo_cmd,
    servo_par,
    pulley,
    free0,
    prev_corner,
    prev_u,
    f_ext,
    mu,
    v_eps,
    implicit,
    max_age,
    h,
    n_steps,
    normal,
    out,
    force,
    moment,
    rhs,
    vflat,
    cth,
    sth,
    lu,
    kband,
    jvec,
    jmeta,
    reaction,
    belly_points,
    belly_par,
    belly,
    lateral,
    k_lat,
    done,
):
    """:func:`coupled_steps` for B robots of one model at once, one thread per robot: every per-robot
    array has a leading axis of length B; ``done`` (B,) receives each robot's completed steps."""
    for b in prange(torso.shape[0]):
        done[b] = coupled_steps(
            torso[b],
            momentum[b],
            torso_mass,
            inertia,
            gravity,
            corners,
            yaw,
            rest_theta0,
            pos[b],
            eta[b],
            vel[b],
            theta[b],
            omega[b],
            rest_pos,
            l0,
            voronoi,
            dtheta0,
            ea,
            ga,
            ei,
            mass,
            inertia_el,
            par[b],
            servo[b],
            servo_cmd[b],
            servo_par,
            pulley,
            free0[b],
            prev_corner[b],
            prev_u[b],
            f_ext[b],
            mu,
            v_eps,
            implicit,
            max_age,
            h,
            n_steps,
            normal[b],
            out[b],
            force[b],
            moment[b],
            rhs[b],
            vflat[b],
            cth[b],
            sth[b],
            lu[b],
            kband[b],
            jvec[b],
            jmeta[b],
            reaction[b],
            belly_points,
            belly_par,
            belly[b],
            lateral[b],
            k_lat,
            False,
        )


@dataclass
class CosseratPlantConfig(PlantConfig):
    """The soft plant's settings (``plant.*`` with ``plant=cosserat``)."""

    name: str = "cosserat"
    # implicit (linearly implicit Euler, stable at 1e-4 s and above) or symplectic (dt <~ 3e-5 s)
    integrator: str = choice_field("implicit", "implicit", "symplectic")
    # implicit step: steps a factored Jacobian may serve (1: a fresh one every step); a change of contact,
    # friction regime or tendon state refreshes it sooner (slotexp/soft/integrators.py)
    jacobian_age: int = num_field(1, lo=1, hi=100000, unit="steps")


@PLANTS.register()
class CosseratPlant:
    """Torso + four soft legs behind the :class:`slotexp.plants.Plant` interface."""

    command_type = TendonCommand
    schema: ClassVar[type] = CosseratPlantConfig
    free_space: ClassVar[bool] = True  # sim.ground=false: the robot in free space (checks of what it conserves)

    @staticmethod
    def check(cfg: SlotConfig) -> None:
        """The laws the chosen step has: static friction and the paper's rod need the right integrator."""
        symplectic = cfg.plant.integrator == "symplectic"
        if symplectic and cfg.robot.contact.static_friction is not None:
            raise ConfigError(
                "robot.contact.static_friction is a law of the implicit step only: drop it, or use "
                "plant.integrator=implicit"
            )
        if cfg.robot.leg.model == "paper" and not symplectic:
            raise ConfigError(
                "robot.leg.model=paper has no Jacobian for the implicit step: add plant.integrator=symplectic "
                "sim.dt=2e-5"
            )

    @classmethod
    def from_config(cls, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> CosseratPlant:
        return cls(cfg, robot, x0)

    def __init__(self, cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> None:
        self.cfg = cfg
        self.robot = robot
        self.dt = cfg.sim.dt
        self.time = 0.0
        self.implicit = cfg.plant.integrator == "implicit"
        leg_cfg = cfg.robot.leg
        self.model: LegModel = build_leg(leg_cfg)
        m = self.model
        n = m.n_nodes
        lx, ly, lz = cfg.robot.torso.size
        # each root node moves with its corner, so its mass rides with the torso
        self.torso_mass = cfg.robot.torso.mass + 4 * m.mass[0]
        self.inertia = self.torso_mass / 12.0 * np.diag([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
        self.yaw = np.deg2rad(np.asarray(leg_cfg.yaw_deg, dtype=float))
        # leg roots on the torso's bottom face, relative to the torso's mass centre
        self.corners = np.column_stack(
            [np.sign(np.cos(self.yaw)) * lx / 2, np.sign(np.sin(self.yaw)) * ly / 2, np.full(4, -lz / 2)]
        ) - horizontal(cfg.robot.torso.com_offset)
        drop = m.rest_pos[0, 1] - m.rest_pos[-1, 1]
        # The torso starts level, with the resting feet just touching the ground; settling lowers it
        # onto the scenario's offset pose (see _settle_legs).
        z0 = lz / 2 + drop + (x0[5] - robot.stance_height)
        self.start_pose = np.array([x0[3], x0[4], lz / 2 + drop, 0.0, 0.0, x0[2]])  # position, roll pitch yaw
        self.target_pose = np.array([x0[3], x0[4], z0, *x0[0:3]])
        self.torso = np.concatenate([pose_between(self.start_pose, self.target_pose, 0.0), np.zeros(6)])
        self.momentum = np.zeros(6)  # linear, and angular about the world origin (coupled_steps)
        rot = quat_to_rot(self.torso[3:7])
        self.pos = np.repeat(m.rest_pos[None], 4, axis=0).copy()
        corner_w = self.torso[0:3] + self.corners @ rot.T
        self.pos[:, :, 1] += (corner_w[:, 2] - m.rest_pos[0, 1])[:, None]
        self.eta = np.zeros((4, n))  # each node's offset across its leg's plane
        self.vel = np.zeros_like(self.pos)
        self.theta = np.repeat(m.rest_theta[None], 4, axis=0).copy()
        self.omega = np.zeros_like(self.theta)
        self.prev_corner = corner_w.copy()
        self.prev_u = np.column_stack([np.cos(self.yaw), np.sin(self.yaw)])  # the planes' directions (level torso)
        self.par = np.tile(leg_params(cfg, ground=cfg.sim.ground), (4, 1))  # one row per leg, no tip load
        # free cable with the servo at zero; the servo angle then sets each leg's free length
        self.free0 = np.full(4, rest_free_length(m, self.par[0], cfg.robot.tendon.slack))
        self.servo = np.zeros(4)  # servo (tendon) angle, rad
        self.servo_cmd = np.zeros(4)
        sc = cfg.robot.servo
        self.servo_par = np.array(
            [
                sc.time_constant,
                sc.stall_torque,
                sc.no_load_speed_rpm * RPM_TO_RAD_S,
                sc.profile_velocity_rpm * RPM_TO_RAD_S,
            ]
        )
        self.belly_points = belly_points(cfg.robot.torso)
        contact = cfg.robot.contact
        mu_belly = contact.friction if cfg.robot.torso.friction is None else cfg.robot.torso.friction
        self.belly_par = np.array([contact.stiffness, contact.damping, mu_belly, contact.slip_velocity])
        self.belly = np.zeros(3)  # the torso's underside on the ground: normal force, friction x, y
        self.k_lat = lateral_stiffness(cfg.robot.leg)  # 0: the legs are rigid across their planes
        self.lateral = np.zeros((4, 2))  # each contact patch's deflection across its plane (m) and its rate
        self.normal = np.zeros((4, n))
        self.out = np.zeros((4, len(OUT)))
        self.reaction = np.zeros((4, 6))
        nd = 3 * n - 1
        # scratch (force, moment, rhs, vflat), the directors, and each leg's implicit-step Jacobian
        self._work = (
            np.zeros((n, 2)),
            np.zeros(n - 1),
            np.zeros(nd),
            np.zeros(nd),
            np.cos(self.theta),
            np.sin(self.theta),
            *jacobian_state(n, 4),
        )
        self.marker_nodes = sorted({0, (n - 1) // 3, 2 * (n - 1) // 3, n - 1})
        self._legs: np.ndarray | None = None  # leg_world's, until the legs next move
        self._settle_legs(SETTLE_S)
        self._release(x0[9:12], x0[6:9])

    # ------------------------------------------------------------------ Plant interface
    def state(self) -> np.ndarray:
        q = self.torso[3:7]
        rot = quat_to_rot(q)
        return np.concatenate([quat_to_euler(q), self.torso[0:3], rot @ self.torso[10:13], self.torso[7:10]])

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        return self.torso[0:3].copy(), self.torso[3:7].copy()

    def _plane(self) -> tuple[np.ndarray, np.ndarray]:
        """Corner world positions (4, 3) and in-plane unit directions (4, 3)."""
        rot = quat_to_rot(self.torso[3:7])
        corners = self.torso[0:3] + self.corners @ rot.T
        d = np.column_stack([np.cos(self.yaw), np.sin(self.yaw), np.zeros(4)]) @ rot.T
        u = d.copy()
        u[:, 2] = 0.0
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        return corners, u

    def leg_world(self) -> np.ndarray:
        """Every node of every leg in the world frame (4, N, 3), read-only: computed once per plant step
        (the controller's feet, the log's markers, shapes and 3D scene all read it)."""
        if self._legs is None:
            corners, u = self._plane()
            lat = np.column_stack([-u[:, 1], u[:, 0], np.zeros(4)])
            out = corners[:, None, :] + self.pos[:, :, 0:1] * u[:, None, :] + self.eta[:, :, None] * lat[:, None, :]
            out[:, :, 2] = self.pos[:, :, 1]
            out.flags.writeable = False
            self._legs = out
        return self._legs

    def feet(self) -> np.ndarray:
        return self.leg_world()[:, -1, :]

    def legs(self) -> np.ndarray:
        return self.leg_world()

    def markers(self) -> dict[str, np.ndarray]:
        legs = self.leg_world()
        out = {"com": self.torso[0:3].copy()}
        for i, name in enumerate(self.robot.names):
            out[f"{name}_foot"] = legs[i, -1]
            for k in self.marker_nodes:
                out[f"{name}_n{k}"] = legs[i, k]
        return out

    def telemetry(self) -> dict[str, dict]:
        """Extra per-step log messages: leg shapes, tendon tension, servo angle, contact."""
        legs = self.leg_world()
        names = self.robot.names
        return {
            T.LEGS_SHAPE: {name: legs[i] for i, name in enumerate(names)},
            T.LEGS_TENDON: {
                "tension_n": self.out[:, O_T].copy(),
                "servo_deg": np.rad2deg(self.servo),
                "command_deg": np.rad2deg(self.servo_cmd),
            },
            # friction_n: the size of the leg's friction, along its plane and across it
            T.LEGS_CONTACT: {
                "normal_n": self.out[:, O_N].copy(),
                "friction_n": np.hypot(self.out[:, O_F], self.out[:, O_FL]),
                "lateral_m": self.lateral[:, 0].copy(),  # the patch's deflection across the plane
            },
            T.LEGS_ROOT: {"force_n": self.reaction[:, 0:3].copy(), "moment_nm": self.reaction[:, 3:6].copy()},
            T.TORSO_CONTACT: {"normal_n": float(self.belly[0]), "friction_n": self.belly[1:3].copy()},
        }

    def _settle_legs(self, seconds: float) -> None:
        """Put the robot down in equilibrium at its initial pose.

        The torso is held, at rest, while the legs settle onto the ground. It starts level
        with the resting feet just touching and is lowered in small moves onto the
        scenario's initial pose over the first half of the settling time: a pose whose
        corner is lower or tilted down puts that leg's resting foot tens of millimetres
        into the ground, and placed there at once the contact folded the leg under the
        body (combined offsets: the front-right foot 144 mm from its root instead of
        250 mm), a state no robot set down on its feet is in. The servos take
        the common angle at which the legs carry the robot's weight there (a few
        Newton steps on the total normal force, with the actuation map's slope), as a
        robot is powered up before it is let go: at zero tendon the legs cannot carry
        it, and a servo at its rated speed needs about 0.3 s to wind in. The robot is
        then released with the scenario's velocities (:meth:`_release`).
        """
        weight = self.robot.mass * self.cfg.sim.gravity
        slope = 4.0 * self.cfg.robot.actuation.slope_n_per_deg
        top = self.cfg.robot.leg.tendon_max_deg
        angle = float(tendon_angle_deg(np.array([weight / 4.0]), self.cfg.robot.actuation, top)[0])
        lowering = SETTLE_ITERATIONS // 2
        for k in range(SETTLE_ITERATIONS):
            self.servo[:] = self.servo_cmd[:] = np.deg2rad(angle)
            if k < lowering:  # in small moves, so that every leg deforms continuously onto the ground
                for s in np.linspace(k, k + 1, LOWERING_MOVES + 1)[1:] / lowering:
                    self.torso[0:7] = pose_between(self.start_pose, self.target_pose, float(s))
                    self._run(seconds / SETTLE_ITERATIONS / LOWERING_MOVES, np.zeros(3), hold=True)
            else:
                self._run(seconds / SETTLE_ITERATIONS, np.zeros(3), hold=True)
            angle = float(np.clip(angle + (weight - self.out[:, O_N].sum()) / slope, 0.0, top))
        self.time = 0.0

    def _release(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """Let the robot go with the torso moving at ``linear`` and ``angular`` (world) velocity: the whole
        robot moves with it as one rigid body (each leg's nodes and elements get the rigid motion of its
        root frame on top of what they had), and the momentum state is the one of that motion."""
        rot = quat_to_rot(self.torso[3:7])
        _, u = self._plane()
        p = self.torso[0:3]
        for i in range(4):
            axis = np.cross(u[i], [0.0, 0.0, 1.0])  # the in-plane angle's axis
            r = self.leg_world()[i] - p
            rigid = linear + np.cross(angular, r)
            self.vel[i, :, 0] += rigid @ u[i]
            self.vel[i, :, 1] += rigid[:, 2]
            self.omega[i] += angular @ axis
        aug = self._augmented_inertia()
        pi = aug @ np.concatenate([linear, angular])
        self.momentum[:] = np.concatenate([pi[0:3], pi[3:6] + np.cross(p, pi[0:3])])
        self.torso[7:10] = linear
        self.torso[10:13] = rot.T @ angular

    def _augmented_inertia(self) -> np.ndarray:
        """The 6x6 inertia of the torso and the legs' motion across their planes (:func:`augmented_inertia`)."""
        out = np.empty((6, 6))
        rot = quat_to_rot(self.torso[3:7])
        augmented_inertia(
            self.torso,
            rot,
            self.torso_mass,
            self.inertia,
            self.corners,
            np.cos(self.yaw),
            np.sin(self.yaw),
            self.pos,
            self.model.mass,
            out,
        )
        return out

    def momentum_world(self) -> tuple[np.ndarray, np.ndarray]:
        """The whole robot's linear momentum and its angular momentum about the world origin, from the
        velocities of every part: the torso, every leg node (along its plane its own velocity, across it
        the torso's rigid motion there) and every element's spin in its plane."""
        p = self.torso[0:3]
        rot = quat_to_rot(self.torso[3:7])
        v = self.torso[7:10]
        w = rot @ self.torso[10:13]
        linear = self.torso_mass * v
        angular = np.cross(p, linear) + rot @ (self.inertia @ self.torso[10:13])
        _, u = self._plane()
        legs = self.leg_world()
        m = self.model.mass[1:, None]
        for i in range(4):
            lat = np.cross([0.0, 0.0, 1.0], u[i])
            r = legs[i, 1:]
            vlat = (v + np.cross(w, r - p)) @ lat
            velocity = self.vel[i, 1:, 0:1] * u[i] + vlat[:, None] * lat
            velocity[:, 2] += self.vel[i, 1:, 1]
            linear = linear + (m * velocity).sum(axis=0)
            angular = angular + np.cross(r, m * velocity).sum(axis=0)
            angular = angular + (self.model.inertia * self.omega[i]).sum() * np.cross(u[i], [0.0, 0.0, 1.0])
        return linear, angular

    def centre_of_mass(self) -> np.ndarray:
        """The whole robot's centre of mass (world): the torso (with the legs' root nodes) and every leg node."""
        m = self.model.mass[1:]
        legs = self.leg_world()[:, 1:]
        total = self.torso_mass * self.torso[0:3] + np.einsum("k,lkj->j", m, legs)
        return total / (self.torso_mass + 4 * m.sum())

    def step(self, command: TendonCommand, period: float, external_force: np.ndarray | None = None) -> None:
        """Advance ``period`` with the servos tracking the commanded angles (ground forces are the legs' own)."""
        self.servo_cmd[:] = np.deg2rad(command.tendon_deg)
        f_ext = np.zeros(3) if external_force is None else np.asarray(external_force, dtype=float)
        self._run(period, f_ext, hold=False)

    def _run(self, period: float, f_ext: np.ndarray, hold: bool) -> None:
        n, h = self._steps(period)
        own = {name: getattr(self, name) for name in _OWN}
        done = coupled_steps(*self._kernel_args(own, self._work, f_ext, h, n), hold)
        self._advanced(done, n, h, "the soft-leg simulation", "the scenario's offsets and impulses")

    def _steps(self, period: float) -> tuple[int, float]:
        """How many steps cover ``period``, and their length (at most ``sim.dt``, equal)."""
        n = max(1, int(round(period / self.dt)))
        return n, period / n

    def _kernel_args(
        self, own: dict[str, np.ndarray], work: tuple[np.ndarray, ...], f_ext: np.ndarray, h: float, n: int
    ) -> tuple:
        """The arguments :func:`coupled_steps` and :func:`batch_steps` share, in their order: this plant's
        model and settings, and the per-robot arrays ``own`` (named as in ``_OWN``) and ``work`` (scratch),
        one robot's or a batch's stacked along a first axis."""
        m = self.model
        return (
            own["torso"],
            own["momentum"],
            self.torso_mass,
            self.inertia,
            self.cfg.sim.gravity,
            self.corners,
            self.yaw,
            float(m.rest_theta[0]),
            own["pos"],
            own["eta"],
            own["vel"],
            own["theta"],
            own["omega"],
            m.rest_pos,
            m.l0,
            m.voronoi,
            m.dtheta0,
            m.ea,
            m.ga,
            m.ei,
            m.mass,
            m.inertia,
            own["par"],
            own["servo"],
            own["servo_cmd"],
            self.servo_par,
            self.cfg.robot.leg.pulley_radius,
            own["free0"],
            own["prev_corner"],
            own["prev_u"],
            f_ext,
            self.cfg.robot.contact.friction,
            self.cfg.robot.contact.slip_velocity,
            self.implicit,
            self.cfg.plant.jacobian_age,
            h,
            n,
            own["normal"],
            own["out"],
            *work,
            own["reaction"],
            self.belly_points,
            self.belly_par,
            own["belly"],
            own["lateral"],
            self.k_lat,
        )

    def _advanced(self, done: int, n: int, h: float, what: str, loads: str) -> None:
        """Count ``done`` of ``n`` steps of ``h``; a run cut short or gone non-finite diverged."""
        self.time += done * h
        self._legs = None  # the legs moved
        if done < n or not np.all(np.isfinite(self.torso)):
            limit = stable_dt(self.model, self.cfg.robot.contact.stiffness)
            raise DivergenceError(
                divergence_message(
                    what, self.time, h, self.cfg.plant.integrator, limit, ("sim.dt", "plant.integrator"), loads, self.dt
                )
            )

    def apply_impulse(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """A push on the torso (world, about its centre): the momentum takes it, the velocity follows."""
        linear = np.asarray(linear, dtype=float)
        self.momentum[0:3] += linear
        self.momentum[3:6] += np.asarray(angular, dtype=float) + np.cross(self.torso[0:3], linear)
        _velocity_from_momentum(
            self.torso,
            self.momentum,
            quat_to_rot(self.torso[3:7]),
            self._augmented_inertia(),
            np.empty((6, 6)),
            np.empty(6),
            np.empty(6),
        )


# each robot's own arrays (state, servo, contact output): a batch stacks them along a first axis
_OWN = (
    "torso",
    "momentum",
    "pos",
    "eta",
    "vel",
    "theta",
    "omega",
    "par",
    "servo",
    "servo_cmd",
    "free0",
    "prev_corner",
    "prev_u",
    "normal",
    "out",
    "reaction",
    "belly",
    "lateral",
)


class CosseratBatch:
    """B soft robots of one config stepped together in one compiled call, one thread per robot.

    For searches and Monte Carlo runs: each robot has its own tendon commands and
    state, and they advance in parallel (numba ``prange``, as many threads as
    ``NUMBA_NUM_THREADS``, every core by default). The robots are ordinary
    :class:`CosseratPlant` objects, set down as usual; the batch moves their state
    into stacked arrays and leaves each plant's attributes as views of its row, so
    ``state()``, ``feet()`` and ``telemetry()`` keep working on every one of them.
    Stepped in a batch or alone, a robot follows the same arithmetic.
    """

    def __init__(self, plants: list[CosseratPlant]) -> None:
        if not plants:
            raise ValueError("a batch needs at least one plant")
        first = plants[0]
        if any(p.cfg is not first.cfg and (p.cfg.robot != first.cfg.robot or p.dt != first.dt) for p in plants):
            raise ValueError("every plant in a batch must share the robot and sim.dt of the first")
        if any(p.cfg.plant != first.cfg.plant for p in plants):
            raise ValueError("every plant in a batch must use the same integrator and Jacobian age")
        self.plants = plants
        self.stacked = {name: np.stack([getattr(p, name) for p in plants]) for name in _OWN}
        self.work = tuple(np.stack([p._work[k] for p in plants]) for k in range(len(first._work)))
        for b, p in enumerate(plants):
            for name, stacked in self.stacked.items():
                setattr(p, name, stacked[b])
            p._work = tuple(w[b] for w in self.work)
        self.f_ext = np.zeros((len(plants), 3))
        self.done = np.zeros(len(plants), dtype=np.int64)

    def __len__(self) -> int:
        return len(self.plants)

    def step(self, tendon_deg: np.ndarray, period: float) -> None:
        """Advance every robot ``period`` with its servos tracking ``tendon_deg`` (B, 4), deg."""
        tendon_deg = np.asarray(tendon_deg, dtype=float)
        if tendon_deg.shape != (len(self), 4):
            raise ValueError(f"tendon_deg must be ({len(self)}, 4), not {tendon_deg.shape}")
        first = self.plants[0]
        self.stacked["servo_cmd"][:] = np.deg2rad(tendon_deg)
        n, h = first._steps(period)
        batch_steps(*first._kernel_args(self.stacked, self.work, self.f_ext, h, n), self.done)
        for b, p in enumerate(self.plants):
            p._advanced(int(self.done[b]), n, h, f"robot {b} of the batch", "its tendon commands")
