"""Every QP backend solves the same problem: same objective, every constraint satisfied.

The reference is Clarabel through CVXPY at tight tolerances. Sequences are fed to
one instance per backend, so warm starts and in-place updates are exercised:
random perturbed states on three gaits, a closed-loop walk with a push, the
zero-force (swing legs lifted) gait that removes variables, the strict balance,
and lever arms that change from step to step (seed 001's B_k). The condensed
backend's matrices are checked against a direct stacking of A_d and the B_k.
"""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from slotexp.backends import BACKENDS, backend_class, make_mpc
from slotexp.backends._condensing import build, horizon_coefficients
from slotexp.controllers.paper import PaperController as Controller
from slotexp.gait import GaitMatrix, contact_plan
from slotexp.mpc import DiscreteModel, continuous_model, discretize, plan_violations, step_lever_arms
from slotexp.plants import ForceCommand, nominal_state
from slotexp.plants.ideal import IdealPlant
from slotexp.reference import reference
from slotexp.robot import build_robot
from tests.helpers import check_plan_constraints, load


def test_every_backend_declares_how_exact_it_is():
    # the tests hold each backend to its own class attributes: a new backend declares them, or fails here
    for name in BACKENDS.names():
        cls = backend_class(name)
        assert 0.0 < cls.objective_rtol < 0.1 and 0.0 < cls.violation_tol < 0.01, name
        assert isinstance(cls.first_order, bool), name


def rel_tol(backend: str) -> float:
    """The backend's own promise: objective agreement with the reference, relative (plus 1e-9 absolute)."""
    return backend_class(backend).objective_rtol


def violation_tol(backend: str) -> float:
    """The backend's own promise: the largest constraint violation over the whole plan (N)."""
    return backend_class(backend).violation_tol


REFERENCE = ("solver=clarabel", "solver.eps_abs=1e-9", "solver.eps_rel=1e-9")
# The CVXPY backends are slow per step (OSQP through CVXPY needs up to ~30k iterations on some):
# they see every n-th problem of a sequence, the direct backends every problem.
STRIDE = {"clarabel": 2, "scs": 3, "osqp": 4}


@cache
def _cfg(*overrides: str):
    return load(*overrides)


def _random_problems(gait: str, n: int, seed: int, *extra: str) -> tuple[tuple[str, ...], list]:
    """Independent perturbed states at random points of the gait cycle."""
    overrides = (f"gait={gait}", *extra)
    cfg = _cfg(*overrides)
    robot = build_robot(cfg.robot)
    rng = np.random.default_rng(seed)
    gait_m = GaitMatrix(cfg.gait.phases)
    out = []
    for _ in range(n):
        x = nominal_state(robot) + np.concatenate(
            [rng.normal(0, 0.05, 3), [0, 0, rng.normal(0, 0.005)], rng.normal(0, 0.1, 3), rng.normal(0, 0.05, 3)]
        )
        for _ in range(rng.integers(1, 12)):
            gait_m.roll()
        plan = contact_plan(gait_m.contacts(cfg.mpc.horizon), cfg.gait, cfg.mpc.f_min_stance, cfg.mpc.f_max)
        x_ref = reference(x, 0.0, cfg.gait, 1 / cfg.mpc.rate_hz, cfg.mpc.horizon)
        out.append((x, x_ref, robot.feet_body.copy(), plan))
    return overrides, out


def step_arms(arms: np.ndarray, plan, period: float, velocity: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Lever arms (H, 4, 3) as a walking robot's: the CoM moves at ``velocity`` over feet that stay put,
    and a foot that lands after a swing lands 1-3 cm away from where it was."""
    h = plan.stance.shape[0]
    feet = np.broadcast_to(arms, (h, 4, 3)).copy()
    for leg in range(4):
        for k in np.flatnonzero(plan.stance[1:, leg] & ~plan.stance[:-1, leg]) + 1:
            feet[k:, leg, 0:2] += rng.uniform(0.01, 0.03, 2) * rng.choice([-1.0, 1.0], 2)
    return feet - (period * np.arange(h))[:, None, None] * velocity


def _step_arm_problems(n: int, seed: int, *extra: str) -> tuple[tuple[str, ...], list]:
    """The lifted-swing walk's random problems with lever arms that differ at every step."""
    overrides, problems = _random_problems("walk", n, seed, *extra)
    cfg = _cfg(*overrides)
    rng = np.random.default_rng(seed + 100)
    out = []
    for x, x_ref, arms, plan in problems:
        v = np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), 0.0])
        out.append((x, x_ref, step_arms(arms, plan, 1 / cfg.mpc.rate_hz, v, rng), plan))
    return overrides, out


