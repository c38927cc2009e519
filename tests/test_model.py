"""The MPC's prediction model against the continuous dynamics and the nonlinear plant."""

import numpy as np
import pytest
from scipy.linalg import expm

from slotexp.body import euler_rate_matrix, euler_to_quat, quat_to_euler
from slotexp.mpc import continuous_model, discretize, rotation_from_euler
from slotexp.plants import ForceCommand, nominal_state
from slotexp.plants.ideal import IdealPlant
from slotexp.robot import build_robot
from tests.helpers import load

G = 9.81


def f_continuous(x, u, lever, mass, inertia_body):
    """Eq. (7) in MPC coordinates, attitude terms evaluated at x itself (not frozen)."""
    rot = rotation_from_euler(x[0:3])
    iw_inv = np.linalg.inv(rot @ inertia_body @ rot.T)
    f = u.reshape(4, 3)
    dx = np.zeros(12)
    dx[0:3] = np.linalg.solve(euler_rate_matrix(*x[0:3]), x[6:9])
    dx[3:6] = x[9:12]
    dx[6:9] = iw_inv @ sum(np.cross(lever[i], f[i]) for i in range(4))
    dx[9:12] = f.sum(axis=0) / mass + np.array([0, 0, -G])
    return dx


@pytest.fixture(scope="module")
def robot():
    return build_robot(load().robot)


def test_input_matrix_matches_finite_differences(robot):
    rng = np.random.default_rng(1)
    x = nominal_state(robot) + rng.normal(0, 0.05, 12)
    lever = robot.feet_body + rng.normal(0, 0.01, (4, 3))
    u = rng.normal(0, 2, 12)
    a, b, g = continuous_model(x, lever, robot.mass, robot.inertia_body, G)
    h = 1e-6
    fd = np.column_stack(
        [
            (
                f_continuous(x, u + h * e, lever, robot.mass, robot.inertia_body)
                - f_continuous(x, u - h * e, lever, robot.mass, robot.inertia_body)
            )
            / (2 * h)
            for e in np.eye(12)
        ]
    )
    np.testing.assert_allclose(b, fd, atol=1e-6)
    # the affine model reproduces f itself at the linearisation point
    np.testing.assert_allclose(a @ x + b @ u + g, f_continuous(x, u, lever, robot.mass, robot.inertia_body), atol=1e-9)


def test_state_matrix_matches_finite_differences_at_rest(robot):
    # With omega = 0 and no forces, the frozen attitude terms have zero derivative,
    # so the Jacobian of the full dynamics equals A_c exactly.
    x = nominal_state(robot)
    x[0:3] = [0.05, -0.03, 0.4]
    lever = robot.feet_body
    u = np.zeros(12)
    a, _, _ = continuous_model(x, lever, robot.mass, robot.inertia_body, G)
    h = 1e-6
    fd = np.column_stack(
        [
            (
                f_continuous(x + h * e, u, lever, robot.mass, robot.inertia_body)
                - f_continuous(x - h * e, u, lever, robot.mass, robot.inertia_body)
            )
            / (2 * h)
            for e in np.eye(12)
        ]
    )
    np.testing.assert_allclose(a, fd, atol=1e-7)


def test_zoh_discretisation_is_exact(robot):
    rng = np.random.default_rng(2)
    x = nominal_state(robot) + rng.normal(0, 0.05, 12)
    a, b, g = continuous_model(x, robot.feet_body, robot.mass, robot.inertia_body, G)
    assert np.allclose(a @ a, 0)
    period = 1 / 30
    ad, bd, gd = discretize(a, b, g, period)
    n = 12
    aug = np.zeros((n + 13, n + 13))
    aug[:n, :n] = a
    aug[:n, n : n + 12] = b
    aug[:n, n + 12] = g
    e = expm(aug * period)
    np.testing.assert_allclose(ad, e[:n, :n], atol=1e-12)
    np.testing.assert_allclose(bd, e[:n, n : n + 12], atol=1e-12)
    np.testing.assert_allclose(gd, e[:n, n + 12], atol=1e-12)


def test_one_period_prediction_matches_nonlinear_plant(robot):
    # Static stance forces plus a small horizontal push: the discrete model predicts
    # the nonlinear rigid body one MPC period ahead to within second-order terms.
    x0 = nominal_state(robot)
    x0[0:3] = [0.02, -0.01, 0.1]
    x0[6:9] = [0.05, -0.02, 0.03]
    x0[9:12] = [0.05, 0.01, 0.0]
    plant = IdealPlant(robot, x0, G, 1e-4)
    np.testing.assert_allclose(plant.state(), x0, atol=1e-12)
    forces = np.tile([0.3, -0.1, robot.mass * G / 4], (4, 1))
    lever = plant.feet() - x0[3:6]
    a, b, g = continuous_model(x0, lever, robot.mass, robot.inertia_body, G)
    period = 1 / 30
    ad, bd, gd = discretize(a, b, g, period)
    predicted = ad @ x0 + bd @ forces.ravel() + gd
    plant.step(ForceCommand(forces), period)
    actual = plant.state()
    np.testing.assert_allclose(actual[3:6], predicted[3:6], atol=2e-5)  # m
    np.testing.assert_allclose(actual[9:12], predicted[9:12], atol=2e-5)  # m/s
    np.testing.assert_allclose(actual[0:3], predicted[0:3], atol=2e-3)  # rad
    np.testing.assert_allclose(actual[6:9], predicted[6:9], atol=5e-2)  # rad/s; lever arms rotate in the plant


def test_euler_quaternion_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(50):
        rpy = rng.uniform([-3, -1.4, -3], [3, 1.4, 3])
        np.testing.assert_allclose(quat_to_euler(euler_to_quat(*rpy)), rpy, atol=1e-12)
