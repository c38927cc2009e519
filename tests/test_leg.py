"""The Cosserat leg against beam theory, its own energy, and between integrators (uniform rod unless noted)."""

import numpy as np
import pytest
from scipy.linalg import eigh

from slotexp.config import LegConfig
from slotexp.errors import DivergenceError
from slotexp.soft.integrators import LegSim, stable_dt
from slotexp.soft.params import make_par
from slotexp.soft.rod import (
    build_leg,
    elastic_energy,
    elastic_forces,
    elastic_hessian_band,
    lateral_stiffness,
    model_from_shape,
    node_arclengths,
)
from tests.helpers import load as load_config

L, W, H, E, RHO = 0.19, 0.02, 0.005, 1.0e7, 1200.0
EI = E * W * H**3 / 12


def uniform(n=31, h=H):
    shape = np.column_stack([np.linspace(0, L, n), np.zeros(n)])
    return model_from_shape(shape, W, h, h, E, RHO)


def settle(sim, integrator="implicit", h=1e-4, seconds=3.0):
    sim.step(h, int(round(seconds / h)), integrator)
    return sim


def _flat(pos, th):
    q = np.zeros(3 * len(pos) - 1)
    q[0::3], q[1::3], q[2::3] = pos[:, 0], pos[:, 1], th
    return q


def _unflat(q):
    return np.column_stack([q[0::3], q[1::3]]), q[2::3].copy()


def test_forces_are_minus_energy_gradient_and_hessian_is_exact():
    m = build_leg(LegConfig(), 11)
    rng = np.random.default_rng(0)
    pos0 = m.rest_pos + rng.normal(0, 1e-3, m.rest_pos.shape)
    th0 = m.rest_theta + rng.normal(0, 0.05, m.rest_theta.shape)
    root = m.rest_theta[0] + 0.02
    args = (m.l0, m.voronoi, m.dtheta0, m.ea, m.ga, m.ei)

    def force(q):
        p, t = _unflat(q)
        f, mo = np.zeros_like(p), np.zeros_like(t)
        elastic_forces(p, t, root, *args, f, mo)
        return _flat(f, mo)

    def energy(q):
        return elastic_energy(*_unflat(q), root, *args)

    q = _flat(pos0, th0)
    n, h = len(q), 1e-7
    grad = np.array([(energy(q + h * e) - energy(q - h * e)) / (2 * h) for e in np.eye(n)])
    np.testing.assert_allclose(force(q), -grad, atol=1e-8 * np.abs(grad).max())
    band = np.zeros((n, 9))
    elastic_hessian_band(pos0, th0, root, *args, band, 1.0)
    hess = np.zeros((n, n))
    for i in range(n):
        for k in range(9):
            if 0 <= i + k - 4 < n:
                hess[i, i + k - 4] = band[i, k]
    jac = np.column_stack([(force(q + h * e) - force(q - h * e)) / (2 * h) for e in np.eye(n)])
    np.testing.assert_allclose(hess, -jac, atol=1e-8 * np.abs(jac).max())
    np.testing.assert_allclose(hess, hess.T, atol=1e-9 * np.abs(hess).max())


@pytest.mark.parametrize("integrator", ["implicit", "symplectic"])
def test_tip_deflection_matches_euler_bernoulli(integrator):
    m = uniform()
    p = -1e-3  # N: small, so the response is linear
    h = 1e-4 if integrator == "implicit" else 0.8 * stable_dt(m)
    sim = settle(LegSim(m, make_par(tip_fz=p, damping=50.0)), integrator, h)
    expected = p * L**3 / (3 * EI)
    assert sim.tip[1] == pytest.approx(expected, rel=0.01)


def test_pure_end_moment_bends_a_circular_arc():
    m = uniform()
    moment = 0.5 * EI / L  # curvature 0.5/L: the tip turns 0.5 rad, a large rotation
    sim = settle(LegSim(m, make_par(tip_m=moment, damping=50.0)))
    radius = EI / moment
    expected = np.array([radius * np.sin(L / radius), radius * (1 - np.cos(L / radius))])
    err = np.linalg.norm(sim.tip - expected) / np.linalg.norm(expected)
    assert err < 0.005
    # element angles sit at element midpoints: the last one at s = L - l0/2
    assert sim.theta[-1] == pytest.approx((L - m.l0[-1] / 2) / radius, rel=1e-3)


