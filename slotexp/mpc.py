"""Convex MPC over ground-reaction forces (paper Sec. V; seed 001): the model and the common interface.

Prediction model (paper eq. 7, gyroscopic term neglected), linearised about the
current state and held over the horizon:

    d(roll, pitch, yaw)/dt = E(pitch, yaw)^-1 omega      (Z-Y-X Euler rates)
    dp/dt = v
    d omega/dt = I_w^-1 sum_i r_{k,i} x f_i,   I_w = R I_b R^T
    dv/dt = sum_i f_i / m - g e_z

The lever arms r_{k,i} may change from step to step (seed 001's B_k: the
footholds of step k relative to the CoM predicted for step k) or be one set for
the whole horizon (the feet where they stand); :func:`step_lever_arms` makes
both (H, 4, 3). The attitude terms (E^-1, I_w) stay frozen at the current state.

A has A @ A = 0, so the zero-order-hold discretisation is exact in closed form:
A_d = I + A T, B_d = (I T + A T^2/2) B, g_d = (I T + A T^2/2) g.

The QP (paper eq. 8-9) is the same for every backend:

    min  sum_{k=1..H} (x_k - x*_k)^T Q (x_k - x*_k) + r sum_{k=0..H-1} |u_k|^2
    s.t. x_{k+1} = A_d x_k + B_k u_k + g_d,  x_0 = measured state
         fz_min <= f_z <= fz_max,  |f_x|, |f_y| <= mu f_z  (per leg and step)
         |sum_i f_z - m g| <= band                           (per step)

Backends (``slotexp/backends``) differ only in how they solve it: through CVXPY
(``clarabel``, ``scs``, ``osqp``), sparse OSQP called directly (``osqp_direct``)
or condensed onto the forces and solved by DAQP (``daqp``).
:func:`slotexp.backends.make_mpc` picks one from :class:`~slotexp.config.SolverConfig`;
each returns an :class:`MpcSolution`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .body import rot_z
from .config import MpcConfig
from .gait import ContactPlan
from .jit import njit

N_STATE = 12
N_INPUT = 12
CONSTRAINT_GROUPS = ("f_max", "f_min", "friction", "balance")
# Statuses a backend reports when its plan may be applied (CVXPY's names, shared by all backends).
SUCCESS = frozenset({"optimal", "optimal_inaccurate"})


def rotation_from_euler(rpy: np.ndarray) -> np.ndarray:
    roll, pitch, yaw = rpy
    cr, sr = np.cos(roll), np.sin(roll)
    cp_, sp = np.cos(pitch), np.sin(pitch)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp_, 0, sp], [0, 1, 0], [-sp, 0, cp_]])
    return rot_z(yaw) @ ry @ rx


@njit(cache=True)
def _world_inertia_inv(x: np.ndarray, inertia_body_inv: np.ndarray) -> np.ndarray:
    """I_w^-1 = R I_b^-1 R^T at the attitude of state ``x``."""
    cr, sr = np.cos(x[0]), np.sin(x[0])
    cp, sp = np.cos(x[1]), np.sin(x[1])
    cy, sy = np.cos(x[2]), np.sin(x[2])
    rot = np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
    return rot @ inertia_body_inv @ rot.T


@njit(cache=True)
def _state_matrix(x: np.ndarray, gravity: float) -> tuple[np.ndarray, np.ndarray]:
    """A_c and g_c at state ``x`` (E^-1 of the Z-Y-X Euler rates, position from velocity, gravity)."""
    cp, sp = np.cos(x[1]), np.sin(x[1])
    cy, sy = np.cos(x[2]), np.sin(x[2])
    a = np.zeros((12, 12))
    a[0, 6], a[0, 7] = cy / cp, sy / cp
    a[1, 6], a[1, 7] = -sy, cy
    a[2, 6], a[2, 7], a[2, 8] = cy * sp / cp, sy * sp / cp, 1.0
    for i in range(3):
        a[3 + i, 9 + i] = 1.0
    g = np.zeros(12)
    g[11] = -gravity
    return a, g


@njit(cache=True)
def _input_matrix(lever_arms: np.ndarray, mass: float, iw_inv: np.ndarray, b: np.ndarray) -> None:
    """B_c for feet at ``lever_arms`` (4, 3) into ``b`` (zeroed): I_w^-1 [r_i]x on omega, I / m on v.

    Column j of I_w^-1 [r]x is I_w^-1 (r x e_j), written out (no temporaries: this
    runs for every step of the horizon).
    """
    for leg in range(4):
        rx, ry, rz = lever_arms[leg, 0], lever_arms[leg, 1], lever_arms[leg, 2]
        c = 3 * leg
        for i in range(3):
            b[6 + i, c] = iw_inv[i, 1] * rz - iw_inv[i, 2] * ry  # r x e_x = (0, r_z, -r_y)
            b[6 + i, c + 1] = iw_inv[i, 2] * rx - iw_inv[i, 0] * rz  # r x e_y = (-r_z, 0, r_x)
            b[6 + i, c + 2] = iw_inv[i, 0] * ry - iw_inv[i, 1] * rx  # r x e_z = (r_y, -r_x, 0)
            b[9 + i, c + i] = 1.0 / mass


@njit(cache=True)
def _model(
    x: np.ndarray, lever_arms: np.ndarray, mass: float, inertia_body_inv: np.ndarray, gravity: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A_c, B_c, g_c in closed form (no matrix inverses) for one set of lever arms (4, 3)."""
    a, g = _state_matrix(x, gravity)
    b = np.zeros((12, 12))
    _input_matrix(lever_arms, mass, _world_inertia_inv(x, inertia_body_inv), b)
    return a, b, g


