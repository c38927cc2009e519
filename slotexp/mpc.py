"""Convex MPC over ground-reaction forces (paper Sec. V; seed 001's sparse QP).

Prediction model (paper eq. 7, gyroscopic term neglected), linearised about the
current state and held over the horizon:

    d(roll, pitch, yaw)/dt = E(pitch, yaw)^-1 omega      (Z-Y-X Euler rates)
    dp/dt = v
    d omega/dt = I_w^-1 sum_i r_i x f_i,   I_w = R I_b R^T
    dv/dt = sum_i f_i / m - g e_z

A has A @ A = 0, so the zero-order-hold discretisation is exact in closed form:
A_d = I + A T, B_d = (I T + A T^2/2) B, g_d = (I T + A T^2/2) g.

The QP (sparse form: states and forces are both variables) is written once with
CVXPY Parameters in a DPP-compliant way, so each solve only updates parameter
values and never recompiles.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import cvxpy as cp
import numpy as np

from .body import euler_rate_matrix, rot_z
from .config import MpcConfig, SolverConfig
from .gait import ContactPlan

N_STATE = 12
N_INPUT = 12
CONSTRAINT_GROUPS = ("f_max", "f_min", "friction", "balance")


def skew(r: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


def rotation_from_euler(rpy: np.ndarray) -> np.ndarray:
    roll, pitch, yaw = rpy
    cr, sr = np.cos(roll), np.sin(roll)
    cp_, sp = np.cos(pitch), np.sin(pitch)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp_, 0, sp], [0, 1, 0], [-sp, 0, cp_]])
    return rot_z(yaw) @ ry @ rx


def continuous_model(x: np.ndarray, lever_arms: np.ndarray, mass: float, inertia_body: np.ndarray,
                     gravity: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A_c, B_c, g_c of dx/dt = A_c x + B_c u + g_c, frozen at state ``x``.

    ``lever_arms[i]`` is foot i relative to the CoM, world frame.
    """
    rot = rotation_from_euler(x[0:3])
    inertia_world_inv = np.linalg.inv(rot @ inertia_body @ rot.T)
    a = np.zeros((N_STATE, N_STATE))
    a[0:3, 6:9] = np.linalg.inv(euler_rate_matrix(*x[0:3]))
    a[3:6, 9:12] = np.eye(3)
    b = np.zeros((N_STATE, N_INPUT))
    for i in range(4):
        b[6:9, 3 * i:3 * i + 3] = inertia_world_inv @ skew(lever_arms[i])
        b[9:12, 3 * i:3 * i + 3] = np.eye(3) / mass
    g = np.zeros(N_STATE)
    g[11] = -gravity
    return a, b, g


