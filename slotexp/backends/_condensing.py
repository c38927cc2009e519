"""Numba kernels of the condensed QP (``condensed.py`` explains the formulation).

Each kernel does one stage in compiled loops so that a whole MPC update costs a
few Python calls rather than dozens of small NumPy ones: the per-step budget is a
fraction of a millisecond. ``cache=True`` compiles once per machine.
"""

from __future__ import annotations

import numpy as np

from ..jit import njit
from ..mpc import _model_steps, _rollout

INF = 1.0e30  # DAQP's infinity
RANK_TOL = 1.0e-9  # relative singular-value threshold of the wrench map
# m: two steps share a force basis when their loaded feet sit at the same places relative to each other
# (to rounding: per-step lever arms are footholds minus a moving CoM, exact to ~1e-16 m per metre)
SAME_FEET_TOL = 1.0e-12
EQUALITY = 5  # DAQP sense: active + immutable
ROWS_PER_STEP = 21  # 4 legs x (f_z bounds + 4 friction rows) + balance


def horizon_coefficients(h: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scalar weights of the four Kronecker terms of the condensed Hessian.

    With A_d^s = I + s T A_c, the block (j, l) of Gamma^T Q Gamma is
    c0 B'QB + c1[j,l] B'QC + c1[l,j] C'QB + c2 C'QC (C = T A_c B), summed over the
    steps k = max(j, l) + 1 .. h that both inputs reach.
    """
    c0, c1, c2 = np.zeros((h, h)), np.zeros((h, h)), np.zeros((h, h))
    for j in range(h):
        for l in range(h):
            for k in range(max(j, l) + 1, h + 1):
                c0[j, l] += 1.0
                c1[j, l] += k - 1 - l
                c2[j, l] += (k - 1 - j) * (k - 1 - l)
    return c0, c1, c2


@njit(cache=True)
def force_mask(mu: np.ndarray, fz_min: np.ndarray, fz_max: np.ndarray) -> tuple[np.ndarray, bool]:
    """(H, 12) components that are decision variables, and whether the bounds are consistent.

    A component is dropped when its bounds force it to zero: f_z with fz_max = 0,
    f_x and f_y with mu = 0 or f_z dropped.
    """
    h = mu.shape[0]
    mask = np.zeros((h, 12), dtype=np.bool_)
    consistent = True
    for k in range(h):
        for leg in range(4):
            consistent = consistent and fz_min[k, leg] <= fz_max[k, leg]
            fz = fz_max[k, leg] > 0.0
            fxy = fz and mu[k, leg] > 0.0
            mask[k, 3 * leg] = fxy
            mask[k, 3 * leg + 1] = fxy
            mask[k, 3 * leg + 2] = fz
    return mask, consistent


@njit(cache=True)
def _same_feet(mask: np.ndarray, arms: np.ndarray, k: int, j: int) -> bool:
    """Steps k and j keep the same forces and their loaded feet are placed alike relative to each other.

    The wrench map's row space (what the basis splits) depends on the loaded feet's
    relative positions only: moving every lever arm by the same vector (the CoM
    moving under fixed feet) adds a multiple of the net force to the torque rows.
    """
    for c in range(12):
        if mask[k, c] != mask[j, c]:
            return False
    first = -1
    for leg in range(4):
        if not mask[k, 3 * leg + 2]:
            continue
        if first < 0:
            first = leg
            continue
        for i in range(3):
            dk = arms[k, leg, i] - arms[k, first, i]
            dj = arms[j, leg, i] - arms[j, first, i]
            if abs(dk - dj) > SAME_FEET_TOL:
                return False
    return True


@njit(cache=True)
def structure(mask: np.ndarray, wrench: np.ndarray, arms: np.ndarray):
    """Per-step bases that split the kept forces into wrench and internal directions.

    ``mask`` (H, 12) marks the force components that are decision variables;
    ``wrench`` (H, 6, 12) maps each step's forces to what the dynamics see (net
    force and torque, rows 6:12 of B_k); ``arms`` (H, 4, 3) are the lever arms.
    Steps with the same kept forces and the same relative feet (:func:`_same_feet`)
    form a class p; ``basis[p]`` (12, 12) holds in its first ``da[p]`` columns an
    orthonormal basis of the row space of the class's wrench map restricted to the
    kept components, and in the next ``db[p]`` columns one of its null space
    (internal forces, invisible to the dynamics). With one B for the horizon the
    classes are the contact patterns. Returns (class of each step, basis, da, db,
    offsets of a and b per step, rows).
    """
    h = mask.shape[0]
    rep = np.zeros(h, dtype=np.int64)  # the first step of each class
    pid = np.zeros(h, dtype=np.int64)
    count = 0
    for k in range(h):
        found = -1
        for p in range(count):
            if _same_feet(mask, arms, k, rep[p]):
                found = p
                break
        if found < 0:
            rep[count] = k
            found = count
            count += 1
        pid[k] = found
    basis = np.zeros((count, 12, 12))
    da = np.zeros(count, dtype=np.int64)
    db = np.zeros(count, dtype=np.int64)
    for p in range(count):
        cols = np.flatnonzero(mask[rep[p]])
        n = cols.shape[0]
        if n == 0:
            continue
        sub = np.empty((6, n))
        for i in range(n):
            sub[:, i] = wrench[rep[p], :, cols[i]]
        _, s, vt = np.linalg.svd(sub)
        rank = 0
        for i in range(s.shape[0]):
            if s[i] > s[0] * RANK_TOL:
                rank += 1
        for i in range(n):
            for c in range(n):
                basis[p, cols[c], i] = vt[i, c]
        da[p] = rank
        db[p] = n - rank
    a_off = np.zeros(h + 1, dtype=np.int64)
    b_off = np.zeros(h + 1, dtype=np.int64)
    rows = 0
    for k in range(h):
        a_off[k + 1] = a_off[k] + da[pid[k]]
        b_off[k + 1] = b_off[k] + db[pid[k]]
        n_fz = 0
        for leg in range(4):
            if mask[k, 3 * leg + 2]:
                n_fz += 1
                rows += 1
            if mask[k, 3 * leg]:
                rows += 4
        if n_fz > 0:
            rows += 1
    return pid, basis, da, db, a_off, b_off, rows


@njit(cache=True)
def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Two 6 x 6 matrices are equal entry for entry (stops at the first difference)."""
    for i in range(6):
        for j in range(6):
            if a[i, j] != b[i, j]:
                return False
    return True


