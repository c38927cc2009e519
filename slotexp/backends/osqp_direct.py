"""Sparse QP handed to OSQP directly: built once, only values updated in place (``solver=osqp_direct``).

Seed 001's "Solver matrices": the decision vector is [e_1 .. e_H, u_0 .. u_{H-1}]
with e_k = x_k - x*_k the deviation from the reference (eq. 37), so the objective
is the diagonal sum e'Qe + r u'u with no linear term, and the references, x_0 and
g enter only the equality bounds: e_{k+1} - A e_k - B u_k = A x*_k + g - x*_{k+1}
(x*_0 = x_0, e_0 = 0).

The constraint matrix is built a single time with every entry that can ever be
non-zero kept as a structural entry (also while its value is 0): A's attitude
block (T E^-1, the only state-dependent part of A), every entry of each step's B_k (lever arms
and world inertia), and the friction-cone coefficients mu of every leg and step
(swing or stance, even mu = 0). Each step then calls
``update(Ax=values, Ax_idx=positions)`` on that fixed pattern plus new bounds
``l``/``u`` (x_0, references, force bounds), and warm-starts from the previous
solution shifted by one step.

Scaling: the paper's weights span 1e-8 (forces) to 0.1 (height) and the states
1e-3..1e-1 while the forces are ~5 N. Deviation states keep every state variable
near zero, ``mpc.objective_scale`` (x1000) lifts the objective away from the
tolerances, OSQP's Ruiz equilibration and adaptive rho do the rest, and
polishing turns the ADMM iterate into the exact solution of its active set.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import osqp
import scipy.sparse as sp
from osqp.interface import SolverStatus

from ..config import MpcConfig, SolverConfig
from ..gait import ContactPlan
from ..mpc import DiscreteModel, MpcSolution, failed_solution, remaining, solution_from_inputs, step_lever_arms
from . import BACKENDS
from ._base import MpcBackend

STATUS = {
    SolverStatus.OSQP_SOLVED: "optimal",
    SolverStatus.OSQP_SOLVED_INACCURATE: "optimal_inaccurate",
    SolverStatus.OSQP_PRIMAL_INFEASIBLE: "infeasible",
    SolverStatus.OSQP_PRIMAL_INFEASIBLE_INACCURATE: "infeasible_inaccurate",
    SolverStatus.OSQP_DUAL_INFEASIBLE: "unbounded",
    SolverStatus.OSQP_DUAL_INFEASIBLE_INACCURATE: "unbounded_inaccurate",
    SolverStatus.OSQP_MAX_ITER_REACHED: "iteration_limit",
    SolverStatus.OSQP_TIME_LIMIT_REACHED: "time_limit",
    SolverStatus.OSQP_NON_CVX: "nonconvex",
}
N = 12  # states, and forces, per step


def osqp_settings(solver: SolverConfig) -> dict:
    """Shared settings as OSQP options (the time limit is set per solve to what is left of the deadline)."""
    opts = dict(
        eps_abs=solver.eps_abs,
        eps_rel=solver.eps_rel,
        max_iter=int(solver.max_iters),
        warm_starting=bool(solver.warm_start),
        polishing=True,
        verbose=bool(solver.verbose),
        check_termination=5,
    )
    return opts


def _patterns() -> tuple[np.ndarray, np.ndarray]:
    """Structural entries of A_d and B_d (the model's sparsity, whatever the state)."""
    a = np.eye(N, dtype=bool)
    a[0:3, 6:9] = True  # T E^-1 (attitude)
    a[3:6, 9:12] = np.eye(3, dtype=bool)  # T I (position <- velocity)
    b = np.zeros((N, N), dtype=bool)
    b[0:3, :] = True  # T^2/2 E^-1 I_w^-1 [r]x
    b[6:9, :] = True  # T I_w^-1 [r]x
    for leg in range(4):
        b[3:6, 3 * leg : 3 * leg + 3] |= np.eye(3, dtype=bool)  # T^2/(2m)
        b[9:12, 3 * leg : 3 * leg + 3] |= np.eye(3, dtype=bool)  # T/m
    return a, b


@BACKENDS.register()
class OsqpMpc(MpcBackend):
    """OSQP on the sparse QP, set up once; each step updates values on a fixed sparsity pattern."""

    # stops at eps 1e-5 (its polish does not always succeed): the objective moves by up to a few 1e-3, and
    # its own criterion eps_abs + eps_rel |Az| is 2.2e-4 N on a balance row
    objective_rtol = 5e-3
    violation_tol = 5e-4
    first_order = True

    def __init__(
        self, cfg: MpcConfig, solver: SolverConfig, mass: float, inertia_body: np.ndarray, gravity: float
    ) -> None:
        super().__init__(cfg, solver, mass, inertia_body, gravity)
        self.settings = osqp_settings(solver)
        h = self.h = cfg.horizon
        self.nx = N * h
        self._build_pattern(h)
        weight = self.mass * self.gravity
        band = float(cfg.force_balance_band)
        scale = cfg.objective_scale
        self.p = sp.diags(
            np.concatenate([np.tile(np.asarray(cfg.q_diag, float) * scale, h), np.full(N * h, cfg.r_weight * scale)])
        ).tocsc()
        # constant parts of the bounds: friction rows one-sided, balance rows the band
        self.lower = np.zeros(self.m)
        self.upper = np.zeros(self.m)
        self.lower[self.friction_le] = -np.inf
        self.upper[self.friction_ge] = np.inf
        self.lower[self.balance] = weight - band
        self.upper[self.balance] = weight + band
        self._solver: osqp.OSQP | None = None
        self._previous: tuple[np.ndarray, np.ndarray] | None = None

    def _build_pattern(self, h: int) -> None:
        """Row/column of every structural entry, tagged with where its value comes from."""
        a_mask, b_mask = _patterns()
        ar, ac = np.nonzero(a_mask)
        br, bc = np.nonzero(b_mask)
        rows, cols, kind = [], [], []  # kind: 0 constant (value in `const`), 1 A entry, 2 B entry, 3 mu entry
        const, src_r, src_c, src_k, src_leg, sign = [], [], [], [], [], []

        def add(
            r: int,
            c: int,
            k: int,
            value: float = 0.0,
            sr: int = 0,
            sc: int = 0,
            step: int = 0,
            leg: int = 0,
            s: float = 0.0,
        ) -> None:
            rows.append(r), cols.append(c), kind.append(k), const.append(value)
            src_r.append(sr), src_c.append(sc), src_k.append(step), src_leg.append(leg), sign.append(s)

        nx = self.nx
        for k in range(h):
            for i in range(N):
                add(N * k + i, N * k + i, 0, 1.0)  # e_{k+1}
            if k > 0:
                for r, c in zip(ar, ac):
                    add(N * k + r, N * (k - 1) + c, 1, sr=r, sc=c)  # -A e_k
            for r, c in zip(br, bc):
                add(N * k + r, nx + N * k + c, 2, sr=r, sc=c, step=k)  # -B_k u_k
        row = N * h
        fz_rows, le, ge, balance = [], [], [], []
        for k in range(h):
            for leg in range(4):
                z = nx + N * k + 3 * leg + 2
                add(row, z, 0, 1.0)
                fz_rows.append(row)
                row += 1
                for ax in range(2):
                    for s, group in ((-1.0, le), (1.0, ge)):  # f_x,y -+ mu f_z  <= 0 / >= 0
                        add(row, nx + N * k + 3 * leg + ax, 0, 1.0)
                        add(row, z, 3, step=k, leg=leg, s=s)
                        group.append(row)
                        row += 1
            for leg in range(4):
                add(row, nx + N * k + 3 * leg + 2, 0, 1.0)
            balance.append(row)
            row += 1
        self.m = row
        n = 2 * nx
        rows_a, cols_a = np.asarray(rows), np.asarray(cols)
        order = np.lexsort((rows_a, cols_a))  # CSC storage order
        self.pattern = sp.csc_matrix((np.ones(len(rows)), (rows_a, cols_a)), shape=(self.m, n))
        if self.pattern.nnz != len(rows):  # pragma: no cover - guards edits to the pattern
            raise RuntimeError("duplicate structural entries in the OSQP pattern")
        kind_s = np.asarray(kind)[order]
        self.const = np.asarray(const)[order]
        self.idx_a = np.flatnonzero(kind_s == 1)
        self.idx_b = np.flatnonzero(kind_s == 2)
        self.idx_mu = np.flatnonzero(kind_s == 3)
        self.idx_var = np.concatenate([self.idx_a, self.idx_b, self.idx_mu]).astype(np.int32)
        sr, sc = np.asarray(src_r)[order], np.asarray(src_c)[order]
        self.a_src = (sr[self.idx_a], sc[self.idx_a])
        self.b_src = (np.asarray(src_k)[order][self.idx_b], sr[self.idx_b], sc[self.idx_b])
        self.mu_src = (np.asarray(src_k)[order][self.idx_mu], np.asarray(src_leg)[order][self.idx_mu])
        self.mu_sign = np.asarray(sign)[order][self.idx_mu]
        self.fz_rows = np.asarray(fz_rows)
        self.friction_le, self.friction_ge = np.asarray(le), np.asarray(ge)
        self.balance = np.asarray(balance)

    def _values(self, model: DiscreteModel, mu: np.ndarray) -> np.ndarray:
        """New values of the variable entries, in the order of ``idx_var``."""
        return np.concatenate([-model.a[self.a_src], -model.b[self.b_src], self.mu_sign * mu[self.mu_src]])

    def _bounds(
        self, x: np.ndarray, x_ref: np.ndarray, model: DiscreteModel, plan: ContactPlan
    ) -> tuple[np.ndarray, np.ndarray]:
        previous = np.vstack([x, x_ref[:-1]])
        rhs = (previous @ model.a.T + model.g - x_ref).ravel()
        lower, upper = self.lower.copy(), self.upper.copy()
        lower[: self.nx] = rhs
        upper[: self.nx] = rhs
        lower[self.fz_rows] = plan.fz_min.ravel()
        upper[self.fz_rows] = plan.fz_max.ravel()
        return lower, upper

    def _shifted(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The previous primal/dual solution moved one step forward (last step repeated)."""
        if self._previous is None:
            return None
        z, y = self._previous
        nx, h = self.nx, self.h

        def shift(v: np.ndarray, width: int) -> np.ndarray:
            blocks = v.reshape(h, width)
            return np.vstack([blocks[1:], blocks[-1:]]).ravel()

        zs = np.concatenate([shift(z[:nx], N), shift(z[nx:], N)])
        per_step = (self.m - nx) // h
        ys = np.concatenate([shift(y[:nx], N), shift(y[nx:], per_step)])
        return zs, ys

    def solve(self, x: np.ndarray, x_ref: np.ndarray, lever_arms: np.ndarray, plan: ContactPlan) -> MpcSolution:
        """Solve for the forces; ``x_ref`` is (H, 12), ``plan`` arrays are (H, 4)."""
        start = time.perf_counter()
        as_f64 = np.ascontiguousarray
        x, x_ref = as_f64(x, dtype=float), as_f64(x_ref, dtype=float)
        model = DiscreteModel(
            x, step_lever_arms(lever_arms, self.h), self.mass, self.inertia_inv, self.gravity, self.period
        )
        values = self._values(model, np.asarray(plan.mu, dtype=float))
        lower, upper = self._bounds(x, x_ref, model, plan)
        if self._solver is None:
            data = self.const.copy()
            data[self.idx_var] = values
            a = sp.csc_matrix((data, self.pattern.indices, self.pattern.indptr), shape=self.pattern.shape)
            self._solver = osqp.OSQP()
            self._solver.setup(self.p, np.zeros(self.p.shape[0]), a, lower, upper, **self.settings)
        else:
            self._solver.update(Ax=values, Ax_idx=self.idx_var, l=lower, u=upper)
            warm = self._shifted() if self.solver_cfg.warm_start else None
            if warm is not None:
                self._solver.warm_start(x=warm[0], y=warm[1])
        if self.solver_cfg.time_limit_s > 0:  # what is left of the update's deadline
            self._solver.update_settings(time_limit=remaining(start, self.solver_cfg.time_limit_s))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = self._solver.solve(raise_error=False)
        info = result.info
        status = STATUS.get(info.status_val, "solver_error")
        if info.status_val in (SolverStatus.OSQP_SOLVED, SolverStatus.OSQP_SOLVED_INACCURATE):
            self._previous = (np.array(result.x), np.array(result.y))
            u = np.asarray(result.x[self.nx :]).reshape(self.h, N)
            return solution_from_inputs(
                u,
                x,
                x_ref,
                model,
                self.weights,
                status,
                info.iter,
                info.solve_time,
                start,
                self.solver_cfg.time_limit_s,
            )
        self._previous = None
        return failed_solution(self.h, status, info.iter, info.solve_time, start)
