"""The tendon as a bowstring (robot.tendon.routing=bowstring): a straight cable from a guide on the torso to its
anchor on the leg. Its forces are the gradient of its length (exact, with an exact Jacobian for the implicit step),
the torso takes their reaction, a small take-up bends a straight leg as linear beam theory says, the servo stalls
at its torque over the pulley, and a robot walking on bowstrings in free space keeps its momentum."""

from __future__ import annotations

import numpy as np
import pytest

from slotexp.config import LegConfig
from slotexp.soft.integrators import LegSim
from slotexp.soft.loads import add_tendon, tendon_cable, tendon_jacobian, tendon_length
from slotexp.soft.params import O_T, P_TMAX, make_par
from slotexp.soft.rod import build_leg, directors, model_from_shape
from tests.test_leg import _flat, _unflat

L, W, H, E, RHO = 0.19, 0.02, 0.005, 1.0e7, 1200.0
EI = E * W * H**3 / 12
NA = 20  # the anchor node, 2/3 of the way down a 31-node leg


def _bowstring_par(guide=(0.0, 0.011), offset=0.004, **kw) -> np.ndarray:
    return make_par(
        tendon_k=2e4,
        tendon_offset=offset,
        n_anchor=NA,
        tendon_route=1.0,
        tendon_guide_x=guide[0],
        tendon_guide_z=guide[1],
        **kw,
    )


@pytest.mark.parametrize("guide", [(0.0, 0.011), (0.005, -0.008)], ids=["above", "below"])
def test_the_bowstrings_forces_are_its_lengths_gradient_on_the_leg_and_the_torso(guide) -> None:
    """-T grad L on every coordinate the length depends on: the anchor's (node na, the anchor element's angle)
    and the root node's (the guide moves with the torso); the implicit step's gradient is the same."""
    m = build_leg(LegConfig(), 31)
    rng = np.random.default_rng(3)
    pos = m.rest_pos + rng.normal(0, 1e-3, m.rest_pos.shape)
    th = m.rest_theta + rng.normal(0, 0.05, m.rest_theta.shape)
    root = m.rest_theta[0] + 0.03
    par = _bowstring_par(guide)
    tension = 7.0

    def length(q):
        return tendon_length(*_unflat(q), root, par)

    q = _flat(pos, th)
    n, h = len(q), 1e-7
    grad = np.array([(length(q + h * e) - length(q - h * e)) / (2 * h) for e in np.eye(n)])
    c, s = np.empty(len(th)), np.empty(len(th))
    directors(th, c, s)
    f, mo = np.zeros_like(pos), np.zeros_like(th)
    add_tendon(pos, c, s, root, tension, 0.0, par, f, mo)
    np.testing.assert_allclose(_flat(f, mo), -tension * grad, atol=1e-7 * tension)
    band, grad_l = np.zeros((n, 9)), np.zeros(n)
    tendon_jacobian(pos, c, s, root, tension, 0.0, par, 1.0, band, grad_l)
    np.testing.assert_allclose(grad_l, grad, atol=1e-8)
    assert not band.any()  # the geometric stiffness stays explicit (the root's share must match the anchor's)
    # the lever tendon_cable reports is -dL/d(root angle): what the implicit step turns the root's rate with
    _, lever = tendon_cable(pos, th, c, s, root, par, 0.0)
    dl_droot = (tendon_length(pos, th, root + 1e-7, par) - tendon_length(pos, th, root - 1e-7, par)) / 2e-7
    assert lever == pytest.approx(-dl_droot, rel=1e-6)