@njit(cache=True)
def condense(
    a_c: np.ndarray,
    b_d: np.ndarray,
    g_d: np.ndarray,
    x0: np.ndarray,
    x_ref: np.ndarray,
    q: np.ndarray,
    rho: float,
    period: float,
    basis: np.ndarray,
    da: np.ndarray,
    pid: np.ndarray,
    a_off: np.ndarray,
    c0: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    same: np.ndarray,
):
    """Hessian H (na, na) and gradient f of the QP in the wrench coordinates a (states eliminated).

    0.5 a'Ha + f'a is the objective up to a constant (and a factor 2); the internal
    coordinates b only carry r |b|^2, so their Hessian is r I.

    ``b_d`` (H, 12, 12) holds B_k per step. Forces enter the model only through the
    wrench rows, so B_k = G W_k with W_k = B_k[6:12] and G = Gamma_T[:, 6:12] / T
    fixed over the horizon (Gamma_T = I T + A_c T^2 / 2; A_c's rows 6:12 and B_c's
    rows 0:6 are zero). With R_k = W_k V_k (6 x da) and C = T A_c G, the block (j, l)
    of the condensed Hessian is R_j' [c0 G'QG + c1[j,l] G'QC + c1[l,j] C'QG + c2 C'QC] R_l:
    three 6 x 6 Gram matrices per update, then one small product per pair of steps, or,
    when few steps differ in R_k (one B for the horizon), R_g' S R_g' per pair of groups
    and a weighted sum per pair of steps. ``same[k]``: B_k is step k-1's (R_k is then too,
    within a class).
    """
    h = x_ref.shape[0]
    ta = period * a_c
    if np.max(np.abs(ta @ ta)) != 0.0 or np.max(np.abs(a_c[6:12])) != 0.0:
        raise ValueError("condensing needs a nilpotent A_c (A_c @ A_c = 0) with no state feeding the rates")
    g_map = np.ascontiguousarray(np.eye(12)[:, 6:12] + 0.5 * ta[:, 6:12])
    c_map = ta @ g_map
    qg = q.reshape(12, 1) * g_map
    qc = q.reshape(12, 1) * c_map
    s00 = g_map.T @ qg
    s01 = g_map.T @ qc
    s10 = np.ascontiguousarray(s01.T)
    s11 = c_map.T @ qc
    # R_k, its columns past da zero; steps with the same R_k form a group (with one B for the horizon the
    # groups are the contact patterns; walking with per-step arms, every step is its own)
    r = np.zeros((h, 6, 6))
    grp = np.zeros(h, dtype=np.int64)
    first = np.zeros(h, dtype=np.int64)
    n_grp = 0
    for k in range(h):
        if k > 0 and same[k] and pid[k] == pid[k - 1]:
            r[k] = r[k - 1]
            grp[k] = grp[k - 1]
            continue
        d = da[pid[k]]
        r[k, :, :d] = np.ascontiguousarray(b_d[k, 6:12]) @ np.ascontiguousarray(basis[pid[k], :, :d])
        grp[k] = -1
        for g in range(n_grp):
            if pid[first[g]] == pid[k] and _same(r[first[g]], r[k]):
                grp[k] = g
                break
        if grp[k] < 0:
            first[n_grp] = k
            grp[k] = n_grp
            n_grp += 1
    na = a_off[h]
    hess = np.zeros((na, na))
    if 4 * n_grp * n_grp <= h * (h + 1) // 2:
        # few groups: their four Gram matrices R_g' S R_g' once, then a weighted sum per pair of steps
        gram = np.empty((n_grp, n_grp, 4, 6, 6))
        for g in range(n_grp):
            rg = np.ascontiguousarray(r[first[g]].T)
            for g2 in range(n_grp):
                r2 = r[first[g2]]
                gram[g, g2, 0], gram[g, g2, 1] = rg @ (s00 @ r2), rg @ (s01 @ r2)
                gram[g, g2, 2], gram[g, g2, 3] = rg @ (s10 @ r2), rg @ (s11 @ r2)
        for j in range(h):
            dj, oj = da[pid[j]], a_off[j]
            for l in range(j, h):
                dl, ol = da[pid[l]], a_off[l]
                w0, w1, w2, w3 = c0[j, l], c1[j, l], c1[l, j], c2[j, l]
                blk = gram[grp[j], grp[l]]
                for a in range(dj):
                    for c in range(dl):
                        val = w0 * blk[0, a, c] + w1 * blk[1, a, c] + w2 * blk[2, a, c] + w3 * blk[3, a, c]
                        hess[oj + a, ol + c] = val
                        hess[ol + c, oj + a] = val
    else:
        # R_j' [weighted S] R_l for every pair, the S R_l once per step
        t00, t01, t10, t11 = np.empty((h, 6, 6)), np.empty((h, 6, 6)), np.empty((h, 6, 6)), np.empty((h, 6, 6))
        for k in range(h):
            t00[k], t01[k], t10[k], t11[k] = s00 @ r[k], s01 @ r[k], s10 @ r[k], s11 @ r[k]
        mid = np.empty((6, 6))
        for j in range(h):
            dj, oj = da[pid[j]], a_off[j]
            for l in range(j, h):
                dl, ol = da[pid[l]], a_off[l]
                w0, w1, w2, w3 = c0[j, l], c1[j, l], c1[l, j], c2[j, l]
                for m in range(6):
                    for c in range(dl):
                        mid[m, c] = w0 * t00[l, m, c] + w1 * t01[l, m, c] + w2 * t10[l, m, c] + w3 * t11[l, m, c]
                for a in range(dj):
                    for c in range(dl):
                        acc = 0.0
                        for m in range(6):
                            acc += r[j, m, a] * mid[m, c]
                        hess[oj + a, ol + c] = acc
                        hess[ol + c, oj + a] = acc
    for i in range(na):
        hess[i, i] += rho
    # free response x_k = x0 + k (T A_c x0 + g) + k (k - 1) / 2 T A_c g, weighted errors w_k
    drift = ta @ x0 + g_d
    curve = ta @ g_d
    werr = np.empty((h, 12))
    for k in range(1, h + 1):
        werr[k - 1] = q * (x0 + k * drift + 0.5 * k * (k - 1) * curve - x_ref[k - 1])
    grad = np.zeros(na)
    s0 = np.zeros(12)  # sum_{k > j} w_k
    s1 = np.zeros(12)  # sum_{k > j} (k - 1 - j) w_k
    for j in range(h - 1, -1, -1):
        s1 = s1 + s0
        s0 = s0 + werr[j]
        d, o = da[pid[j]], a_off[j]
        grad[o : o + d] = (r[j].T @ (g_map.T @ s0 + c_map.T @ s1))[:d]
    return hess, grad