def test_first_natural_frequency_matches_cantilever_theory():
    m = uniform()
    n = 3 * m.n_nodes - 1
    band = np.zeros((n, 9))
    elastic_hessian_band(
        m.rest_pos, m.rest_theta, m.rest_theta[0], m.l0, m.voronoi, m.dtheta0, m.ea, m.ga, m.ei, band, 1.0
    )
    k = np.zeros((n, n))
    for i in range(n):
        for j in range(9):
            if 0 <= i + j - 4 < n:
                k[i, i + j - 4] = band[i, j]
    mass = np.zeros(n)
    mass[0::3], mass[1::3], mass[2::3] = m.mass, m.mass, m.inertia
    free = np.arange(2, n)
    omega1 = np.sqrt(eigh(k[np.ix_(free, free)], np.diag(mass[free]), eigvals_only=True)[0])
    theory = 1.875**2 * np.sqrt(EI / (RHO * W * H * L**4))
    assert omega1 == pytest.approx(theory, rel=0.02)
    # and the time integration oscillates at that frequency
    sim = LegSim(m, make_par())
    sim.vel[:, 1] = 0.01 * (m.rest_pos[:, 0] / L) ** 2
    dt = 0.8 * stable_dt(m)
    chunk = 10
    times, tips = [], []
    for k in range(int(4.0 / (chunk * dt))):
        sim.step(dt, chunk, "symplectic")
        times.append((k + 1) * chunk * dt)
        tips.append(sim.tip[1])
    t, z = np.asarray(times), np.asarray(tips) - np.mean(tips)
    up = np.flatnonzero((z[:-1] < 0) & (z[1:] >= 0))
    crossings = t[up] - z[up] * (t[up + 1] - t[up]) / (z[up + 1] - z[up])
    period = np.mean(np.diff(crossings))
    assert 2 * np.pi / period == pytest.approx(theory, rel=0.02)


def test_node_convergence_default_leg_under_gravity_and_tendon():
    tips = {}
    for n in (31, 121):
        cfg = LegConfig(n_nodes=n)
        m = build_leg(cfg)
        na = int(round(2 * (n - 1) / 3))
        sim = LegSim(
            m, make_par(gravity=9.81, damping=50.0, tip_fz=-1.0, tendon_k=2e4, tendon_offset=0.01, n_anchor=na)
        )
        from slotexp.soft.loads import tendon_length

        sim.free_length = tendon_length(sim.pos, sim.theta, sim.root[4], sim.par) - 0.004  # 4 mm wound in
        tips[n] = settle(sim, "implicit", 2e-5 if n == 121 else 1e-4, 2.0).tip
    assert np.linalg.norm(tips[31] - tips[121]) < 1e-3


def _free_leg_tension(n: int, refinement: int) -> float:
    """The default leg's tendon tension (N) at 80 deg, clamped, free of the ground and gravity, settled."""
    from slotexp.soft.statics import clamped_leg
    from slotexp.soft.statics import settle as settle_load

    cfg = load_config(
        "experiment=leg", "sim.gravity=0", "leg_load.ground=false", "leg_load.tendon_deg=80",
        "leg_load.settle_time=1.5", f"robot.leg.n_nodes={n}", f"robot.leg.anchor_refinement={refinement}",
    )  # fmt: skip
    return settle_load(clamped_leg(cfg), cfg)["tension_n"]


def test_the_mesh_refined_before_the_tendons_anchor_keeps_the_anchor_and_the_leg():
    cfg = LegConfig(anchor_refinement=4)
    s, anchor = node_arclengths(cfg, 2.0 / 3.0)
    uniform_s = np.linspace(0.0, cfg.length, cfg.n_nodes)
    assert s.shape == (cfg.n_nodes + 3,) and anchor == 23
    assert s[anchor] == pytest.approx(uniform_s[20]) and np.allclose(np.diff(s[19:24]), cfg.length / 30 / 4)
    refined = build_leg(cfg, anchor_fraction=2.0 / 3.0)
    assert refined.n_nodes == 34 and refined.length == pytest.approx(build_leg(cfg).length, rel=1e-6)
    assert refined.mass.sum() == pytest.approx(build_leg(cfg).mass.sum(), rel=1e-6)
    # unrefined, the mesh is the uniform one exactly (the default changes no bit)
    plain, with_fraction = build_leg(LegConfig()), build_leg(LegConfig(), anchor_fraction=2.0 / 3.0)
    assert all(np.array_equal(a, b) for a, b in zip(plain, with_fraction, strict=True))


