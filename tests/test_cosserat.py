"""The coupled soft-leg plant: action and reaction between legs and torso, and static load sharing."""

import numpy as np
import pytest

from slotexp.cosserat import CosseratPlant, DivergenceError
from slotexp.legsim import P_GROUND
from slotexp.plant import nominal_state
from slotexp.robot import build_robot
from tests.helpers import load


def _plant(*overrides):
    cfg = load("plant=cosserat", *overrides)
    robot = build_robot(cfg.robot)
    return cfg, CosseratPlant(cfg, robot, nominal_state(robot))


def _vertical_momentum(plant):
    legs = np.sum(plant.model.mass[1:] * plant.vel[:, 1:, 1])
    return plant.torso_mass * plant.torso[9] + legs


def test_free_fall_conserves_momentum_through_the_coupling():
    # No ground: internal forces (leg elasticity, tendon, root reactions) cancel, so the
    # whole robot's vertical momentum changes by exactly -M g t.
    cfg, plant = _plant()
    plant.par[:, P_GROUND] = 0.0
    momentum0 = _vertical_momentum(plant)  # the legs may still move after being set down
    total_mass = plant.torso_mass + 4 * plant.model.mass[1:].sum()
    assert total_mass == pytest.approx(cfg.robot.torso.mass + 4 * plant.model.mass.sum())
    for k in range(6):
        plant.step(np.zeros((4, 3)), 1 / 30, tendon_deg=np.full(4, 20.0 * k))
    t = 6 / 30
    assert _vertical_momentum(plant) - momentum0 == pytest.approx(-total_mass * 9.81 * t, rel=1e-6)


def test_standing_robot_carries_its_weight_on_its_feet():
    # The torso bounces on its soft legs at about 1 Hz, lightly damped: average the third second.
    cfg, plant = _plant()
    normals, vz = [], []
    for k in range(90):  # 3 s with the tendons at a fixed angle
        plant.step(np.zeros((4, 3)), 1 / 30, tendon_deg=np.full(4, 80.0))
        if k >= 60:
            normals.append(plant.out[:, 4].copy())
            vz.append(plant.state()[11])
    weight = (cfg.robot.torso.mass + 4 * plant.model.mass.sum()) * 9.81
    normals = np.asarray(normals)
    assert normals.sum(axis=1).mean() == pytest.approx(weight, rel=0.01)
    np.testing.assert_allclose(normals.mean(axis=0), normals.mean(), rtol=0.05)  # symmetric robot, symmetric load
    assert abs(np.mean(vz)) < 2e-3
    assert 0.02 < plant.state()[5] < 0.1  # held up by the legs, well above the ground


def test_tendon_lifts_the_torso():
    heights = []
    for angle in (40.0, 100.0):
        _, plant = _plant()
        for _ in range(45):
            plant.step(np.zeros((4, 3)), 1 / 30, tendon_deg=np.full(4, angle))
        heights.append(plant.state()[5])
    assert heights[1] > heights[0] + 0.002


def test_symplectic_above_its_limit_stops_with_the_limit_named():
    with pytest.raises(DivergenceError) as exc:
        _, plant = _plant("plant.integrator=symplectic", "sim.dt=2e-4")
        for _ in range(30):
            plant.step(np.zeros((4, 3)), 1 / 30, tendon_deg=np.full(4, 60.0))
    message = str(exc.value)
    assert "sim.dt = 0.0002" in message and "stability limit" in message and "\n" not in message


def test_a_robot_set_down_below_its_height_starts_without_a_jump():
    # Offsets that start the feet below the ground: the legs settle under the held torso
    # first, so the run starts without a contact impulse.
    cfg = load("plant=cosserat")
    robot = build_robot(cfg.robot)
    x0 = nominal_state(robot)
    x0[5] -= 0.008
    x0[0] = 0.05
    low = CosseratPlant(cfg, robot, x0)
    assert np.all(low.leg_world()[:, :, 2] > -2e-3)  # nothing deep in the ground after settling
    low.step(np.zeros((4, 3)), 1 / 30, tendon_deg=np.full(4, 80.0))
    assert np.linalg.norm(low.state()[9:12]) < 0.1  # no launch


def test_markers_follow_the_paper_nodes():
    _, plant = _plant()
    markers = plant.markers()
    for leg in ("FL", "RL", "RR", "FR"):
        for node in (0, 10, 20, 30):
            assert f"{leg}_n{node}" in markers
        np.testing.assert_allclose(markers[f"{leg}_n30"], markers[f"{leg}_foot"])
    np.testing.assert_allclose(plant.feet()[:, 2], 0.0, atol=5e-4)  # set-down feet rest on the ground
