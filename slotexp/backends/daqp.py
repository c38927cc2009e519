"""Condensed QP on the forces alone, solved by the DAQP dense active-set solver (``solver=daqp``, the default).

Formulation (same minimiser as the sparse QP of :mod:`slotexp.mpc`):

1. **States eliminated.** x_k = x_free,k + sum_j A^(k-1-j) B_j u_j, with B_j each
   step's input matrix (seed 001's footholds of step j, or one B for the whole
   horizon). Because A_c @ A_c = 0, A_d^s = I + s T A_c exactly, and the forces
   reach the states only through each step's 6-D wrench, B_j = G W_j with G fixed;
   so the condensed Hessian is three fixed 6x6 Gram matrices weighted by scalars
   (``_condensing.horizon_coefficients``) between each pair of steps' wrench maps,
   instead of a dense H x H product of 12 x 12 blocks.
2. **Forces that must be zero removed.** A component is dropped from the decision
   vector when its bounds force it to zero: f_z with fz_max = 0 (swing legs when
   ``gait.swing_contact=false``, the MIT-controller trick) and f_x, f_y with mu = 0
   or f_z removed. SLOT's default keeps every leg loaded, so nothing is dropped there.
3. **Wrench / internal split.** The dynamics see the 12 forces of a step only
   through a 6-D wrench (net force and torque). An orthonormal change of variables
   per step, u_k = V_k [a_k; b_k], separates the wrench directions a (coupled
   across the horizon) from the internal-force directions b (null space of the
   wrench map, costed only by r |b|^2). The dense Hessian is then 6H x 6H instead
   of 12H x 12H (8x less to factor), and the b block is r I. V_k depends only on
   which forces are kept and where the loaded feet are relative to each other, so
   it is computed once per class of such steps (a few per horizon), not per step.
4. **LDP form.** H_a = L L' is factored (LAPACK Cholesky inside a numba kernel) and
   the variables z = L' a given to DAQP with a diagonal Hessian (I for z, r I for
   b), so DAQP skips its own O(n^3) factorisation; a constraint row g'a + h'b
   becomes (L^-1 g)'z + h'b, one forward substitution per row that DAQP is given.
5. **Constraint screening, warm-started from the previous active set.** Of the
   ~315 rows only 2-10 are active at the optimum (measured on perturbed walks),
   while DAQP's cost per update grows with rows x variables. DAQP is therefore
   given only the rows active at the previous step (shifted one step forward,
   flagged as its initial working set) plus the equality rows; the forces it
   returns are checked against every row, violated rows are added, and it is
   solved again until none is violated. The relaxation's optimum that satisfies
   every constraint is the optimum of the full QP, so the result is exact (to
   eps_abs); an infeasible subset proves the full QP infeasible. After
   ``MAX_ROUNDS`` rounds every row is used at once.
"""

from __future__ import annotations

import time

import daqp
import numpy as np

from ..config import MpcConfig, SolverConfig
from ..gait import ContactPlan
from ..mpc import MpcSolution, failed_solution, remaining, solution_from_rollout, step_lever_arms
from . import BACKENDS
from ._base import MpcBackend, single_threaded_blas
from ._condensing import EQUALITY, INF, build, finish, horizon_coefficients, initial_rows, row_values, solver_rows

# A vanishing ridge so the condensed QP stays strictly convex when mpc.r_weight = 0
# (relative to the scaled weights, far below any solver tolerance).
MIN_RIDGE = 1.0e-12
EXIT_STATUS = {
    1: "optimal",
    2: "optimal",
    -1: "infeasible",
    -2: "cycling",
    -3: "unbounded",
    -4: "iteration_limit",
    -5: "nonconvex",
    -6: "degenerate_start",
    -7: "time_limit",
}
RETRY_COLD = {-2, -6}
ACTIVE_UPPER, ACTIVE_LOWER = 1, 3  # DAQP sense flags of a warm-start working set
MAX_ROUNDS = 25  # screening rounds before solving with every row at once
CAPACITY = 16  # rows the persistent DAQP model holds before it is set up again, larger
NO_ACTIVE = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int32))