def test_the_tendons_anchor_error_is_first_order_in_the_element_before_it_and_refining_it_converges():
    # The cable bends the leg up to its anchor; the staggered rod counts its turn to the last routed element's middle,
    # half an element short. Uniform meshes converge at first order (61 -> 121 nodes halves the error); splitting the
    # one element before the anchor converges the same way, and 7 extra nodes beat 90 more spread evenly.
    uniform = {n: _free_leg_tension(n, 1) for n in (31, 61, 121)}
    limit = 2.0 * uniform[121] - uniform[61]  # Richardson, first order in the element length
    assert (uniform[31] - uniform[61]) / (uniform[61] - uniform[121]) == pytest.approx(2.0, rel=0.1)
    refined = {r: _free_leg_tension(31, r) for r in (2, 4, 8)}
    assert (uniform[31] - refined[2]) / (refined[2] - refined[4]) == pytest.approx(2.0, rel=0.1)
    assert (refined[2] - refined[4]) / (refined[4] - refined[8]) == pytest.approx(2.0, rel=0.1)
    assert uniform[31] / limit - 1.0 > 0.05  # the uniform 31-node leg: 6 % too taut
    assert abs(refined[8] / limit - 1.0) < 0.01 and abs(refined[8] - limit) < abs(uniform[121] - limit)


def test_the_mesh_bench_sets_each_clamped_leg_against_the_even_meshes_first_order_limit(monkeypatch):
    from slotexp.bench import mesh

    monkeypatch.setattr(mesh, "LOADS", mesh.LOADS[:1])  # the free leg
    monkeypatch.setattr(mesh, "EVEN", (31, 61))
    monkeypatch.setattr(mesh, "LIMIT_FROM", (31, 61))
    monkeypatch.setattr(mesh, "SPLITS", (8,))
    cfg = load_config("plant=cosserat", "leg_load.settle_time=1.5")
    rows = {r.extra["mesh"]: r.extra for r in mesh._statics_rows(cfg)}
    coarse, fine = rows["31 nodes"]["tension_n"], rows["61 nodes"]["tension_n"]
    limit = 2.0 * fine - coarse  # the element halves: Richardson's first-order limit
    for extra in rows.values():
        assert extra["tension_error_fraction"] == pytest.approx(extra["tension_n"] / limit - 1.0, rel=1e-9)
    split, even = rows["31 nodes, the anchor's element split in 8"], rows["31 nodes"]
    assert split["nodes"] == 38 and abs(split["tension_error_fraction"]) < 0.2 * even["tension_error_fraction"]


def test_symplectic_energy_drift_without_damping():
    # Symplectic Euler keeps energy within an O(dt) band without secular growth.
    m = uniform()
    sim = LegSim(m, make_par(gravity=9.81))
    sim.vel[:, 1] = 0.2 * (m.rest_pos[:, 0] / L) ** 2
    e0 = sim.energy()
    dt = 0.5 * stable_dt(m)
    energies = []
    for _ in range(int(round(1.0 / (100 * dt)))):
        sim.step(dt, 100, "symplectic")
        energies.append(sim.energy())
    energies = np.asarray(energies)
    assert np.max(np.abs(energies - e0)) < 0.01 * e0
    assert abs(energies[-20:].mean() - energies[:20].mean()) < 0.005 * e0


def _loaded_transient(m, h, integrator="implicit", jacobian_age=1, newton=1, turn=0.0):
    """Smooth loading (the servo winds 4 mm of cable in over 0.1 s, the foot on the ground, friction
    on) at step ``h``: tip (s, z) and tension every 1 ms, and how many Jacobians the implicit step factored."""
    from slotexp.soft.loads import tendon_length

    sim = LegSim(
        m,
        make_par(
            gravity=9.81,
            damping=20.0,
            k_contact=1e5,
            d_contact=10.0,
            mu=0.1,
            ground=1.0,
            tendon_k=2e4,
            tendon_offset=0.01,
            tendon_max=140.0,
            n_anchor=20,
            jacobian_turn=turn,
        ),
    )
    sim.jacobian_age = jacobian_age
    sim.newton = newton
    free0 = tendon_length(sim.pos, sim.theta, sim.root[4], sim.par)
    traj = []
    for k in range(200):
        sim.free_length = free0 - 0.004 * min(1.0, k * 1e-3 / 0.1)
        sim.step(h, int(round(1e-3 / h)), integrator)
        traj.append(np.r_[sim.tip, sim.out[3]])
    return np.asarray(traj), sim.factorisations