def test_the_torso_takes_the_cables_reaction() -> None:
    """The cable pulls the anchor towards the guide and the guide towards the anchor: the two forces, and the
    moment they and the anchor's offset make about the root, sum to zero (nothing is unreacted)."""
    m = build_leg(LegConfig(), 31)
    par = _bowstring_par((0.004, -0.006))
    c, s = np.empty(len(m.rest_theta)), np.empty(len(m.rest_theta))
    directors(m.rest_theta, c, s)
    f, mo = np.zeros_like(m.rest_pos), np.zeros_like(m.rest_theta)
    _, lever = tendon_cable(m.rest_pos, m.rest_theta, c, s, m.rest_theta[0], par, 0.0)
    root_moment = add_tendon(m.rest_pos, c, s, m.rest_theta[0], 9.0, lever, par, f, mo)
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-12)
    lever = m.rest_pos - m.rest_pos[0]
    moment = root_moment + np.sum(lever[:, 0] * f[:, 1] - lever[:, 1] * f[:, 0]) + mo.sum()
    assert abs(moment) < 1e-12  # about the root node, where the torso's share f[0] acts
    assert np.linalg.norm(f[0]) == pytest.approx(9.0)  # the torso is pulled by the whole tension


def test_a_small_take_up_bends_a_straight_leg_as_beam_theory_says() -> None:
    """A straight uniform leg (no gravity, no ground), the guide at the root and 6 mm below its centreline, the
    anchor 2/3 down and 4 mm below: the cable's pull at the anchor is a force F = -T u there plus a couple d F_x
    (the anchor is off the centreline); the linear cantilever then deflects its tip by
    F_z a^2 (3L - a) / (6 EI) + C a (2L - a) / (2 EI). The rod's tension, measured, gives the reference."""
    n = 31
    model = model_from_shape(np.column_stack([np.linspace(0, L, n), np.zeros(n)]), W, H, H, E, RHO)
    guide, d = (0.0, -0.006), 0.004
    par = _bowstring_par(guide, d, damping=60.0)
    free0 = tendon_length(model.rest_pos, model.rest_theta, model.rest_theta[0], par)
    sim = LegSim(model, par, free0 - 2e-5)  # 20 um of cable wound in: a small, linear response
    sim.step(1e-4, 20000, "implicit")
    tension = sim.out[O_T]
    a = model.rest_pos[NA, 0]
    anchor = np.array([a, -d])
    u = (anchor - np.array(guide)) / np.linalg.norm(anchor - np.array(guide))
    fx, fz = -tension * u
    couple = d * fx  # r x F with r = (0, -d)
    expected = fz * a**2 * (3 * L - a) / (6 * EI) + couple * a * (2 * L - a) / (2 * EI)
    assert 0.001 < tension < 1.0  # small: the leg bends to follow the cable
    assert sim.tip[1] - model.rest_pos[-1, 1] == pytest.approx(expected, rel=0.03)


def test_the_servo_stalls_at_its_torque_over_the_pulley() -> None:
    """Winding far past what a stiff leg can follow: the tension stops at the stall torque over the pulley
    radius (1.4 N m over 9 mm)."""
    n = 31
    m = model_from_shape(np.column_stack([np.linspace(0, L, n), np.zeros(n)]), W, 0.0135, 0.0135, 1.0e9, RHO)
    par = _bowstring_par((0.0, -0.006), 0.004, damping=60.0)
    par[P_TMAX] = 1.4 / 0.009
    free0 = tendon_length(m.rest_pos, m.rest_theta, m.rest_theta[0], par)
    sim = LegSim(m, par, free0 - 0.05)
    sim.step(1e-4, 5000, "implicit")
    assert sim.out[O_T] * 0.009 == pytest.approx(1.4, rel=1e-9)


def test_a_robot_on_bowstrings_walking_in_free_space_keeps_its_momentum() -> None:
    from tests.test_cosserat import _plant, _walk

    cfg, plant = _plant(
        "sim.gravity=0",
        "sim.ground=false",
        "robot.tendon.routing=bowstring",
        "robot.tendon.guide_height=-0.006",
        "robot.tendon.offset=0.004",
    )
    from tests.test_cosserat import _total_mass

    momentum0, _ = plant.momentum_world()
    com0 = plant.centre_of_mass()
    tension = []
    for _ in range(3):
        _walk(plant, cfg, 0.5)
        tension.append(plant.out[:, O_T].max())
    momentum, _ = plant.momentum_world()
    np.testing.assert_allclose(momentum, momentum0, atol=1e-12)
    assert np.linalg.norm(plant.centre_of_mass() - com0 - momentum0 * 1.5 / _total_mass(plant)) < 1e-6
    assert max(tension) > 1.0  # the cables did pull
