"""``solver=scs``: the CVXPY QP solved by SCS, the paper's stack."""

from __future__ import annotations

import cvxpy as cp

from ..config import SolverConfig
from . import BACKENDS
from ._cvxpy import CvxpyMpc


@BACKENDS.register()
class ScsMpc(CvxpyMpc):
    solver_name = cp.SCS
    objective_rtol = 5e-3  # stops at eps 1e-5
    violation_tol = 1e-3
    first_order = True

    def options(self, solver: SolverConfig, time_limit_s: float | None) -> dict:
        opts = dict(eps_abs=solver.eps_abs, eps_rel=solver.eps_rel, max_iters=solver.max_iters)
        if time_limit_s:
            opts["time_limit_secs"] = time_limit_s
        return opts
