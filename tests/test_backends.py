"""Every QP backend solves the same problem: same objective, every constraint satisfied.

The reference is Clarabel through CVXPY at tight tolerances. Sequences are fed to
one instance per backend, so warm starts and in-place updates are exercised:
random perturbed states on three gaits, a closed-loop walk with a push, the
zero-force (swing legs lifted) gait that removes variables, and the strict balance.
"""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from slotexp.backends import BACKENDS, backend_class, make_mpc
from slotexp.controllers.paper import PaperController as Controller
from slotexp.gait import GaitMatrix, contact_plan
from slotexp.mpc import plan_violations
from slotexp.plants import ForceCommand, nominal_state
from slotexp.plants.ideal import IdealPlant
from slotexp.reference import reference
from slotexp.robot import build_robot
from tests.helpers import check_plan_constraints, load

# Objective agreement with the reference, relative (plus 1e-9 absolute). The active-set
# and interior-point solutions are exact; OSQP and SCS stop at eps = 1e-5 (OSQP's
# polish does not always succeed), which moves the objective by up to a few 1e-3.
REL_TOL = {"daqp": 1e-6, "clarabel": 1e-5, "osqp_direct": 5e-3, "osqp": 5e-3, "scs": 5e-3}
# Largest constraint violation allowed over the whole plan (N): exact for the active-set and
# interior-point solvers; OSQP's own criterion eps_abs + eps_rel |Az| is 2.2e-4 N on a balance row.
VIOLATION_TOL = {"daqp": 1e-6, "clarabel": 1e-6, "osqp_direct": 5e-4, "osqp": 5e-4, "scs": 1e-3}
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
    ["walk_random", "crawl_random", "omni_random", "strict_balance", "lifted_swing", "lifted_crawl", "closed_loop"],
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
        assert sol.objective == pytest.approx(ref.objective, rel=REL_TOL[backend], abs=1e-9), (backend, sequence, i)
        worst = plan_violations(sol.inputs, plan, weight, cfg.mpc.force_balance_band)
        assert max(worst.values()) <= VIOLATION_TOL[backend], (backend, sequence, i, worst)
        if VIOLATION_TOL[backend] <= 1e-4:  # test_mpc's checks use 0.1 mN; first-order solvers meet their eps
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
        assert w.objective == pytest.approx(c.objective, rel=REL_TOL[backend], abs=1e-9)


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