def _closed_loop(steps: int, push_at: int, *extra: str) -> tuple[tuple[str, ...], list]:
    """A perturbed walk on the ideal plant driven by the reference backend, pushed once."""
    overrides = tuple(extra)
    cfg = _cfg(*REFERENCE, *overrides)
    robot = build_robot(cfg.robot)
    scenario = cfg.scenarios["combined"]
    plant = IdealPlant(
        robot, nominal_state(robot) + np.asarray(scenario.offset.as_array()), cfg.sim.gravity, cfg.sim.dt
    )
    ctrl = Controller(cfg, robot)
    out = []
    for k in range(steps):
        x, feet = plant.state(), plant.feet()
        step = ctrl.step(k * ctrl.period, x, feet)
        out.append((x, step.x_ref, feet - x[3:6], step.plan))
        if k == push_at:
            plant.apply_impulse(np.array([-0.1, 0.05, 0.0]), np.array([0.0, 0.002, 0.0]))
        plant.step(ForceCommand(step.forces), ctrl.period)
    return overrides, out


@cache
def _sequences() -> dict[str, tuple[tuple[str, ...], list]]:
    return {
        "walk_random": _random_problems("walk", 8, 0),
        "crawl_random": _random_problems("crawl", 6, 1),
        "omni_random": _random_problems("omni60", 6, 2),
        "strict_balance": _random_problems("walk", 6, 3, "mpc.force_balance_band=0"),
        # swing legs exert no force (variables removed); f_max raised so two legs carry m g
        "lifted_swing": _random_problems("walk", 8, 4, "gait.swing_contact=false", "mpc.f_max=12"),
        "lifted_crawl": _random_problems("crawl", 6, 5, "gait.swing_contact=false", "mpc.f_max=9"),
        "closed_loop": _closed_loop(45, 15),
        # seed 001's B_k: the lever arms change at every step (the CoM moves, feet land elsewhere); short
        # phases, so the same contact pattern comes back within the horizon with its feet somewhere else
        "step_arms": _step_arm_problems(
            8, 6, "gait.swing_contact=false", "mpc.f_max=12", "gait.phases=[[3,1,0,1,0],[3,0,1,0,1]]"
        ),
    }


@cache
def _reference(name: str) -> list:
    overrides, problems = _sequences()[name]
    return _solve_all(problems, *REFERENCE, *overrides)