def test_implicit_and_symplectic_agree_on_a_transient_with_tendon_and_contact():
    # both first-order schemes must follow the same path
    m = build_leg(LegConfig())
    imp, _ = _loaded_transient(m, 1e-5)
    sym, _ = _loaded_transient(m, 0.5 * stable_dt(m, 1e5), "symplectic")
    assert imp[-1, 2] > 1.0  # the tendon is loaded
    np.testing.assert_allclose(imp[:, :2], sym[:, :2], atol=1e-4)  # tip within 0.1 mm all along
    # the cable's own high-frequency ringing is damped by implicit Euler: compare its mean
    assert imp[-50:, 2].mean() == pytest.approx(sym[-50:, 2].mean(), rel=0.02)


def test_a_reused_jacobian_follows_the_exact_implicit_step():
    # The W-method (factored Jacobian kept up to 20 steps) against a fresh Jacobian every step, on the
    # loaded transient with tendon, contact and friction: the same path, at a fraction of the factorisations.
    m = build_leg(LegConfig())
    exact, n_exact = _loaded_transient(m, 1e-4)
    reused, n_reused = _loaded_transient(m, 1e-4, jacobian_age=20)
    assert n_exact == 2000  # one per step
    assert 100 <= n_reused < 400  # at least one per 20 steps; contact and tendon changes add a few
    np.testing.assert_allclose(reused[:, :2], exact[:, :2], atol=2e-5)  # tip within 0.02 mm all along
    assert reused[-50:, 2].mean() == pytest.approx(exact[-50:, 2].mean(), rel=1e-3)


def test_the_jacobian_is_refactored_once_an_element_has_turned_past_the_limit():
    # plant.jacobian_turn: a factorisation kept by age is made afresh once the elements' largest turn, summed over
    # the steps since it was made, passes the limit; a limit never reached changes nothing, bit for bit
    m = build_leg(LegConfig())
    exact, _ = _loaded_transient(m, 1e-4)
    kept, n_kept = _loaded_transient(m, 1e-4, jacobian_age=10**6)
    same, n_same = _loaded_transient(m, 1e-4, jacobian_age=10**6, turn=10.0)
    assert n_same == n_kept and np.array_equal(same, kept)
    turned, n_turned = _loaded_transient(m, 1e-4, jacobian_age=10**6, turn=0.01)
    assert n_turned > n_kept
    assert np.abs(turned[:, :2] - exact[:, :2]).max() < np.abs(kept[:, :2] - exact[:, :2]).max()
    # step by step: whenever the summed turn had passed the limit at a step's start, that step refactored
    sim = LegSim(m, make_par(gravity=9.81, damping=20.0, tendon_k=2e4, tendon_offset=0.01, n_anchor=20,
                             jacobian_turn=0.01))  # fmt: skip
    sim.jacobian_age = 10**6
    from slotexp.soft.loads import tendon_length

    free0 = tendon_length(sim.pos, sim.theta, sim.root[4], sim.par)
    summed, refreshes = 0.0, 0
    for k in range(400):
        sim.free_length = free0 - 0.004 * min(1.0, k / 200)
        before, count = sim.theta.copy(), sim.factorisations
        sim.step(1e-4, 1, "implicit")
        if summed > 0.01:
            assert sim.factorisations == count + 1
            refreshes += 1
        summed = (0.0 if sim.factorisations > count else summed) + np.abs(sim.theta - before).max()
    assert refreshes >= 3  # the cable curls the leg past the limit again and again


