"""``solver=clarabel``: the CVXPY QP solved by Clarabel (interior point); the equivalence tests' reference."""

from __future__ import annotations

import cvxpy as cp

from ..config import SolverConfig
from . import BACKENDS
from ._cvxpy import CvxpyMpc


@BACKENDS.register()
class ClarabelMpc(CvxpyMpc):
    solver_name = cp.CLARABEL
    objective_rtol = 1e-5  # an interior-point solution at its default eps
    violation_tol = 1e-6

    def options(self, solver: SolverConfig, time_limit_s: float | None) -> dict:
        opts = dict(
            tol_gap_abs=solver.eps_abs, tol_gap_rel=solver.eps_rel, tol_feas=solver.eps_abs, max_iter=solver.max_iters
        )
        if time_limit_s:
            opts["time_limit"] = time_limit_s
        return opts
