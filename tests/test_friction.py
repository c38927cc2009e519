"""The feet's friction solved at the implicit step's end (plant.friction=solved, slotexp/soft/friction.py)."""

import numpy as np
import pytest
from scipy.optimize import minimize

from slotexp.soft.friction import ROW_V, friction_work, solve_friction
from slotexp.soft.loads import coulomb_friction, friction_tangent
from slotexp.soft.params import P_FSOLVE, P_MU
from tests.helpers import load

MU, V_EPS = 0.3, 1e-3


@pytest.mark.parametrize("mu_s", [0.0, 0.8], ids=["coulomb", "static"])
@pytest.mark.parametrize("v, v_other", [(2e-4, 0.0), (-3e-4, 4e-4), (0.02, 0.0), (-0.015, 0.01), (0.5e-3, -0.7e-3)])
def test_the_friction_tangent_is_the_laws_derivative(mu_s, v, v_other):
    # central differences of coulomb_friction along v, the slip's other component held (the Stribeck
    # curve's fall included where there is a static coefficient), within 1e-6 of the slope's scale
    nrm, v_s, d = 2.0, 0.01, 1e-9
    up, _ = coulomb_friction(v + d, v_other, nrm, MU, V_EPS, mu_s, v_s)
    down, _ = coulomb_friction(v - d, v_other, nrm, MU, V_EPS, mu_s, v_s)
    assert friction_tangent(v, v_other, nrm, MU, V_EPS, mu_s, v_s) == pytest.approx(
        (up - down) / (2 * d), abs=1e-6 * max(MU, mu_s) * nrm / V_EPS
    )


def _dissipation(v, v_other, nrm):
    """The regularised Coulomb law's potential: psi with -dpsi/dv = coulomb_friction (plain, mu = MU)."""
    s = np.hypot(v, v_other)
    return np.where(s < V_EPS, MU * nrm * s * s / (2 * V_EPS), MU * nrm * (s - V_EPS / 2))


def _problem(seed, n_nodes=7, pressed=(3, 4, 5, 6), h=1e-3):
    """A leg-shaped friction problem: a random positive definite W^-1 over the 3N - 1 dofs, its pressed nodes'
    columns in jvec's rows 2 + i, start velocities and a friction-free velocity change."""
    rng = np.random.default_rng(seed)
    nd = 3 * n_nodes - 1
    a = rng.normal(size=(nd, nd))
    winv = 1e-3 * (a @ a.T / nd + 0.05 * np.eye(nd))  # s/kg: a few grams' compliance, strongly coupled
    winv[:2, :] = winv[:, :2] = 0.0  # the root's rows are prescribed
    jvec = np.zeros((2 + n_nodes, nd))
    flags = np.zeros(n_nodes)
    for i in pressed:
        jvec[2 + i] = winv[:, 3 * i]
        flags[i] = 1.0
    vstart = rng.normal(scale=0.01, size=nd)
    dv = rng.normal(scale=0.01, size=nd)
    normal = np.where(flags > 0, rng.uniform(0.5, 3.0, n_nodes), 0.0)
    vlat = rng.normal(scale=0.005, size=n_nodes)
    return winv, jvec, flags, vstart, dv, normal, vlat, h


@pytest.mark.parametrize("seed", range(6))
def test_the_friction_solve_finds_the_step_whose_friction_is_the_law_at_its_end(seed):
    # v = b + h D F(v) is the optimality condition of a strictly convex problem (plain Coulomb friction):
    # min 1/(2h) (v - b)^T D^-1 (v - b) + sum psi_k(v_k). scipy's BFGS on that, an independent route, finds
    # the same end velocities; every dof moves by the friction's impulses through W^-1; each friction is in
    # the cone and against its node's end slip.
    winv, jvec, flags, vstart, dv, normal, vlat, h = _problem(seed)
    pressed = np.flatnonzero(flags)
    dofs = 3 * pressed
    b = vstart[dofs] + dv[dofs]
    d_inv = np.linalg.inv(winv[np.ix_(dofs, dofs)])

    def objective(v):
        r = v - b
        return r @ d_inv @ r / (2 * h) + _dissipation(v, vlat[pressed], normal[pressed]).sum()

    expected = minimize(objective, b, method="BFGS", options={"gtol": 1e-12}).x
    before = dv.copy()
    total, iterations, converged = solve_friction(
        jvec, flags, vstart, dv, normal, vlat, h, MU, V_EPS, 0.0, 1.0, friction_work(len(flags))
    )
    end = vstart[dofs] + dv[dofs]
    np.testing.assert_allclose(end, expected, atol=1e-7)
    assert converged and 0 < iterations < 20
    force = np.array([coulomb_friction(v, vlat[i], normal[i], MU, V_EPS, 0.0, 1.0)[0] for v, i in zip(end, pressed)])
    np.testing.assert_allclose(dv, before + h * winv[:, dofs] @ force, atol=1e-15)
    assert total == pytest.approx(force.sum(), abs=1e-9)  # (the sticking slope amplifies round-off 600-fold)
    assert np.all(np.abs(force) <= MU * normal[pressed] * (1 + 1e-12))
    assert np.all(force * end <= 0.0)