def _stance_after_a_tendon_step(h, newton, seconds=1.0):
    """`slot bench leg`'s loaded leg (the robot's leg at its standing root height, foot on the ground, friction)
    with its cable 30 deg slack for 0.05 s, then stepped to 80 deg, at step ``h`` with ``newton`` passes per
    step: tip (s, z), tension and the ground's normal force after ``seconds``."""
    from slotexp.bench.leg import _loaded_leg

    cfg = load_config("plant=cosserat")
    sim = _loaded_leg(cfg, 1, newton)
    wound = sim.free_length
    sim.free_length = wound + cfg.robot.leg.pulley_radius * np.deg2rad(30.0)
    sim.step(h, max(1, int(round(0.05 / h))), "implicit")
    sim.free_length = wound
    sim.step(h, int(round(seconds / h)), "implicit")
    return np.r_[sim.tip, sim.out[3], sim.out[4]]


def test_newton_corrections_keep_a_loaded_leg_in_contact_stable_up_to_the_control_period():
    # The linearly implicit step sees a switch (a node landing, a foot sticking, the cable going taut) only a
    # step late: on the loaded leg it diverges at 2 ms. Backward Euler, solved by Newton corrections (halving a
    # step they cannot resolve), is stable up to the 1/30 s control period and settles where the converged
    # step does (the tip within 0.02 mm, the tension and the ground's force within 1 %; measured 5 um).
    with pytest.raises(DivergenceError):
        _stance_after_a_tendon_step(2e-3, 1)
    converged = _stance_after_a_tendon_step(2.5e-5, 1)
    assert converged[2] > 10.0 and converged[3] > 1.0  # the cable pulls and the foot presses
    for h in (2e-3, 1e-2, 1.0 / 30.0):
        settled = _stance_after_a_tendon_step(h, 8)
        np.testing.assert_allclose(settled[:2], converged[:2], atol=2e-5)
        np.testing.assert_allclose(settled[2:], converged[2:], rtol=0.01)


def test_newton_corrections_follow_the_linearly_implicit_path_where_both_converge():
    # At 0.1 ms both are first-order steps of the same equations: the smooth loading transient (tip every ms)
    # agrees within 10 um (measured 3.4), the tension within 0.1 %. (The corrections are not a different model.)
    m = build_leg(LegConfig())
    one, _ = _loaded_transient(m, 1e-4)
    newton, _ = _loaded_transient(m, 1e-4, newton=8)
    np.testing.assert_allclose(newton[:, :2], one[:, :2], atol=1e-5)
    assert newton[-50:, 2].mean() == pytest.approx(one[-50:, 2].mean(), rel=1e-3)


def test_the_jacobian_is_refactored_at_its_age_and_at_a_contact_change():
    m = uniform()
    free = LegSim(m, make_par(gravity=9.81, damping=50.0))  # hanging, nothing changes regime
    free.jacobian_age = 10
    free.step(1e-4, 95, "implicit")
    assert free.factorisations == 10  # steps 0, 10, ..., 90
    # the same leg falling onto the ground: each node that touches down refactors at once
    par = make_par(gravity=9.81, damping=5.0, k_contact=1e5, d_contact=10.0, mu=0.5, ground=1.0)
    falling = LegSim(m, par)
    falling.jacobian_age = 10**6
    falling.pos[:, 1] += 1e-3
    falling.step(1e-4, 3000, "implicit")
    assert falling.out[4] > 0.0  # it landed
    assert falling.factorisations >= 2  # the first step, and at least one touch-down


@pytest.mark.parametrize("n", [3, 4, 5, 9, 92])
def test_banded_solver_and_product_match_dense_algebra(n):
    """The unpivoted banded LU and its substitution (written out for full-width rows, generic near
    the ends) solve what numpy's dense solver solves, and the banded product is the dense product,
    for every size up to and past the band."""
    from slotexp.soft.rod import banded_factor, banded_multiply_subtract, banded_substitute

    rng = np.random.default_rng(n)
    dense = np.zeros((n, n))
    band = np.zeros((n, 9))
    for i in range(n):
        for j in range(max(0, i - 4), min(n, i + 5)):
            dense[i, j] = rng.normal() + (12.0 if i == j else 0.0)  # diagonally dominant, like M - h^2 K - h C
            band[i, 4 + j - i] = dense[i, j]
    b, v = rng.normal(size=n), rng.normal(size=n)
    out = b.copy()
    banded_multiply_subtract(band, v, out)
    np.testing.assert_allclose(out, b - dense @ v, rtol=1e-13, atol=1e-13)
    banded_factor(band)
    x = b.copy()
    banded_substitute(band, x)
    np.testing.assert_allclose(x, np.linalg.solve(dense, b), rtol=1e-12, atol=1e-13)