@njit(cache=True)
def row_layout(
    mask: np.ndarray, mu: np.ndarray, fz_min: np.ndarray, fz_max: np.ndarray, weight: float, band: float, rows: int
):
    """Every constraint row: bounds, DAQP sense, identity, and the force terms it combines.

    Row r is ``sum_j coef[r, j] * u[step[r], comp[r, j]]`` (up to four terms) within
    [lo, hi]. Identity ``step * ROWS_PER_STEP + leg * 5 + j`` (j: 0 f_z bounds, 1-4
    f_x -, f_x +, f_y -, f_y + friction) or ``step * ROWS_PER_STEP + 20`` (balance)
    lets rows be matched across MPC steps. Returns (lo, hi, sense, identity, step,
    comp, coef, trivially infeasible: a step with no force left but a load to carry).
    """
    lo, hi = np.empty(rows), np.empty(rows)
    sense, ident, step = np.zeros(rows, np.int32), np.zeros(rows, np.int64), np.zeros(rows, np.int64)
    comp, coef = np.zeros((rows, 4), np.int64), np.zeros((rows, 4))
    r = 0
    infeasible = False
    for k in range(mask.shape[0]):
        n_fz = 0
        for leg in range(4):
            cz = 3 * leg + 2
            if not mask[k, cz]:
                continue
            n_fz += 1
            step[r], ident[r], comp[r, 0], coef[r, 0] = k, k * ROWS_PER_STEP + 5 * leg, cz, 1.0
            lo[r], hi[r] = fz_min[k, leg], fz_max[k, leg]
            r += 1
            if not mask[k, 3 * leg]:
                continue
            for ax in range(2):
                for side in range(2):  # f_ax - mu f_z <= 0, f_ax + mu f_z >= 0
                    step[r], ident[r] = k, k * ROWS_PER_STEP + 5 * leg + 1 + 2 * ax + side
                    comp[r, 0], coef[r, 0] = 3 * leg + ax, 1.0
                    comp[r, 1], coef[r, 1] = cz, (2.0 * side - 1.0) * mu[k, leg]
                    lo[r], hi[r] = (-INF, 0.0) if side == 0 else (0.0, INF)
                    r += 1
        if n_fz == 0:
            infeasible = infeasible or weight - band > 0.0
            continue
        step[r], ident[r] = k, k * ROWS_PER_STEP + 20
        j = 0
        for leg in range(4):
            if mask[k, 3 * leg + 2]:
                comp[r, j], coef[r, j] = 3 * leg + 2, 1.0
                j += 1
        lo[r], hi[r] = weight - band, weight + band
        r += 1
    for i in range(rows):
        sense[i] = EQUALITY if lo[i] == hi[i] else 0
    return lo, hi, sense, ident, step, comp, coef, infeasible


