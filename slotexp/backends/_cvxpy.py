"""The QP written once in CVXPY (sparse form: states and forces are both variables).

DPP-compliant Parameters mean each solve only updates parameter values and never
recompiles. This is the paper's modelling stack (with ``solver=scs`` its solver)
and the reference the direct backends are tested against. Each CVXPY backend
(``clarabel``, ``scs``, ``osqp``) is a thin subclass that names its solver and
maps the shared settings onto that solver's options.
"""

from __future__ import annotations

import time
import warnings

import cvxpy as cp
import numpy as np

from ..config import MpcConfig, SolverConfig
from ..gait import ContactPlan
from ..mpc import (
    N_INPUT,
    N_STATE,
    SUCCESS,
    DiscreteModel,
    MpcSolution,
    failed_solution,
    solution_from_inputs,
    step_lever_arms,
)
from ._base import MpcBackend


class CvxpyMpc(MpcBackend):
    """The paper's QP, built once; :meth:`solve` only sets parameter values."""

    solver_name: str = ""  # CVXPY's name of the solver (cp.CLARABEL, ...), set by each subclass

    def options(self, solver: SolverConfig, time_limit_s: float | None) -> dict:
        """The shared settings as this solver's CVXPY options.

        The time limit goes to the solver as its own limit; the update as a whole
        (CVXPY's parameter handling included) is also held to it by ``solution_from_inputs``.
        """
        raise NotImplementedError

    def __init__(
        self, cfg: MpcConfig, solver: SolverConfig, mass: float, inertia_body: np.ndarray, gravity: float
    ) -> None:
        super().__init__(cfg, solver, mass, inertia_body, gravity)
        self.q = np.asarray(cfg.q_diag, dtype=float)
        h = cfg.horizon
        self._options = self.options(solver, solver.time_limit_s if solver.time_limit_s > 0 else None)

        self.x0 = cp.Parameter(N_STATE, name="x0")
        self.x_ref = cp.Parameter((N_STATE, h), name="x_ref")
        self.a = cp.Parameter((N_STATE, N_STATE), name="A")
        self.b = [cp.Parameter((N_STATE, N_INPUT), name=f"B{k}") for k in range(h)]
        self.g = cp.Parameter(N_STATE, name="g")
        self.mu = cp.Parameter((4, h), nonneg=True, name="mu")
        self.fz_min = cp.Parameter((4, h), nonneg=True, name="fz_min")
        self.fz_max = cp.Parameter((4, h), nonneg=True, name="fz_max")
        self.x = cp.Variable((N_STATE, h + 1), name="x")
        # The forces are solved for in units of m g / 4 (a stance leg's share of the weight), so they are
        # of order one like the states: unscaled, a 12 kg robot's forces of 50-150 N kept OSQP from converging.
        self.force_unit = self.weight / 4.0
        self.u = cp.Variable((N_INPUT, h), name="u_scaled")

        fx, fy, fz = self.u[0::3, :], self.u[1::3, :], self.u[2::3, :]
        weight = self.weight / self.force_unit
        constraints = [self.x[:, 0] == self.x0]
        constraints += [self.x[:, k + 1] == self.a @ self.x[:, k] + self.b[k] @ self.u[:, k] + self.g for k in range(h)]
        constraints += [
            fz <= self.fz_max,
            fz >= self.fz_min,
            fx <= cp.multiply(self.mu, fz),
            -fx <= cp.multiply(self.mu, fz),
            fy <= cp.multiply(self.mu, fz),
            -fy <= cp.multiply(self.mu, fz),
            cp.sum(fz, axis=0) <= weight + cfg.force_balance_band / self.force_unit,
            cp.sum(fz, axis=0) >= weight - cfg.force_balance_band / self.force_unit,
        ]
        sqrt_q = np.sqrt(self.q)[:, None]
        tracking = cp.sum_squares(cp.multiply(sqrt_q, self.x[:, 1:] - self.x_ref))
        effort = cfg.r_weight * self.force_unit**2 * cp.sum_squares(self.u)
        self.problem = cp.Problem(cp.Minimize(cfg.objective_scale * (tracking + effort)), constraints)
        if not self.problem.is_dpp():  # pragma: no cover - guards future edits
            raise RuntimeError("MPC problem is not DPP-compliant; it would recompile every step")

    def set_model(self, x: np.ndarray, lever_arms: np.ndarray) -> DiscreteModel:
        """Set A, g and each step's B_k (lever arms (4, 3) or (H, 4, 3)) from state ``x``."""
        model = DiscreteModel(
            np.ascontiguousarray(x, dtype=float),
            step_lever_arms(lever_arms, self.cfg.horizon),
            self.mass,
            self.inertia_inv,
            self.gravity,
            self.period,
        )
        self.a.value = model.a
        self.g.value = model.g
        for b, b_k in zip(self.b, model.b):
            b.value = b_k * self.force_unit
        return model

    def solve(self, x: np.ndarray, x_ref: np.ndarray, lever_arms: np.ndarray, plan: ContactPlan) -> MpcSolution:
        """Solve for the forces; ``x_ref`` is (H, 12), ``plan`` arrays are (H, 4)."""
        start = time.perf_counter()
        model = self.set_model(x, lever_arms)
        self.x0.value = x
        self.x_ref.value = x_ref.T
        self.mu.value = plan.mu.T
        self.fz_min.value = plan.fz_min.T / self.force_unit
        self.fz_max.value = plan.fz_max.T / self.force_unit
        status, iterations, solve_time = "solver_error", 0, float("nan")
        try:
            with warnings.catch_warnings():  # the status is recorded; no console noise per step
                warnings.simplefilter("ignore")
                self.problem.solve(
                    solver=self.solver_name,
                    warm_start=self.solver_cfg.warm_start,
                    verbose=self.solver_cfg.verbose,
                    **self._options,
                )
            status = self.problem.status
            stats = self.problem.solver_stats
            iterations = int(stats.num_iters or 0)
            solve_time = float(stats.solve_time) if stats.solve_time is not None else float("nan")
        except cp.error.SolverError:
            pass
        if status in SUCCESS and self.u.value is not None:
            return solution_from_inputs(
                self.u.value.T * self.force_unit,
                np.ascontiguousarray(x, dtype=float),
                np.ascontiguousarray(x_ref, dtype=float),
                model,
                self.weights,
                status,
                iterations,
                solve_time,
                start,
                self.solver_cfg.time_limit_s,
            )
        return failed_solution(self.cfg.horizon, status, iterations, solve_time, start)