def test_the_sideways_tip_stiffness_is_the_cantilevers_and_the_rigid_leg_has_none():
    # robot.leg.out_of_plane=bending: a strip of even thickness t bends sideways about its stiff axis,
    # I = t w^3 / 12, with the cantilever's tip stiffness 3 E I / L^3 (L its arc length); tapered, it lies
    # between the even strips of its tip's and its root's thickness, and it scales with E.
    even = LegConfig(out_of_plane="bending", thickness_root=0.008, thickness_tip=0.008)
    length = build_leg(even).length
    assert lateral_stiffness(even) == pytest.approx(3 * 1e7 * 0.008 * 0.02**3 / 12 / length**3, rel=1e-6)
    tapered = LegConfig(out_of_plane="bending")
    k = lateral_stiffness(tapered)
    thin, thick = (LegConfig(out_of_plane="bending", thickness_root=t, thickness_tip=t) for t in (0.0035, 0.0135))
    assert lateral_stiffness(thin) < k < lateral_stiffness(thick)
    assert k == pytest.approx(30.8, abs=0.3)  # the paper's leg: 31 N/m, about 4x its in-plane tip stiffness
    assert lateral_stiffness(LegConfig(out_of_plane="bending", youngs_modulus=2e7)) == pytest.approx(2 * k)
    assert lateral_stiffness(LegConfig()) == 0.0  # rigid across the plane, the default


@pytest.mark.parametrize("integrator", ["implicit", "symplectic"])
def test_a_cable_pair_curls_a_straight_leg_up_as_far_as_it_curls_it_down(integrator):
    # robot.tendon.antagonist: the second cable runs the same offset above the centreline, so on a straight
    # leg without gravity or ground letting the servo turn back by theta mirrors winding it on by theta
    from slotexp.soft.loads import pair_free_length, tendon_length
    from slotexp.soft.params import O_TS, P_TPAIR

    m = uniform()
    par = make_par(damping=50.0, tendon_k=2e4, tendon_offset=0.01, tendon_max=140.0, n_anchor=20)
    free0 = tendon_length(m.rest_pos, m.rest_theta, m.rest_theta[0], par)
    h = 2e-4 if integrator == "implicit" else 0.5 * stable_dt(m)
    tips, sides = {}, {}
    for pair in (False, True):
        for wound in (0.004, -0.004):  # m of cable in (the lower one) or out
            p = par.copy()
            if pair:
                p[P_TPAIR] = pair_free_length(m, p, free0)
            sim = LegSim(m, p, free0)
            sim.free_length = free0 - wound
            sim.step(h, int(round(1.0 / h)), integrator)
            tips[pair, wound] = sim.tip - m.rest_pos[-1]
            sides[pair, wound] = sim.out[O_TS]
    assert tips[True, 0.004][1] < -0.02  # curled well down
    np.testing.assert_allclose(tips[True, -0.004], tips[True, 0.004] * [1.0, -1.0], atol=1e-9)
    # wound in, the lower cable pulls as it does alone (the upper one may catch the first swing back)
    np.testing.assert_allclose(tips[False, 0.004], tips[True, 0.004], atol=1e-9)
    np.testing.assert_allclose(tips[False, -0.004], 0.0, atol=1e-12)  # one cable: letting it out does nothing
    assert (sides[True, 0.004], sides[True, -0.004], sides[False, -0.004]) == (1.0, -1.0, 0.0)


def test_the_servo_turns_against_a_cable_on_either_side_at_the_same_speed():
    # the pair's upper cable loads the servo the other way: the speed-torque line is mirrored
    from slotexp.soft.servo import servo_step

    args = (1e-3, 0.005)
    for load in (0.0, 0.7, 1.2):
        up = servo_step(0.0, 1.0, *args, load, 1.4, 6.0, 0.0)
        down = servo_step(0.0, -1.0, *args, -load, 1.4, 6.0, 0.0)
        assert down == -up
        assert up == pytest.approx(6.0 * (1.0 - load / 1.4) * 1e-3)  # at the line's speed for that torque
        assert servo_step(0.0, -1.0, *args, load, 1.4, 6.0, 0.0) == pytest.approx(-6.0e-3)  # the load helps