def test_the_friction_solve_meets_the_law_with_a_falling_static_coefficient_too():
    # With a static coefficient the law is not monotone (its Stribeck fall): Newton with its line search
    # still ends where v = b + h D F(v), to the solve's tolerance
    winv, jvec, flags, vstart, dv, normal, vlat, h = _problem(11)
    mu_s, v_s = 0.8, 0.01
    pressed = np.flatnonzero(flags)
    dofs = 3 * pressed
    b = vstart[dofs] + dv[dofs]
    _, _, converged = solve_friction(jvec, flags, vstart, dv, normal, vlat, h, MU, V_EPS, mu_s, v_s, friction_work(7))
    end = vstart[dofs] + dv[dofs]
    force = np.array([coulomb_friction(v, vlat[i], normal[i], MU, V_EPS, mu_s, v_s)[0] for v, i in zip(end, pressed)])
    assert converged
    np.testing.assert_allclose(end, b + h * winv[np.ix_(dofs, dofs)] @ force, atol=1e-11)


def _indefinite(winv, seed):
    """``winv`` plus a random symmetric part that leaves it indefinite: a linearised step whose W is not positive
    definite (a soft leg curled hard at a large step)."""
    a = np.random.default_rng(seed + 1000).normal(size=winv.shape)
    a[:2] = a[:, :2] = 0.0
    return winv + 3e-3 * (a + a.T) / 2 / np.sqrt(winv.shape[0])


def _stiff_problem(seed, indefinite=False):
    """_problem with a node of a fraction of a gram's compliance (W^-1 1e6 times _problem's), its W optionally
    indefinite; returns it and its pressed nodes' dofs."""
    winv, jvec, flags, vstart, dv, normal, vlat, h = _problem(seed)
    if indefinite:
        winv = _indefinite(winv, seed)
    winv *= 1e6
    pressed = np.flatnonzero(flags)
    for i in pressed:
        jvec[2 + i] = winv[:, 3 * i]
    return (winv, jvec, flags, vstart, dv, normal, vlat, h), 3 * pressed


@pytest.mark.parametrize("seed", [1, 3, 5])
def test_the_friction_solve_converges_where_newton_alone_stalls(seed):
    # A static coefficient's Stribeck fall (the law not monotone) on a stiff problem: Newton with its line
    # search alone stalls on each of these (measured: on 119 of 200 such problems), then Gauss-Seidel's
    # sweeps, whose one-node equations always have a root, carry it on (all 200 converge). It ends where
    # v = b + h D F(v), to the solve's tolerance or the rounding of the terms it sums.
    (winv, jvec, flags, vstart, dv, normal, vlat, h), dofs = _stiff_problem(seed)
    pressed = dofs // 3
    b = vstart[dofs] + dv[dofs]
    work = friction_work(len(flags))
    _, _, converged = solve_friction(jvec, flags, vstart, dv, normal, vlat, h, MU, V_EPS, 1.0, 0.01, work)
    v = work[len(flags) + ROW_V, : len(pressed)]  # the solve's end velocities, whose law the friction is
    force = np.array([coulomb_friction(x, vlat[i], normal[i], MU, V_EPS, 1.0, 0.01)[0] for x, i in zip(v, pressed)])
    impulses = h * winv[np.ix_(dofs, dofs)] * force
    assert converged
    np.testing.assert_allclose(v, b + impulses.sum(axis=1), rtol=0, atol=1e-12 + 1e-13 * np.abs(impulses).sum())
    np.testing.assert_allclose(vstart[dofs] + dv[dofs], v, rtol=0, atol=1e-12 + 1e-13 * np.abs(impulses).sum())