def _solve_all(problems: list, *overrides: str, stride: int = 1) -> list:
    cfg = _cfg(*overrides)
    robot = build_robot(cfg.robot)
    mpc = make_mpc(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
    return [mpc.solve(*p) if i % stride == 0 else None for i, p in enumerate(problems)]


@pytest.mark.parametrize(
    "sequence",
    [
        "walk_random",
        "crawl_random",
        "omni_random",
        "strict_balance",
        "lifted_swing",
        "lifted_crawl",
        "closed_loop",
        "step_arms",
    ],
)
@pytest.mark.parametrize("backend", BACKENDS.names())
def test_backend_matches_reference_and_satisfies_constraints(backend: str, sequence: str) -> None:
    overrides, problems = _sequences()[sequence]
    reference_solutions = _reference(sequence)
    stride = STRIDE.get(backend, 1)
    solutions = _solve_all(problems, f"solver={backend}", *overrides, stride=stride)
    cfg = _cfg(*overrides)
    robot = build_robot(cfg.robot)
    weight = robot.mass * cfg.sim.gravity
    for i, (problem, sol, ref) in enumerate(zip(problems, solutions, reference_solutions)):
        if sol is None:
            continue
        x, _, _, plan = problem
        assert ref.success, (sequence, i, ref.status)
        assert sol.success, (backend, sequence, i, sol.status)
        assert sol.objective == pytest.approx(ref.objective, rel=rel_tol(backend), abs=1e-9), (backend, sequence, i)
        worst = plan_violations(sol.inputs, plan, weight, cfg.mpc.force_balance_band)
        assert max(worst.values()) <= violation_tol(backend), (backend, sequence, i, worst)
        if violation_tol(backend) <= 1e-4:  # test_mpc's checks use 0.1 mN; first-order solvers meet their eps
            check_plan_constraints(cfg, robot, sol, x, plan)
        if backend == "daqp" and not cfg.gait.swing_contact:  # removed variables are exactly zero
            assert np.all(sol.inputs.reshape(-1, 4, 3)[~plan.stance] == 0.0)


@pytest.mark.parametrize("backend", BACKENDS.names())
def test_infeasible_problem_is_reported_by_every_backend(backend: str) -> None:
    # Three legs cannot carry m g at f_z <= 6 N under the strict balance.
    overrides = (
        f"solver={backend}",
        "gait.swing_contact=false",
        "mpc.force_balance_band=0",
        "gait.phases=[[1,1,1,1,1],[29,0,1,1,1]]",
    )
    cfg = _cfg(*overrides)
    robot = build_robot(cfg.robot)
    ctrl = Controller(cfg, robot)
    x = nominal_state(robot)
    first = ctrl.step(0.0, x, robot.feet_body + x[3:6])
    assert first.fallback and not first.solution.success and ctrl.infeasible_steps == 1
    np.testing.assert_allclose(first.forces, np.tile([0, 0, robot.mass * cfg.sim.gravity / 4], (4, 1)))


@pytest.mark.parametrize("backend", BACKENDS.names())
def test_a_missed_deadline_is_a_failed_solve(backend: str) -> None:
    _, problems = _sequences()["walk_random"]
    cfg = _cfg(f"solver={backend}", "solver.time_limit_s=1e-6")
    robot = build_robot(cfg.robot)
    mpc = make_mpc(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
    for problem in problems[:2]:
        sol = mpc.solve(*problem)
        assert not sol.success and sol.status in ("time_limit", "user_limit") and np.all(np.isnan(sol.forces))


@pytest.mark.parametrize("backend", ["daqp", "osqp_direct"])
def test_iteration_limit_is_a_failed_solve(backend: str) -> None:
    _, problems = _sequences()["walk_random"]
    cfg = _cfg(f"solver={backend}", "solver.max_iters=1")
    robot = build_robot(cfg.robot)
    mpc = make_mpc(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
    sols = [mpc.solve(*p) for p in problems[:3]]
    assert any(s.status == "iteration_limit" for s in sols), [s.status for s in sols]
    assert all(s.success or (s.status == "iteration_limit" and np.all(np.isnan(s.forces))) for s in sols)


@pytest.mark.parametrize("backend", ["daqp", "osqp_direct"])
def test_cold_start_gives_the_same_solution(backend: str) -> None:
    _, problems = _sequences()["closed_loop"]
    warm = _solve_all(problems[:20], f"solver={backend}")
    cold = _solve_all(problems[:20], f"solver={backend}", "solver.warm_start=false")
    for w, c in zip(warm, cold):
        assert w.success and c.success
        assert w.objective == pytest.approx(c.objective, rel=rel_tol(backend), abs=1e-9)


def test_every_backend_is_selectable_and_unknown_names_fail() -> None:
    for name in BACKENDS.names():
        cfg = _cfg(f"solver={name}")
        assert cfg.solver.name == name
        assert backend_class(name).__name__.endswith("Mpc")
    with pytest.raises(ValueError, match="unknown solver"):
        backend_class("nope")
    cfg = _cfg()
    with pytest.raises(ValueError):
        make_mpc(cfg.mpc, dataclasses.replace(cfg.solver, name="nope"), 1.0, np.eye(3), 9.81)


def test_step_arm_problems_change_their_lever_arms_within_the_horizon() -> None:
    # guards the sequence above: every problem's B_k differ from step to step
    for _, _, arms, _ in _sequences()["step_arms"][1]:
        assert arms.shape[0] > 1 and np.min(np.abs(np.diff(arms, axis=0)).max(axis=(1, 2))) > 1e-4


def test_equal_step_arms_are_the_single_b_model() -> None:
    # per-step lever arms all equal to the current ones give B_k = the single B of the model, exactly
    overrides, problems = _sequences()["lifted_swing"]
    cfg = _cfg(*overrides)
    robot = build_robot(cfg.robot)
    period = 1 / cfg.mpc.rate_hz
    for x, _, arms, _ in problems:
        a, b, g = discretize(*continuous_model(x, arms, robot.mass, robot.inertia_body, cfg.sim.gravity), period)
        model = DiscreteModel(
            x,
            step_lever_arms(arms, cfg.mpc.horizon),
            robot.mass,
            np.linalg.inv(robot.inertia_body),
            cfg.sim.gravity,
            period,
        )
        assert model.b.shape == (cfg.mpc.horizon, 12, 12)
        np.testing.assert_array_equal(model.a, a)
        np.testing.assert_array_equal(model.g, g)
        for b_k in model.b:
            np.testing.assert_array_equal(b_k, b)
    with pytest.raises(ValueError, match="lever arms must be"):
        step_lever_arms(np.zeros((3, 4, 3)), cfg.mpc.horizon)


@pytest.mark.parametrize("backend", BACKENDS.names())
def test_equal_step_arms_give_the_single_b_solution(backend: str) -> None:
    # (H, 4, 3) arms all equal to the current (4, 3) ones: the same plan as the single B, to rounding
    overrides, problems = _sequences()["lifted_swing"]
    cfg = _cfg(f"solver={backend}", *overrides)
    robot = build_robot(cfg.robot)
    single = make_mpc(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
    steps = make_mpc(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
    for x, x_ref, arms, plan in problems[:3]:
        a = single.solve(x, x_ref, arms, plan)
        b = steps.solve(x, x_ref, np.stack([arms] * cfg.mpc.horizon), plan)
        assert a.success and b.success
        np.testing.assert_allclose(b.inputs, a.inputs, rtol=0, atol=1e-9)
        assert b.objective == pytest.approx(a.objective, rel=1e-12)


@pytest.mark.parametrize("sequence", ["step_arms", "lifted_swing", "walk_random"])
def test_condensed_matrices_equal_a_direct_stacking_of_the_step_models(sequence: str) -> None:
    """The condensed Hessian and gradient against Gamma' Q Gamma built from A_d and each B_k directly.

    x_k = A^k x_0 + sum_j A^(k-1-j) (B_j u_j + g); with u_k = V_k [a_k; b_k], the
    condensed QP in a must be V_a' (Gamma' Q Gamma + r I) V_a and V_a' Gamma' Q (x_free - x_ref),
    and the internal forces b must not move the states (Gamma V_b = 0).
    """
    overrides, problems = _sequences()[sequence]
    cfg = _cfg("solver=daqp", *overrides)
    robot = build_robot(cfg.robot)
    h, period = cfg.mpc.horizon, 1 / cfg.mpc.rate_hz
    q = np.asarray(cfg.mpc.q_diag) * cfg.mpc.objective_scale
    rho = cfg.mpc.r_weight * cfg.mpc.objective_scale
    weight = robot.mass * cfg.sim.gravity
    for x, x_ref, arms, plan in problems[:4]:
        arms = step_lever_arms(arms, h)
        out = build(
            x,
            arms,
            robot.mass,
            np.linalg.inv(robot.inertia_body),
            cfg.sim.gravity,
            period,
            np.ascontiguousarray(x_ref),
            *(np.ascontiguousarray(v, dtype=float) for v in (plan.mu, plan.fz_min, plan.fz_max)),
            q,
            rho,
            *horizon_coefficients(h),
            weight,
            float(cfg.mpc.force_balance_band),
        )
        _, _, _, mask, _, pid, basis, da, db, a_off, b_off, chol, lin = out[:13]
        hess, grad = chol @ chol.T, chol @ lin
        # the direct stacking, from the single-B model of each step
        models = [
            discretize(*continuous_model(x, arms[k], robot.mass, robot.inertia_body, cfg.sim.gravity), period)
            for k in range(h)
        ]
        a_d, g_d = models[0][0], models[0][2]
        gamma = np.zeros((12 * h, 12 * h))
        x_free = np.zeros((h, 12))
        state = x.copy()
        for k in range(h):
            state = a_d @ state + g_d
            x_free[k] = state
            for j in range(k + 1):
                gamma[12 * k : 12 * k + 12, 12 * j : 12 * j + 12] = np.linalg.matrix_power(a_d, k - j) @ models[j][1]
        h_u = gamma.T @ np.diag(np.tile(q, h)) @ gamma + rho * np.eye(12 * h)
        f_u = gamma.T @ (np.tile(q, h) * (x_free - x_ref).ravel())
        na, nb = int(a_off[-1]), int(b_off[-1])
        v_a, v_b = np.zeros((12 * h, na)), np.zeros((12 * h, nb))
        for k in range(h):
            p = pid[k]
            v_a[12 * k : 12 * k + 12, a_off[k] : a_off[k + 1]] = basis[p][:, : da[p]]
            v_b[12 * k : 12 * k + 12, b_off[k] : b_off[k + 1]] = basis[p][:, da[p] : da[p] + db[p]]
        kept = mask.ravel()
        # the bases span exactly the kept forces, orthonormally
        np.testing.assert_allclose(
            np.hstack([v_a, v_b])[kept].T @ np.hstack([v_a, v_b])[kept], np.eye(na + nb), atol=1e-12
        )
        assert np.all(v_a[~kept] == 0.0) and np.all(v_b[~kept] == 0.0)
        scale = np.abs(h_u).max()
        np.testing.assert_allclose(gamma @ v_b, 0.0, atol=1e-12 * np.abs(gamma).max())
        np.testing.assert_allclose(hess, v_a.T @ h_u @ v_a, rtol=0, atol=1e-10 * scale)
        np.testing.assert_allclose(grad, v_a.T @ f_u, rtol=0, atol=1e-10 * np.abs(f_u).max())
