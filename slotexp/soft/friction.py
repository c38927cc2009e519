"""The pressed nodes' friction along a leg's plane, solved at the end of the linearly implicit step.

Why: a step that linearises the friction once, at its start, must take its secant slope mu N / |v|
along a slip (the tangent, zero along a straight slip, throws a light node back and forth each
step: :func:`slotexp.soft.loads.friction_slope`). But with that slope a sliding node answers a
change of the force on it as if it weighed h mu N / |v| more than it does, and a sticking one
h mu N / v_eps more: at 1 ms, mu 0.1, N 2 N and 10 mm/s, 20 g against the node's fraction of a
gram. A foot then breaks away over many steps and its slip follows the leg's load late, by a
lag that grows with the step; the robot's yaw, the feet's slips and the torso's height drift
with the step instead of converging to the law's motion.

Solved at the step's end, each pressed node's friction is the law at its end velocity:
:func:`slotexp.soft.loads.coulomb_friction`, within the cone by construction, never reversing a
slip it stops. The step's matrix W is factored without the friction (the normal force's rows
stay); its compliance at the pressed nodes' along-plane velocities, one banded substitution per
pressed node kept with the factorisation (``jvec[2 + i]`` = W^-1 e for node i), turns the step
into a small nonlinear problem in their end velocities v:

    v = b + h D F(v),   D_ak = (W^-1)_{a k},   F_k = coulomb_friction(v_k, v_lat,k, N_k),

with b their end velocities without friction and N the normal forces at the step's start. Newton's
method on the law's tangent (:func:`slotexp.soft.loads.friction_tangent`), with a backtracking line
search on the residual, solves it (for plain Coulomb friction F is monotone, so where W is positive
definite the solution is unique; where it is not, a soft leg curled hard at a large step, or where a
static coefficient makes the law non-monotone, Newton can stop unconverged, and the step counts it:
``J_UNSOLVED``); the impulses h F then move every degree of freedom through D's columns. This is the
Delassus-operator form of the field's contact solvers (MuJoCo's constraint space; Otaduy et al.,
"Implicit contact handling for deformable objects", Eurographics 2009), here with the smooth
regularised law instead of a cone complementarity problem, on the step's own linearisation (the
elastic forces once a step, as the rest of the step).
"""

from __future__ import annotations

import numpy as np

from ..jit import njit
from .loads import coulomb_friction, friction_tangent

NEWTON_ITERATIONS = 50  # Newton iterations at most (a node that switches between sticking and sliding takes a few)
# the residual (m/s) at which the solve stops, relative to the slip velocity: far below anything the step resolves
TOLERANCE = 1e-9
# the scratch's rows after Newton's n x n matrix: the pressed nodes' indices, velocities, friction-free end
# velocities, residual, friction, Newton's step, and a line search's trial velocities, friction and residual
ROW_INDEX, ROW_V, ROW_B, ROW_R, ROW_F, ROW_DV, ROW_VT, ROW_FT, ROW_RT = range(9)


def friction_work(n_nodes: int, lead: tuple[int, ...] = ()) -> np.ndarray:
    """Scratch for :func:`solve_friction` on a leg of ``n_nodes`` nodes (Newton's matrix and its vectors)."""
    return np.zeros(lead + (n_nodes + 9, n_nodes))


@njit(cache=True, allocates=False)
def _dense_solve(a, b, n):
    """``b[:n]`` := A^-1 ``b[:n]`` for A = ``a[:n, :n]`` (overwritten): Gaussian elimination, partial pivoting."""
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(a[i, k]) > abs(a[p, k]):
                p = i
        if p != k:
            for j in range(n):
                a[k, j], a[p, j] = a[p, j], a[k, j]
            b[k], b[p] = b[p], b[k]
        for i in range(k + 1, n):
            f = a[i, k] / a[k, k]
            for j in range(k + 1, n):
                a[i, j] -= f * a[k, j]
            b[i] -= f * b[k]
    for k in range(n - 1, -1, -1):
        acc = b[k]
        for j in range(k + 1, n):
            acc -= a[k, j] * b[j]
        b[k] = acc / a[k, k]