def daqp_settings(solver: SolverConfig) -> dict:
    """Shared settings as DAQP options (an active-set solution is exact: eps_rel has no counterpart).

    The time limit is set per solve to what is left of the update's deadline.
    """
    return {"primal_tol": solver.eps_abs, "iter_limit": int(solver.max_iters)}


@BACKENDS.register()
class CondensedMpc(MpcBackend):
    """States eliminated, zero-forced forces removed, dense QP solved by DAQP with screened rows."""

    objective_rtol = 1e-6  # an active-set solution: exact
    violation_tol = 1e-6

    def __init__(
        self, cfg: MpcConfig, solver: SolverConfig, mass: float, inertia_body: np.ndarray, gravity: float
    ) -> None:
        super().__init__(cfg, solver, mass, inertia_body, gravity)
        self.band = float(cfg.force_balance_band)
        scale = cfg.objective_scale
        self.q = np.asarray(cfg.q_diag, dtype=float) * scale
        self.rho = max(cfg.r_weight * scale, MIN_RIDGE)
        self.coeffs = horizon_coefficients(cfg.horizon)
        self.settings = daqp_settings(solver)
        self._active = NO_ACTIVE  # (row identities, DAQP sense) active at the previous optimum
        self._model: daqp.Model | None = None
        self._pad: tuple[np.ndarray, ...] = ()
        self._dummy = np.zeros((0, 0))
        self._dims = (0, 0)
        self._used = 0
        single_threaded_blas()

    def solve(self, x: np.ndarray, x_ref: np.ndarray, lever_arms: np.ndarray, plan: ContactPlan) -> MpcSolution:
        """Solve for the forces; ``x_ref`` is (H, 12), ``plan`` arrays are (H, 4)."""
        start = time.perf_counter()
        as_f64 = np.ascontiguousarray
        x, x_ref = as_f64(x, dtype=float), as_f64(x_ref, dtype=float)
        mu, fz_min, fz_max = (
            as_f64(plan.mu, dtype=float),
            as_f64(plan.fz_min, dtype=float),
            as_f64(plan.fz_max, dtype=float),
        )
        try:
            (
                a_d,
                b_d,
                g_d,
                _mask,
                consistent,
                pid,
                basis,
                da,
                db,
                a_off,
                b_off,
                chol,
                lin,
                lo,
                hi,
                sense,
                row_id,
                step,
                comp,
                coef,
                infeasible,
            ) = build(
                x,
                step_lever_arms(lever_arms, self.cfg.horizon),
                self.mass,
                self.inertia_inv,
                self.gravity,
                self.period,
                x_ref,
                mu,
                fz_min,
                fz_max,
                self.q,
                self.rho,
                *self.coeffs,
                self.weight,
                self.band,
            )
        except np.linalg.LinAlgError:  # the condensed Hessian is not positive definite
            return self._fail("solver_error", 0, 0.0, start)
        if not consistent or infeasible:
            return self._fail("infeasible", 0, 0.0, start)
        na, nb = int(a_off[-1]), int(b_off[-1])
        f = np.concatenate([lin, np.zeros(nb)])
        values = np.empty(lo.shape[0])
        tol = self.solver_cfg.eps_abs
        chosen, flags = initial_rows(sense, row_id, self.cfg.horizon, *self._active, self.solver_cfg.warm_start)
        iterations, solve_time = 0, 0.0
        for rounds in range(MAX_ROUNDS + 1):
            if rounds == MAX_ROUNDS:  # screening did not settle: every row at once
                chosen, flags = np.arange(lo.shape[0]), sense.copy()
            rows = solver_rows(chosen, step, comp, coef, chol, basis, da, db, pid, a_off, b_off)
            sol, exitflag, lam, its, secs = self._daqp(
                (na, nb), f, rows, hi[chosen], lo[chosen], flags, sense[chosen], start
            )
            iterations, solve_time = iterations + its, solve_time + secs
            if exitflag <= 0:
                return self._fail(EXIT_STATUS.get(exitflag, "solver_error"), iterations, solve_time, start)
            u, xs, cost = finish(sol, chol, basis, da, db, pid, a_off, b_off, x, a_d, b_d, g_d, x_ref, *self.weights)
            row_values(u, step, comp, coef, values)
            violated = np.flatnonzero((values > hi + tol) | (values < lo - tol))
            if violated.size == 0 or rounds == MAX_ROUNDS:
                break
            # keep the working set DAQP ended with, add the violated rows as candidates
            flags = np.concatenate(
                [np.where(lam > 0, ACTIVE_UPPER, np.where(lam < 0, ACTIVE_LOWER, 0)), np.zeros(violated.size)]
            ).astype(np.int32)
            flags[: chosen.size][sense[chosen] == EQUALITY] = EQUALITY
            chosen = np.concatenate([chosen, violated])
        on = lam != 0.0
        self._active = (row_id[chosen[on]], np.where(lam[on] > 0, ACTIVE_UPPER, ACTIVE_LOWER).astype(np.int32))
        return solution_from_rollout(
            u, xs, cost, EXIT_STATUS[exitflag], iterations, solve_time, start, self.solver_cfg.time_limit_s
        )

    def _fail(self, status: str, iterations: int, solve_time: float, started: float) -> MpcSolution:
        self._active = NO_ACTIVE
        return failed_solution(self.cfg.horizon, status, iterations, solve_time, started)

    def _daqp(
        self,
        dims: tuple[int, int],
        f: np.ndarray,
        rows: np.ndarray,
        hi: np.ndarray,
        lo: np.ndarray,
        flags: np.ndarray,
        base: np.ndarray,
        started: float,
    ) -> tuple[np.ndarray, int, np.ndarray, int, float]:
        """One DAQP solve of the chosen rows from working set ``flags``; retried cold if that start is unusable.

        The DAQP model is kept between solves with room for ``CAPACITY`` rows or more
        (unused ones are unbounded rows that never become active), so a solve is an
        in-place ``update`` rather than a new setup.
        """
        m = rows.shape[0]
        iterations, solve_time = 0, 0.0
        for sense in (flags, base):
            self._load(dims, f, rows, hi, lo, sense)
            if self.solver_cfg.time_limit_s > 0:
                self._model.settings = {"time_limit": remaining(started, self.solver_cfg.time_limit_s)}
            sol, _, exitflag, info = self._model.solve()
            iterations += int(info["iterations"])
            solve_time += float(info["solve_time"])
            if int(exitflag) not in RETRY_COLD:
                break
        return np.asarray(sol), int(exitflag), np.asarray(info["lam"])[:m], iterations, solve_time

    def _load(
        self, dims: tuple[int, int], f: np.ndarray, rows: np.ndarray, hi: np.ndarray, lo: np.ndarray, sense: np.ndarray
    ) -> None:
        m, n = rows.shape
        if self._model is None or dims != self._dims or m > self._pad[0].shape[0]:
            cap = max(CAPACITY, 2 * m)
            dummy = np.zeros((cap, n))
            dummy[np.arange(cap), np.arange(cap) % n] = 1.0  # unit rows, unbounded: never active
            self._dummy = dummy
            self._pad = (dummy.copy(), np.full(cap, INF), np.full(cap, -INF), np.zeros(cap, np.int32))
            self._used = 0
            self._fill(f, rows, hi, lo, sense, m)
            self._model = daqp.Model()
            self._model.setup(np.diag(np.concatenate([np.ones(dims[0]), np.full(dims[1], self.rho)])), f, *self._pad)
            self._model.settings = self.settings
            self._dims = dims
            return
        self._fill(f, rows, hi, lo, sense, m)
        self._model.update(f=f, A=self._pad[0], bupper=self._pad[1], blower=self._pad[2], sense=self._pad[3])

    def _fill(self, f: np.ndarray, rows: np.ndarray, hi: np.ndarray, lo: np.ndarray, sense: np.ndarray, m: int) -> None:
        """Chosen rows first; rows no longer used go back to unbounded dummies."""
        a, upper, lower, flags = self._pad
        a[:m], upper[:m], lower[:m], flags[:m] = rows, hi, lo, sense
        if self._used > m:
            a[m : self._used] = self._dummy[m : self._used]
            upper[m : self._used], lower[m : self._used], flags[m : self._used] = INF, -INF, 0
        self._used = m
