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
search on the residual, solves it; for plain Coulomb friction F is monotone, so where D's symmetric
part is positive definite the solution is unique. Where a static coefficient makes the law
non-monotone, Newton can stall on a fold of the residual: nonlinear Gauss-Seidel sweeps then move the
iterate (each node's own equation, the others' friction held, always has a root, bracketed by the
cone) and Newton starts again from there. Where D's symmetric part is indefinite (W indefinite: a
soft leg curled hard at a large step) the problem is not dissipative, its roots need not be unique,
and the solve stops at Newton's iterate and says so (the step counts it: ``J_UNSOLVED``). Each
residual is solved to ``TOLERANCE`` v_eps or to its own rounding. The impulses h F then move every
degree of freedom through D's columns. This is the
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
ROUNDS = 10  # Newton, and up to nine times more after Gauss-Seidel's sweeps where it stalls
GS_SWEEPS = 40  # nonlinear Gauss-Seidel sweeps between Newton's rounds
GS_ITERATIONS = 80  # a node's own equation: safeguarded Newton (bisection where its step leaves the bracket)
# the residual (m/s) at which the solve stops, relative to the slip velocity: far below anything the step resolves
TOLERANCE = 1e-9
# ... or within this many machine epsilons of the sizes the residual sums (its rounding floor: a soft leg's pressed
# nodes can carry impulses whose velocities are 10^4 times the tolerance's)
ROUNDING = 64.0
EPSILON = float(np.finfo(np.float64).eps)
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
def _within(residual, size, v_eps):
    """Whether a residual (m/s) is solved: within ``TOLERANCE`` v_eps or, where the terms it sums are large (their
    sizes' sum ``size``), within their rounding, ``ROUNDING`` machine epsilons of it, below which nothing can go."""
    return abs(residual) <= max(TOLERANCE * v_eps, ROUNDING * EPSILON * size)


@njit(cache=True, allocates=False)
def _residual(fw, jvec, nc, v, f, r, normal, vlat, h, mu, v_eps, mu_s, v_s):
    """r = v - b - h D F(v) (F into ``f``) for the pressed nodes listed in ``fw``.

    Returns (|r|^2, whether every r_a is solved: :func:`_within`)."""
    n = fw.shape[1]
    idx = fw[n + ROW_INDEX]
    b = fw[n + ROW_B]
    for k in range(nc):
        i = int(idx[k])
        f[k], _ = coulomb_friction(v[k], vlat[i], normal[i], mu, v_eps, mu_s, v_s)
    total = 0.0
    done = True
    for a in range(nc):
        dof = 3 * int(idx[a])
        acc = v[a] - b[a]
        size = abs(v[a]) + abs(b[a])
        for k in range(nc):
            term = h * jvec[2 + int(idx[k]), dof] * f[k]
            acc -= term
            size += abs(term)
        r[a] = acc
        total += acc * acc
        if not _within(acc, size, v_eps):
            done = False
    return total, done


@njit(cache=True, allocates=False)
def _newton(fw, jvec, nc, merit, normal, vlat, h, mu, v_eps, mu_s, v_s):
    """Newton's iterations on the law's tangent from ``fw``'s iterate (its residual ``merit``), with a backtracking
    line search: until converged, ``NEWTON_ITERATIONS``, or a step that no longer lowers the residual. Returns
    (|r|^2, converged, iterations)."""
    n = fw.shape[1]
    idx = fw[n + ROW_INDEX]
    v, r, f, step = fw[n + ROW_V], fw[n + ROW_R], fw[n + ROW_F], fw[n + ROW_DV]
    vt, ft, rt = fw[n + ROW_VT], fw[n + ROW_FT], fw[n + ROW_RT]
    done = False
    for iteration in range(NEWTON_ITERATIONS):
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
            trial, done = _residual(fw, jvec, nc, vt, ft, rt, normal, vlat, h, mu, v_eps, mu_s, v_s)
            if trial < (1.0 - 1e-4 * lam) * merit or done:
                break
            if lam < 1e-6:  # stalled (a fold of the residual: W indefinite, or the static coefficient's fall)
                return merit, False, iteration + 1
            lam *= 0.5
        for a in range(nc):
            v[a] = vt[a]
            f[a] = ft[a]
            r[a] = rt[a]
        merit = trial
        if done:
            return merit, True, iteration + 1
    return merit, False, NEWTON_ITERATIONS


@njit(cache=True, allocates=False)
def _node_velocity(x, c, d, vlat, nrm, mu, v_eps, mu_s, v_s):
    """A root of g(x) = x - c - d F(x), one node's equation with the others' friction held, searched from ``x``.
    |F| <= mu N brackets the roots in c -/+ |d| mu N, where g changes sign, so one is always found: Newton's
    steps where they stay inside the bracket, halvings where not."""
    top = max(mu, mu_s) * nrm * abs(d)
    lo, hi = c - top, c + top
    x = min(max(x, lo), hi)
    for _ in range(GS_ITERATIONS):
        f, _ = coulomb_friction(x, vlat, nrm, mu, v_eps, mu_s, v_s)
        g = x - c - d * f
        if _within(g, abs(x) + abs(c) + abs(d * f), v_eps):
            break
        if g > 0.0:
            hi = x
        else:
            lo = x
        slope = 1.0 - d * friction_tangent(x, vlat, nrm, mu, v_eps, mu_s, v_s)
        trial = x - g / slope if slope != 0.0 else lo
        x = trial if lo < trial < hi else 0.5 * (lo + hi)
    return x