@njit(cache=True)
def solver_rows(
    chosen: np.ndarray,
    step: np.ndarray,
    comp: np.ndarray,
    coef: np.ndarray,
    chol: np.ndarray,
    basis: np.ndarray,
    da: np.ndarray,
    db: np.ndarray,
    pid: np.ndarray,
    a_off: np.ndarray,
    b_off: np.ndarray,
) -> np.ndarray:
    """The chosen rows in the solver's variables (z = L' a, b): a-part by forward substitution with L.

    A row g'a + h'b becomes (L^-1 g)'z + h'b. g is non-zero only in its step's
    block, so the substitution starts there.
    """
    na = chol.shape[0]
    nb = b_off[b_off.shape[0] - 1]
    out = np.zeros((chosen.shape[0], na + nb))
    g = np.zeros(12)
    for i in range(chosen.shape[0]):
        r = chosen[i]
        k = step[r]
        p, d, e, ao, bo = pid[k], da[pid[k]], db[pid[k]], a_off[k], na + b_off[k]
        g[:] = 0.0
        for j in range(4):
            if coef[r, j] != 0.0:
                for c in range(d + e):
                    g[c] += coef[r, j] * basis[p, comp[r, j], c]
        row = out[i]
        for c in range(e):
            row[bo + c] = g[d + c]
        for t in range(ao, na):
            acc = g[t - ao] if t < ao + d else 0.0
            for s in range(ao, t):
                acc -= chol[t, s] * row[s]
            row[t] = acc / chol[t, t]
    return out


