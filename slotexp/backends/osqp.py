"""``solver=osqp``: the CVXPY QP solved by OSQP (``osqp_direct`` calls OSQP without CVXPY)."""

from __future__ import annotations

import cvxpy as cp

from ..config import SolverConfig
from . import BACKENDS
from ._cvxpy import CvxpyMpc


@BACKENDS.register()
class OsqpCvxpyMpc(CvxpyMpc):
    solver_name = cp.OSQP
    objective_rtol = 5e-3  # as osqp_direct: the same solver at the same eps
    violation_tol = 5e-4
    first_order = True

    def options(self, solver: SolverConfig, time_limit_s: float | None) -> dict:
        opts = dict(eps_abs=solver.eps_abs, eps_rel=solver.eps_rel, max_iter=solver.max_iters, polish=True)
        if time_limit_s:
            opts["time_limit"] = time_limit_s
        return opts
