"""The QP: every solution satisfies its constraints, the backends agree, the band matters."""

import numpy as np
import pytest

from slotexp.backends import backend_class
from slotexp.controllers.paper import PaperController as Controller
from slotexp.gait import GaitMatrix, contact_plan
from slotexp.plants import nominal_state
from slotexp.reference import reference
from slotexp.robot import build_robot
from tests.helpers import PLAN_TOL, check_plan_constraints, load


def _problem(*overrides, seed=0, offset_scale=1.0):
    # these tests exercise the CVXPY formulation: Clarabel unless a test picks a CVXPY solver
    if not any(o.startswith("solver=") for o in overrides):
        overrides = ("solver=clarabel", *overrides)
    cfg = load(*overrides)
    robot = build_robot(cfg.robot)
    rng = np.random.default_rng(seed)
    x = nominal_state(robot)
    x += offset_scale * np.concatenate(
        [rng.normal(0, 0.05, 3), [0, 0, rng.normal(0, 0.005)], rng.normal(0, 0.1, 3), rng.normal(0, 0.05, 3)]
    )
    gait = GaitMatrix(cfg.gait.phases)
    for _ in range(rng.integers(0, 30)):
        gait.roll()
    plan = contact_plan(gait.contacts(cfg.mpc.horizon), cfg.gait, cfg.mpc.f_min_stance, cfg.mpc.f_max)
    x_ref = reference(x, 0.0, cfg.gait, 1 / cfg.mpc.rate_hz, cfg.mpc.horizon)
    return cfg, robot, x, x_ref, plan


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("gait", ["walk", "crawl", "omni60"])
def test_solutions_satisfy_every_constraint(seed, gait):
    cfg, robot, x, x_ref, plan = _problem(f"gait={gait}", seed=seed)
    mpc = backend_class(cfg.solver.name)(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
    sol = mpc.solve(x, x_ref, robot.feet_body, plan)
    assert sol.success, sol.status
    check_plan_constraints(cfg, robot, sol, x, plan)
    # the predicted states obey the model exactly (equality constraints)
    mpc.set_model(x, robot.feet_body)
    a, b, g = mpc.a.value, mpc.b[0].value, mpc.g.value
    u = mpc.u.value
    for k in range(cfg.mpc.horizon):
        np.testing.assert_allclose(sol.predicted[k + 1], a @ sol.predicted[k] + b @ u[:, k] + g, atol=1e-6)


@pytest.mark.parametrize("seed", range(3))
def test_cvxpy_backends_agree(seed):
    results = {}
    for solver in ("clarabel", "osqp", "scs"):
        overrides = [f"solver={solver}", "solver.eps_abs=1e-7", "solver.eps_rel=1e-7", "solver.max_iters=200000"]
        cfg, robot, x, x_ref, plan = _problem(*overrides, seed=seed, offset_scale=0.5)
        mpc = backend_class(cfg.solver.name)(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
        sol = mpc.solve(x, x_ref, robot.feet_body, plan)
        assert sol.success, (solver, sol.status)
        results[solver] = sol
    ref = results["clarabel"]
    for name, sol in results.items():
        assert sol.objective == pytest.approx(ref.objective, rel=1e-3, abs=1e-9), name
        np.testing.assert_allclose(sol.predicted[1:, 5], ref.predicted[1:, 5], atol=1e-5, err_msg=name)
        np.testing.assert_allclose(sol.predicted[1:, 9], ref.predicted[1:, 9], atol=1e-4, err_msg=name)


def test_strict_force_balance_cannot_correct_height():
    # With sum f_z = m g exactly, the model has no vertical acceleration: a height
    # error stays as it is over the whole horizon. A band lets the MPC lift the body.
    for band, moves in ((0.0, False), (2.0, True)):
        cfg, robot, x, x_ref, plan = _problem(f"mpc.force_balance_band={band}", offset_scale=0.0)
        x = nominal_state(robot)
        x[5] = x_ref[0, 5] - 0.01
        mpc = backend_class(cfg.solver.name)(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
        sol = mpc.solve(x, x_ref, robot.feet_body, plan)
        assert sol.success
        rise = sol.predicted[-1, 5] - x[5]
        assert (rise > 1e-3) == moves, (band, rise)
        if not moves:
            assert abs(rise) < 1e-6


def test_infeasible_step_falls_back_to_last_feasible_input():
    # Three legs cannot carry m g at f_z <= 6 N with the strict balance: infeasible.
    cfg = load("gait.swing_contact=false", "mpc.force_balance_band=0", "gait.phases=[[1,1,1,1,1],[29,0,1,1,1]]")
    robot = build_robot(cfg.robot)
    ctrl = Controller(cfg, robot)
    x = nominal_state(robot)
    feet = robot.feet_body + x[3:6]
    first = ctrl.step(0.0, x, feet)  # four legs at k = 0, three from k = 1: the horizon is infeasible
    assert first.fallback and ctrl.infeasible_steps == 1
    np.testing.assert_allclose(first.forces, np.tile([0, 0, robot.mass * 9.81 / 4], (4, 1)))


def test_feasible_steps_update_last_feasible_input():
    cfg = load()
    robot = build_robot(cfg.robot)
    ctrl = Controller(cfg, robot)
    x = nominal_state(robot)
    step = ctrl.step(0.0, x, robot.feet_body + x[3:6])
    assert not step.fallback
    np.testing.assert_allclose(ctrl.last_feasible, step.forces)
    assert all(v <= PLAN_TOL for v in step.violations.values())