@njit(cache=True)
def _model_steps(
    x: np.ndarray, lever_arms: np.ndarray, mass: float, inertia_body_inv: np.ndarray, gravity: float, period: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A_c, and A_d, B_k per step (H, 12, 12), g_d, for lever arms per step (H, 4, 3): every backend's hot path.

    The attitude (A_c and the world inertia) is frozen at ``x`` over the horizon as
    before; only the feet move (seed 001's B_k: the footholds of step k relative to
    the CoM at step k). ``same[k]`` marks a step whose arms equal step k-1's: its B_k
    is copied, not rebuilt (one B for the horizon costs one B).
    """
    a_c, g_c = _state_matrix(x, gravity)
    iw_inv = _world_inertia_inv(x, inertia_body_inv)
    eye = np.eye(12)
    gamma = eye * period + a_c * (period**2 / 2.0)
    h = lever_arms.shape[0]
    b_c = np.zeros((12, 12))
    b_d = np.empty((h, 12, 12))
    same = np.zeros(h, dtype=np.bool_)
    for k in range(h):
        if k > 0:
            same[k] = True
            for leg in range(4):
                for i in range(3):
                    if lever_arms[k, leg, i] != lever_arms[k - 1, leg, i]:
                        same[k] = False
        if same[k]:
            b_d[k] = b_d[k - 1]
        else:
            _input_matrix(lever_arms[k], mass, iw_inv, b_c)
            b_d[k] = gamma @ b_c
    return a_c, eye + a_c * period, b_d, gamma @ g_c, same


def continuous_model(
    x: np.ndarray, lever_arms: np.ndarray, mass: float, inertia_body: np.ndarray, gravity: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A_c, B_c, g_c of dx/dt = A_c x + B_c u + g_c, frozen at state ``x``.

    ``lever_arms[i]`` is foot i relative to the CoM, world frame.
    """
    return _model(
        np.ascontiguousarray(x, dtype=float),
        np.ascontiguousarray(lever_arms, dtype=float),
        float(mass),
        np.linalg.inv(np.asarray(inertia_body, dtype=float)),
        float(gravity),
    )


@njit(cache=True)
def _discretize(
    a: np.ndarray, b: np.ndarray, g: np.ndarray, period: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    eye = np.eye(a.shape[0])
    gamma = eye * period + a * (period**2 / 2.0)
    return eye + a * period, gamma @ b, gamma @ g


def discretize(a: np.ndarray, b: np.ndarray, g: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact zero-order hold for a nilpotent A (A @ A = 0)."""
    f64 = np.ascontiguousarray
    return _discretize(f64(a, dtype=float), f64(b, dtype=float), f64(g, dtype=float), float(period))


@dataclass
class MpcSolution:
    forces: np.ndarray  # (4, 3) first input of the plan
    plan_fz: np.ndarray  # (H, 4) planned normal forces
    predicted: np.ndarray  # (H + 1, 12) predicted states
    status: str
    success: bool
    iterations: int
    solve_time_s: float  # solver-reported time
    wall_time_s: float  # build-or-update + solve, as the loop sees it
    objective: float  # unscaled objective (paper eq. 8, summed over k = 1..H)
    inputs: np.ndarray | None = None  # (H, 12) the whole planned input sequence (None if the solve failed)


def step_lever_arms(lever_arms: np.ndarray, horizon: int) -> np.ndarray:
    """Lever arms per horizon step, (H, 4, 3) contiguous floats.

    A (4, 3) array (the feet where they stand, one B for the whole horizon) is
    repeated over the horizon; an (H, 4, 3) array (seed 001's footholds of each
    step relative to the CoM predicted for that step) is taken as it is.
    """
    arms = np.asarray(lever_arms, dtype=float)
    if arms.shape == (4, 3):
        return np.ascontiguousarray(np.broadcast_to(arms, (horizon, 4, 3)))
    if arms.shape != (horizon, 4, 3):
        raise ValueError(f"lever arms must be (4, 3) or (horizon={horizon}, 4, 3), got {arms.shape}")
    return np.ascontiguousarray(arms)


class DiscreteModel:
    """The prediction model for one MPC update, computed once and shared by a backend's build and rollout.

    ``b`` is (H, 12, 12): B_k of each horizon step.
    """

    __slots__ = ("a", "a_c", "b", "g")

    def __init__(
        self,
        x: np.ndarray,
        lever_arms: np.ndarray,
        mass: float,
        inertia_body_inv: np.ndarray,
        gravity: float,
        period: float,
    ) -> None:
        """``x`` a contiguous float array, ``lever_arms`` (H, 4, 3) from :func:`step_lever_arms`."""
        self.a_c, self.a, self.b, self.g, _ = _model_steps(x, lever_arms, mass, inertia_body_inv, gravity, period)


@njit(cache=True)
def _rollout(
    x0: np.ndarray,
    u: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    g: np.ndarray,
    x_ref: np.ndarray,
    q: np.ndarray,
    r: float,
) -> tuple[np.ndarray, float]:
    h = u.shape[0]
    xs = np.empty((h + 1, x0.shape[0]))
    xs[0] = x0
    cost = 0.0
    for k in range(h):
        xs[k + 1] = a @ xs[k] + b[k] @ u[k] + g
        e = xs[k + 1] - x_ref[k]
        cost += np.sum(q * e * e) + r * np.sum(u[k] * u[k])
    return xs, cost


def solution_from_inputs(
    u: np.ndarray,
    x: np.ndarray,
    x_ref: np.ndarray,
    model: DiscreteModel,
    weights: tuple[np.ndarray, float],
    status: str,
    iterations: int,
    solve_time_s: float,
    started: float,
    time_limit_s: float = 0.0,
) -> MpcSolution:
    """A successful solution from the planned inputs ``u`` (H, 12); ``started`` is the solve's perf_counter().

    The predicted states are rolled out through the model, so they satisfy the
    dynamics exactly whatever the backend's equality tolerance, and the objective
    is evaluated on them (paper eq. 8, without the solver's objective scaling).
    ``weights`` is (q_diag as an array, r_weight), unscaled; ``model.b`` holds B_k per step. The wall time covers the
    whole step: build or update, solve, and this rollout.
    """
    u = np.ascontiguousarray(u, dtype=float)
    xs, cost = _rollout(x, u, model.a, model.b, model.g, x_ref, weights[0], weights[1])
    return solution_from_rollout(u, xs, cost, status, iterations, solve_time_s, started, time_limit_s)


def solution_from_rollout(
    u: np.ndarray,
    xs: np.ndarray,
    cost: float,
    status: str,
    iterations: int,
    solve_time_s: float,
    started: float,
    time_limit_s: float = 0.0,
) -> MpcSolution:
    """A solution from inputs, predicted states and objective already computed.

    ``time_limit_s`` > 0 is the deadline of the whole update: a plan that arrives
    later counts as a failed solve ("time_limit"), whatever the solver reported.
    """
    wall_time_s = time.perf_counter() - started
    if 0.0 < time_limit_s < wall_time_s:
        return failed_solution(u.shape[0], "time_limit", iterations, solve_time_s, started)
    return MpcSolution(
        forces=u[0].reshape(4, 3).copy(),
        plan_fz=u[:, 2::3].copy(),
        predicted=xs,
        status=status,
        success=True,
        iterations=int(iterations),
        solve_time_s=float(solve_time_s),
        wall_time_s=float(wall_time_s),
        objective=float(cost),
        inputs=u,
    )


def failed_solution(horizon: int, status: str, iterations: int, solve_time_s: float, started: float) -> MpcSolution:
    """A solve that produced no usable plan: the controller applies the last feasible input."""
    wall_time_s = time.perf_counter() - started
    nan = np.full
    return MpcSolution(
        forces=nan((4, 3), np.nan),
        plan_fz=nan((horizon, 4), np.nan),
        predicted=nan((horizon + 1, N_STATE), np.nan),
        status=status,
        success=False,
        iterations=int(iterations),
        solve_time_s=float(solve_time_s),
        wall_time_s=float(wall_time_s),
        objective=float("nan"),
    )


def remaining(started: float, time_limit_s: float) -> float:
    """What is left of the update's deadline for the solver itself (0 = no limit; never 0 once set)."""
    if time_limit_s <= 0.0:
        return 0.0
    return max(time_limit_s - (time.perf_counter() - started), 1e-9)


def objective_weights(cfg: MpcConfig) -> tuple[np.ndarray, float]:
    """(q_diag, r_weight) of the reported objective, unscaled."""
    return np.asarray(cfg.q_diag, dtype=float), float(cfg.r_weight)


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


def plan_violations(u: np.ndarray, plan: ContactPlan, weight: float, band: float) -> dict[str, float]:
    """Like :func:`constraint_violations` but over the whole plan ``u`` (H, 12): every step's inputs."""
    f = np.asarray(u, dtype=float).reshape(-1, 4, 3)
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    return {
        "f_max": float(max(0.0, np.max(fz - plan.fz_max))),
        "f_min": float(max(0.0, np.max(plan.fz_min - fz))),
        "friction": float(max(0.0, np.max(np.abs(fx) - plan.mu * fz), np.max(np.abs(fy) - plan.mu * fz))),
        "balance": float(max(0.0, np.max(np.abs(fz.sum(axis=1) - weight)) - band)),
    }