@njit(cache=True)
def forward(chol: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """L^-1 rhs (L lower triangular)."""
    n = chol.shape[0]
    out = np.empty(n)
    for t in range(n):
        acc = rhs[t]
        for s in range(t):
            acc -= chol[t, s] * out[s]
        out[t] = acc / chol[t, t]
    return out


@njit(cache=True)
def backward(chol: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """L'^-1 rhs (L lower triangular)."""
    n = chol.shape[0]
    out = np.empty(n)
    for t in range(n - 1, -1, -1):
        acc = rhs[t]
        for s in range(t + 1, n):
            acc -= chol[s, t] * out[s]
        out[t] = acc / chol[t, t]
    return out


@njit(cache=True)
def build(
    x: np.ndarray,
    lever_arms: np.ndarray,
    mass: float,
    inertia_inv: np.ndarray,
    gravity: float,
    period: float,
    x_ref: np.ndarray,
    mu: np.ndarray,
    fz_min: np.ndarray,
    fz_max: np.ndarray,
    q: np.ndarray,
    rho: float,
    c0: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    weight: float,
    band: float,
):
    """Everything a step needs before the solver, in one compiled call.

    Model (B_k per step from ``lever_arms`` (H, 4, 3)), kept forces, per-class
    bases, condensed Hessian H = L L' (Cholesky) and the linear term L^-1 f of the
    solver's variables z = L' a, and the row layout.
    """
    a_c, a_d, b_d, g_d, same = _model_steps(x, lever_arms, mass, inertia_inv, gravity, period)
    mask, consistent = force_mask(mu, fz_min, fz_max)
    pid, basis, da, db, a_off, b_off, rows = structure(mask, np.ascontiguousarray(b_d[:, 6:12]), lever_arms)
    hess, grad = condense(a_c, b_d, g_d, x, x_ref, q, rho, period, basis, da, pid, a_off, c0, c1, c2, same)
    chol = np.linalg.cholesky(hess) if hess.shape[0] else np.zeros((0, 0))
    lin = forward(chol, grad)
    layout = row_layout(mask, mu, fz_min, fz_max, weight, band, rows)
    return (a_d, b_d, g_d, mask, consistent, pid, basis, da, db, a_off, b_off, chol, lin) + layout


@njit(cache=True)
def finish(
    sol: np.ndarray,
    chol: np.ndarray,
    basis: np.ndarray,
    da: np.ndarray,
    db: np.ndarray,
    pid: np.ndarray,
    a_off: np.ndarray,
    b_off: np.ndarray,
    x: np.ndarray,
    a_d: np.ndarray,
    b_d: np.ndarray,
    g_d: np.ndarray,
    x_ref: np.ndarray,
    q_report: np.ndarray,
    r_report: float,
):
    """Forces u_k = basis_k [a_k; b_k] with a = L'^-1 z, the predicted states and the reported objective."""
    h = pid.shape[0]
    na = chol.shape[0]
    a = backward(chol, np.ascontiguousarray(sol[:na]))
    u = np.zeros((h, 12))
    for k in range(h):
        p, d, e, ao, bo = pid[k], da[pid[k]], db[pid[k]], a_off[k], na + b_off[k]
        for c in range(12):
            acc = 0.0
            for i in range(d):
                acc += basis[p, c, i] * a[ao + i]
            for i in range(e):
                acc += basis[p, c, d + i] * sol[bo + i]
            u[k, c] = acc
    xs, cost = _rollout(x, u, a_d, b_d, g_d, x_ref, q_report, r_report)
    return u, xs, cost


@njit(cache=True)
def row_values(u: np.ndarray, step: np.ndarray, comp: np.ndarray, coef: np.ndarray, out: np.ndarray) -> None:
    """Each constraint row's value at the forces ``u`` (H, 12)."""
    for r in range(step.shape[0]):
        acc = 0.0
        for j in range(4):
            acc += coef[r, j] * u[step[r], comp[r, j]]
        out[r] = acc


@njit(cache=True)
def initial_rows(
    sense: np.ndarray, row_id: np.ndarray, h: int, prev_ids: np.ndarray, prev_sense: np.ndarray, warm: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Rows DAQP starts with, and their working-set flags.

    Equality rows always; with ``warm``, the previous optimum's active rows moved
    one step earlier (flagged active with their side) and in place (candidates).
    """
    n = row_id.shape[0]
    lookup = np.full((h + 1) * ROWS_PER_STEP, -1, dtype=np.int64)
    for r in range(n):
        lookup[row_id[r]] = r
    flags = np.zeros(n, dtype=np.int32)
    chosen = np.zeros(n, dtype=np.bool_)
    for r in range(n):
        if sense[r] == EQUALITY:
            flags[r] = EQUALITY
            chosen[r] = True
    if warm:
        for i in range(prev_ids.shape[0]):
            here = lookup[prev_ids[i]]
            if here >= 0:
                chosen[here] = True
            if prev_ids[i] >= ROWS_PER_STEP:
                earlier = lookup[prev_ids[i] - ROWS_PER_STEP]
                if earlier >= 0 and flags[earlier] != EQUALITY:
                    flags[earlier] = prev_sense[i]
                    chosen[earlier] = True
    rows = np.flatnonzero(chosen)
    return rows, flags[rows]
