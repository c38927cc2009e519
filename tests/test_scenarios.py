"""A scenario's perturbations (slotexp/scenarios.py): pushes cut the period exactly, forces add, and a new
kind of perturbation needs no plant of its own."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from slotexp.config import Impulse, NoiseConfig, ScenarioConfig
from slotexp.plants import ForceCommand, nominal_state
from slotexp.plants.ideal import IdealPlant
from slotexp.robot import build_robot
from slotexp.scenarios import Disturbance, Impulses, ProcessNoise, advance, perturbations
from tests.helpers import load

PERIOD = 1 / 30


def _free_body():
    """The ideal plant without gravity and with no leg forces: a free rigid body, whose motion is analytic."""
    cfg = load("sim.gravity=0")
    robot = build_robot(cfg.robot)
    return IdealPlant(robot, nominal_state(robot), 0.0, cfg.sim.dt), robot.mass


IDLE = ForceCommand(np.zeros((4, 3)))


def test_a_push_inside_a_period_acts_from_its_instant_on():
    plant, mass = _free_body()
    p0 = plant.state()[3:6].copy()
    push = Impulses([Impulse(t=0.01, linear=[0.3, 0.0, 0.0])])
    advance(plant, IDLE, 0.0, PERIOD, [push], np.random.default_rng(0))
    v = 0.3 / mass
    np.testing.assert_allclose(plant.state()[9:12], [v, 0, 0], atol=1e-12)
    np.testing.assert_allclose(plant.state()[3:6] - p0, [v * (PERIOD - 0.01), 0, 0], atol=1e-12)
    assert not push.pending  # given once
    advance(plant, IDLE, PERIOD, PERIOD, [push], np.random.default_rng(0))
    np.testing.assert_allclose(plant.state()[9:12], [v, 0, 0], atol=1e-12)


@dataclass
class SteadyPush:
    """A new kind of perturbation, defined here: a constant force on the torso between two instants."""

    force: np.ndarray
    start: float
    stop: float

    def over(self, t0: float, t1: float, rng: np.random.Generator) -> Disturbance:
        return Disturbance(force=self.force if self.start - 1e-9 <= t0 < self.stop - 1e-9 else None)


def test_a_new_kind_of_perturbation_moves_any_plant_without_a_plant_edit():
    plant, mass = _free_body()
    push = SteadyPush(np.array([0.0, 2.0, 0.0]), 0.0, 0.5)
    for k in range(30):  # 1 s: pushed for 15 periods (0.5 s), then coasting
        advance(plant, IDLE, k * PERIOD, PERIOD, [push], np.random.default_rng(0))
    v = 2.0 * 0.5 / mass
    np.testing.assert_allclose(plant.state()[9:12], [0, v, 0], atol=1e-9)
    travelled = 0.5 * 2.0 / mass * 0.5**2 + v * 0.5
    assert plant.state()[4] - nominal_state(build_robot(load().robot))[4] == pytest.approx(travelled, rel=1e-9)


def test_forces_of_several_perturbations_add_and_noise_draws_once_per_period():
    plant, mass = _free_body()
    a = SteadyPush(np.array([1.0, 0.0, 0.0]), 0.0, 1.0)
    noise = ProcessNoise(0.5)
    rng = np.random.default_rng(7)
    advance(plant, IDLE, 0.0, PERIOD, [a, noise, Impulses([Impulse(t=0.02, linear=[0, 0, 0.1])])], rng)
    drawn = np.random.default_rng(7).normal(0.0, 0.5, 3)  # one draw, held over the whole (cut) period
    expected = (np.array([1.0, 0.0, 0.0]) + drawn) * PERIOD / mass + np.array([0, 0, 0.1]) / mass
    np.testing.assert_allclose(plant.state()[9:12], expected, atol=1e-12)


def test_a_scenario_config_lists_only_the_perturbations_that_act():
    assert perturbations(ScenarioConfig()) == []
    acting = perturbations(ScenarioConfig(impulses=[Impulse(t=1.0)], noise=NoiseConfig(process_force_sigma=0.2)))
    assert [type(p) for p in acting] == [Impulses, ProcessNoise]