def discretize(a: np.ndarray, b: np.ndarray, g: np.ndarray, period: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact zero-order hold for a nilpotent A (A @ A = 0)."""
    eye = np.eye(a.shape[0])
    gamma = eye * period + a * (period**2 / 2.0)
    return eye + a * period, gamma @ b, gamma @ g


@dataclass
class MpcSolution:
    forces: np.ndarray        # (4, 3) first input of the plan
    plan_fz: np.ndarray       # (H, 4) planned normal forces
    predicted: np.ndarray     # (H + 1, 12) predicted states
    status: str
    success: bool
    iterations: int
    solve_time_s: float       # solver-reported time
    wall_time_s: float        # parameter update + solve, as the loop sees it
    objective: float          # unscaled objective (paper eq. 8, summed over k = 1..H)


SUCCESS = {cp.OPTIMAL, cp.OPTIMAL_INACCURATE}


def _solver_options(solver: SolverConfig) -> tuple[str, dict]:
    limit = solver.time_limit_s if solver.time_limit_s > 0 else None
    if solver.name == "osqp":
        opts = dict(eps_abs=solver.eps_abs, eps_rel=solver.eps_rel, max_iter=solver.max_iters, polish=True)
        if limit:
            opts["time_limit"] = limit
        return cp.OSQP, opts
    if solver.name == "scs":
        opts = dict(eps_abs=solver.eps_abs, eps_rel=solver.eps_rel, max_iters=solver.max_iters)
        if limit:
            opts["time_limit_secs"] = limit
        return cp.SCS, opts
    if solver.name == "clarabel":
        opts = dict(tol_gap_abs=solver.eps_abs, tol_gap_rel=solver.eps_rel, tol_feas=solver.eps_abs,
                    max_iter=solver.max_iters)
        if limit:
            opts["time_limit"] = limit
        return cp.CLARABEL, opts
    raise ValueError(f"unknown solver {solver.name!r}")


class ConvexMpc:
    """The paper's QP, built once; :meth:`solve` only sets parameter values."""

    def __init__(self, cfg: MpcConfig, solver: SolverConfig, mass: float, inertia_body: np.ndarray,
                 gravity: float) -> None:
        self.cfg = cfg
        self.solver_cfg = solver
        self.mass = mass
        self.inertia_body = inertia_body
        self.gravity = gravity
        self.period = 1.0 / cfg.rate_hz
        self.q = np.asarray(cfg.q_diag, dtype=float)
        h = cfg.horizon
        self._solver, self._options = _solver_options(solver)

        self.x0 = cp.Parameter(N_STATE, name="x0")
        self.x_ref = cp.Parameter((N_STATE, h), name="x_ref")
        self.a = cp.Parameter((N_STATE, N_STATE), name="A")
        self.b = [cp.Parameter((N_STATE, N_INPUT), name=f"B{k}") for k in range(h)]
        self.g = cp.Parameter(N_STATE, name="g")
        self.mu = cp.Parameter((4, h), nonneg=True, name="mu")
        self.fz_min = cp.Parameter((4, h), nonneg=True, name="fz_min")
        self.fz_max = cp.Parameter((4, h), nonneg=True, name="fz_max")
        self.x = cp.Variable((N_STATE, h + 1), name="x")
        self.u = cp.Variable((N_INPUT, h), name="u")

        fx, fy, fz = self.u[0::3, :], self.u[1::3, :], self.u[2::3, :]
        weight = mass * gravity
        constraints = [self.x[:, 0] == self.x0]
        constraints += [self.x[:, k + 1] == self.a @ self.x[:, k] + self.b[k] @ self.u[:, k] + self.g
                        for k in range(h)]
        constraints += [
            fz <= self.fz_max,
            fz >= self.fz_min,
            fx <= cp.multiply(self.mu, fz), -fx <= cp.multiply(self.mu, fz),
            fy <= cp.multiply(self.mu, fz), -fy <= cp.multiply(self.mu, fz),
            cp.sum(fz, axis=0) <= weight + cfg.force_balance_band,
            cp.sum(fz, axis=0) >= weight - cfg.force_balance_band,
        ]
        sqrt_q = np.sqrt(self.q)[:, None]
        tracking = cp.sum_squares(cp.multiply(sqrt_q, self.x[:, 1:] - self.x_ref))
        effort = cfg.r_weight * cp.sum_squares(self.u)
        self.problem = cp.Problem(cp.Minimize(cfg.objective_scale * (tracking + effort)), constraints)
        if not self.problem.is_dpp():  # pragma: no cover - guards future edits
            raise RuntimeError("MPC problem is not DPP-compliant; it would recompile every step")

    def set_model(self, x: np.ndarray, lever_arms: np.ndarray) -> None:
        a_c, b_c, g_c = continuous_model(x, lever_arms, self.mass, self.inertia_body, self.gravity)
        a_d, b_d, g_d = discretize(a_c, b_c, g_c, self.period)
        self.a.value = a_d
        self.g.value = g_d
        for b in self.b:
            b.value = b_d

    def solve(self, x: np.ndarray, x_ref: np.ndarray, lever_arms: np.ndarray, plan: ContactPlan) -> MpcSolution:
        """Solve for the forces; ``x_ref`` is (H, 12), ``plan`` arrays are (H, 4)."""
        start = time.perf_counter()
        self.set_model(x, lever_arms)
        self.x0.value = x
        self.x_ref.value = x_ref.T
        self.mu.value = plan.mu.T
        self.fz_min.value = plan.fz_min.T
        self.fz_max.value = plan.fz_max.T
        status, iterations, solve_time = "solver_error", 0, float("nan")
        try:
            with warnings.catch_warnings():  # the status is recorded; no console noise per step
                warnings.simplefilter("ignore")
                self.problem.solve(solver=self._solver, warm_start=self.solver_cfg.warm_start,
                                   verbose=self.solver_cfg.verbose, **self._options)
            status = self.problem.status
            stats = self.problem.solver_stats
            iterations = int(stats.num_iters or 0)
            solve_time = float(stats.solve_time) if stats.solve_time is not None else float("nan")
        except cp.error.SolverError:
            pass
        wall = time.perf_counter() - start
        success = status in SUCCESS and self.u.value is not None
        h = self.cfg.horizon
        if success:
            u = self.u.value
            xs = self.x.value.T
            err = xs[1:] - x_ref
            objective = float(np.sum(self.q * err**2) + self.cfg.r_weight * np.sum(u**2))
            return MpcSolution(forces=u[:, 0].reshape(4, 3), plan_fz=u[2::3, :].T.copy(), predicted=xs,
                               status=status, success=True, iterations=iterations,
                               solve_time_s=solve_time, wall_time_s=wall, objective=objective)
        nan = np.full
        return MpcSolution(forces=nan((4, 3), np.nan), plan_fz=nan((h, 4), np.nan),
                           predicted=nan((h + 1, N_STATE), np.nan), status=status, success=False,
                           iterations=iterations, solve_time_s=solve_time, wall_time_s=wall,
                           objective=float("nan"))


def constraint_violations(forces: np.ndarray, plan: ContactPlan, weight: float, band: float) -> dict[str, float]:
    """Largest violation (N) of each constraint group by an input applied at step 0.

    Zero means satisfied. Used for the Dynamic Constraint Map (paper Fig. 8).
    """
    fx, fy, fz = forces[:, 0], forces[:, 1], forces[:, 2]
    mu, lo, hi = plan.mu[0], plan.fz_min[0], plan.fz_max[0]
    total = float(np.sum(fz))
    return {
        "f_max": float(max(0.0, np.max(fz - hi))),
        "f_min": float(max(0.0, np.max(lo - fz))),
        "friction": float(max(0.0, np.max(np.abs(fx) - mu * fz), np.max(np.abs(fy) - mu * fz))),
        "balance": float(max(0.0, abs(total - weight) - band)),
    }