def test_a_friction_solve_on_a_step_that_is_not_dissipative_is_reported_unconverged():
    # Where the step's compliance has an indefinite symmetric part (W indefinite) the friction problem is no
    # dissipative one: its roots need not be unique, and one far from the start's slip can throw the leg. Newton
    # stalls here; the solve does not go on to Gauss-Seidel, it says so (the plant counts it), and the friction
    # it leaves is still the law at an iterate: in the cone, against that iterate's slip.
    (winv, jvec, flags, vstart, dv, normal, vlat, h), dofs = _stiff_problem(40, indefinite=True)
    assert np.linalg.eigvalsh(winv[np.ix_(dofs, dofs)] + winv[np.ix_(dofs, dofs)].T).min() < 0.0
    before = dv.copy()
    work = friction_work(len(flags))
    total, _, converged = solve_friction(jvec, flags, vstart, dv, normal, vlat, h, MU, V_EPS, 0.0, 1.0, work)
    assert not converged
    pressed = dofs // 3
    v = work[len(flags) + ROW_V, : len(pressed)]
    force = np.array([coulomb_friction(x, vlat[i], normal[i], MU, V_EPS, 0.0, 1.0)[0] for x, i in zip(v, pressed)])
    assert np.all(np.abs(force) <= MU * normal[pressed] * (1 + 1e-12)) and np.all(force * v <= 0.0)
    np.testing.assert_allclose(dv, before + h * winv[:, dofs] @ force, rtol=1e-12, atol=1e-15)
    assert total == pytest.approx(force.sum())


def _dragged_foot(h: float, solved: bool, seconds: float = 0.3) -> np.ndarray:
    """`slot bench leg`'s loaded leg (tendon at 80 deg, foot pressed with about 5 N, mu 0.1) with its root dragged
    forwards at 20 mm/s from rest: the tip (s, z) every 1 ms. The foot sticks, loads and slides."""
    from slotexp.bench.leg import _loaded_leg

    sim = _loaded_leg(load("plant=cosserat"), 5 if h > 1e-4 else 1)
    assert sim.par[P_MU] == 0.1
    sim.par[P_FSOLVE] = 1.0
    sim.step(2e-4, 1000, "implicit")  # settled alike
    sim.par[P_FSOLVE] = 1.0 if solved else 0.0
    sim.root[2] = speed = 0.02
    tips = []
    for _ in range(int(round(seconds / 1e-3))):
        for _ in range(int(round(1e-3 / h))):
            sim.step(h, 1, "implicit")
            sim.root[0] += h * speed
        tips.append(sim.tip)
    return np.asarray(tips)


def test_a_dragged_foot_follows_its_converged_path_at_millisecond_steps_when_its_friction_is_solved():
    # The secant slope makes a slipping foot answer its load as if it weighed h mu N / |v| more: its path is
    # off the converged one (2.5e-5 s) by 0.07 mm at 0.2 ms, 0.14 at 0.5 ms, 0.25 at 1 ms. Solved at the
    # step's end: 0.013, 0.022, 0.029 mm. (The two converged paths agree within 0.018 mm: the same law, as
    # the step goes to zero.) The foot slides 5.8 mm in all.
    converged = {solved: _dragged_foot(2.5e-5, solved) for solved in (False, True)}
    assert np.ptp(converged[True][:, 0]) > 4e-3
    np.testing.assert_allclose(converged[True], converged[False], atol=3e-5)
    error = {solved: np.abs(_dragged_foot(1e-3, solved) - converged[solved]).max() for solved in (False, True)}
    assert error[True] < 6e-5
    assert error[False] > 1.5e-4


@pytest.mark.parametrize("model", [[], ["robot.contact.static_friction=0.3"]], ids=["default", "static0.3"])
def test_every_friction_solve_of_a_walking_robot_converges(model):
    # The forward gait played for 2 s at the step the yardstick admits with the solve (5e-4 s): no solve stops
    # unconverged (the plant counts those that do). With a static coefficient (the law not monotone) Newton
    # alone left 170 of them so; Gauss-Seidel's sweeps carry each on.
    from tests.test_cosserat import _plant, _walk

    cfg, plant = _plant("plant.friction=solved", "sim.dt=5e-4", *model)
    _walk(plant, cfg, 2.0)
    assert plant.normal.sum() > 10.0  # standing on its feet
    assert plant.unsolved_frictions == 0