@njit(cache=True, allocates=False)
def _gauss_seidel(fw, jvec, nc, normal, vlat, h, mu, v_eps, mu_s, v_s):
    """One sweep of nonlinear Gauss-Seidel: each pressed node's velocity solved with the others' friction held,
    its friction updated before the next node's (projected Gauss-Seidel's order, on the smooth law)."""
    n = fw.shape[1]
    idx = fw[n + ROW_INDEX]
    v, b, f = fw[n + ROW_V], fw[n + ROW_B], fw[n + ROW_F]
    for a in range(nc):
        i = int(idx[a])
        dof = 3 * i
        c = b[a]
        for k in range(nc):
            if k != a:
                c += h * jvec[2 + int(idx[k]), dof] * f[k]
        v[a] = _node_velocity(v[a], c, h * jvec[2 + i, dof], vlat[i], normal[i], mu, v_eps, mu_s, v_s)
        f[a], _ = coulomb_friction(v[a], vlat[i], normal[i], mu, v_eps, mu_s, v_s)


@njit(cache=True, allocates=False)
def _dissipative(fw, jvec, nc):
    """Whether D, at the ``nc`` pressed nodes listed in ``fw``, has a positive definite symmetric part (Cholesky of
    (D + D^T) / 2 in ``fw``'s matrix): then the friction's impulses take energy out, the problem has one
    solution, and each node's own equation one root near the others'. Where it has not (W indefinite: a soft
    leg curled hard at a large step) the linearised step is no dissipative problem, and a root found far from
    the start's slip can throw the leg."""
    n = fw.shape[1]
    idx = fw[n + ROW_INDEX]
    for a in range(nc):
        for k in range(nc):
            fw[a, k] = 0.5 * (jvec[2 + int(idx[k]), 3 * int(idx[a])] + jvec[2 + int(idx[a]), 3 * int(idx[k])])
    for k in range(nc):
        for j in range(k):
            fw[k, k] -= fw[k, j] * fw[k, j]
        if fw[k, k] <= 0.0:
            return False
        fw[k, k] = np.sqrt(fw[k, k])
        for i in range(k + 1, nc):
            for j in range(k):
                fw[i, k] -= fw[i, j] * fw[k, j]
            fw[i, k] /= fw[k, k]
    return True


@njit(cache=True, allocates=False)
def _list_pressed(pressed, fw):
    """The pressed nodes' indices into ``fw``'s index row; returns how many."""
    n = fw.shape[1]
    idx = fw[n + ROW_INDEX]
    nc = 0
    for i in range(1, n):
        if pressed[i] == 1.0:
            idx[nc] = i
            nc += 1
    return nc


@njit(cache=True, allocates=False)
def friction_dissipative(jvec, pressed, fw):
    """Whether the factorisation's compliance at its ``pressed`` nodes makes the friction's problem dissipative
    (:func:`_dissipative`); true with none pressed. The step takes one that is not as a step too large."""
    return _dissipative(fw, jvec, _list_pressed(pressed, fw))


@njit(cache=True, allocates=False)
def solve_friction(jvec, pressed, vstart, dv, normal, vlat, h, mu, v_eps, mu_s, v_s, fw):
    """The pressed nodes' friction along the plane at the step's end, added to the step's velocity change.

    ``pressed`` (N,) is 1 at the pressed nodes (the regimes the factorisation was made with), ``jvec[2 + i]``
    their columns of W^-1, ``vstart`` (3N - 1) the velocities at the step's start, ``dv`` (3N - 1) the
    step's velocity change without friction (updated in place), ``normal`` (N,) the normal forces, ``vlat``
    (N,) the slips across the plane, ``fw`` :func:`friction_work`'s scratch. Newton first; where it stalls or
    runs out, ``GS_SWEEPS`` sweeps of nonlinear Gauss-Seidel move the iterate (each node's own equation always
    has a root) and Newton starts again from there, ``ROUNDS`` times at most. Returns (the friction's total
    force along the plane, N; Newton's iterations and sweeps; whether it converged).
    """
    n = fw.shape[1]
    idx = fw[n + ROW_INDEX]
    v, b, r, f = fw[n + ROW_V], fw[n + ROW_B], fw[n + ROW_R], fw[n + ROW_F]
    nc = _list_pressed(pressed, fw)
    for k in range(nc):
        dof = 3 * int(idx[k])
        b[k] = vstart[dof] + dv[dof]
        v[k] = vstart[dof]  # from the start's slip: a sticking node stays near it
    if nc == 0:
        return 0.0, 0, True
    merit, done = _residual(fw, jvec, nc, v, f, r, normal, vlat, h, mu, v_eps, mu_s, v_s)
    iterations = 0
    if not done:
        merit, done, iterations = _newton(fw, jvec, nc, merit, normal, vlat, h, mu, v_eps, mu_s, v_s)
    # Newton stalled: Gauss-Seidel's sweeps, then Newton again from where they end (only where the problem is
    # dissipative: elsewhere a root far from the start's slip can throw the leg)
    if not done and _dissipative(fw, jvec, nc):
        for _ in range(ROUNDS - 1):
            for _ in range(GS_SWEEPS):
                _gauss_seidel(fw, jvec, nc, normal, vlat, h, mu, v_eps, mu_s, v_s)
                iterations += 1
                merit, done = _residual(fw, jvec, nc, v, f, r, normal, vlat, h, mu, v_eps, mu_s, v_s)
                if done:
                    break
            if done:
                break
            merit, done, k = _newton(fw, jvec, nc, merit, normal, vlat, h, mu, v_eps, mu_s, v_s)
            iterations += k
            if done:
                break
    total = 0.0
    for k in range(nc):
        total += f[k]
        col = jvec[2 + int(idx[k])]
        impulse = h * f[k]
        for d in range(dv.shape[0]):
            dv[d] += impulse * col[d]
    return total, iterations, done