@njit(cache=True, allocates=False)
def _residual(fw, jvec, nc, v, f, r, normal, vlat, h, mu, v_eps, mu_s, v_s):
    """r = v - b - h D F(v) (F into ``f``) for the pressed nodes listed in ``fw``; returns |r|^2."""
    n = fw.shape[1]
    idx = fw[n + ROW_INDEX]
    b = fw[n + ROW_B]
    for k in range(nc):
        i = int(idx[k])
        f[k], _ = coulomb_friction(v[k], vlat[i], normal[i], mu, v_eps, mu_s, v_s)
    total = 0.0
    for a in range(nc):
        dof = 3 * int(idx[a])
        acc = v[a] - b[a]
        for k in range(nc):
            acc -= h * jvec[2 + int(idx[k]), dof] * f[k]
        r[a] = acc
        total += acc * acc
    return total


@njit(cache=True, allocates=False)
def solve_friction(jvec, pressed, vstart, dv, normal, vlat, h, mu, v_eps, mu_s, v_s, fw):
    """The pressed nodes' friction along the plane at the step's end, added to the step's velocity change.

    ``pressed`` (N,) is 1 at the pressed nodes (the regimes the factorisation was made with), ``jvec[2 + i]``
    their columns of W^-1, ``vstart`` (3N - 1) the velocities at the step's start, ``dv`` (3N - 1) the
    step's velocity change without friction (updated in place), ``normal`` (N,) the normal forces, ``vlat``
    (N,) the slips across the plane, ``fw`` :func:`friction_work`'s scratch. Returns (the friction's total
    force along the plane, N; Newton's iterations, ``NEWTON_ITERATIONS`` + 1 where it did not converge).
    """
    n = fw.shape[1]
    idx = fw[n + ROW_INDEX]
    v, b, r, f, step = fw[n + ROW_V], fw[n + ROW_B], fw[n + ROW_R], fw[n + ROW_F], fw[n + ROW_DV]
    vt, ft, rt = fw[n + ROW_VT], fw[n + ROW_FT], fw[n + ROW_RT]
    nc = 0
    for i in range(1, n):
        if pressed[i] == 1.0:
            idx[nc] = i
            dof = 3 * i
            b[nc] = vstart[dof] + dv[dof]
            v[nc] = vstart[dof]  # from the start's slip: a sticking node stays near it
            nc += 1
    if nc == 0:
        return 0.0, 0
    tol2 = (TOLERANCE * v_eps) ** 2 * nc
    merit = _residual(fw, jvec, nc, v, f, r, normal, vlat, h, mu, v_eps, mu_s, v_s)
    iterations = 0
    while merit > tol2:
        if iterations == NEWTON_ITERATIONS:
            iterations += 1
            break
        iterations += 1
        for k in range(nc):
            i = int(idx[k])
            t = friction_tangent(v[k], vlat[i], normal[i], mu, v_eps, mu_s, v_s)
            for a in range(nc):
                fw[a, k] = -h * jvec[2 + i, 3 * int(idx[a])] * t
            fw[k, k] += 1.0
        for a in range(nc):
            step[a] = -r[a]
        _dense_solve(fw, step, nc)
        lam = 1.0
        while True:  # backtracking: the full step, or the first half that lowers the residual enough
            for a in range(nc):
                vt[a] = v[a] + lam * step[a]
            trial = _residual(fw, jvec, nc, vt, ft, rt, normal, vlat, h, mu, v_eps, mu_s, v_s)
            if trial < (1.0 - 1e-4 * lam) * merit or lam < 1e-6:
                break
            lam *= 0.5
        for a in range(nc):
            v[a] = vt[a]
            f[a] = ft[a]
            r[a] = rt[a]
        merit = trial
    total = 0.0
    for k in range(nc):
        total += f[k]
        col = jvec[2 + int(idx[k])]
        impulse = h * f[k]
        for d in range(dv.shape[0]):
            dv[d] += impulse * col[d]
    return total, iterations
