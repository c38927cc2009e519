"""Rigid torso invariants: free flight, momentum and energy, impulses, static stance."""

import numpy as np

from slotexp.body import quat_to_rot
from slotexp.plants import ForceCommand, nominal_state
from slotexp.plants.ideal import IdealPlant
from slotexp.robot import build_robot
from tests.helpers import load


def _robot():
    return build_robot(load().robot)


def test_free_rotation_conserves_energy_and_angular_momentum():
    robot = _robot()
    x0 = nominal_state(robot)
    x0[6:9] = [1.0, -2.0, 3.0]  # tumbling about no principal axis: gyroscopic coupling active
    plant = IdealPlant(robot, x0, gravity=0.0, dt=1e-3)

    def invariants():
        rot = quat_to_rot(plant._s[3:7])
        w_b = plant._s[10:13]
        i_w = robot.inertia_body @ w_b
        return 0.5 * w_b @ i_w, rot @ i_w

    e0, l0 = invariants()
    for _ in range(30):
        plant.step(ForceCommand(np.zeros((4, 3))), 1 / 30)
    e1, l1 = invariants()
    assert abs(e1 - e0) / e0 < 1e-6
    np.testing.assert_allclose(l1, l0, rtol=1e-6)


def test_ballistic_flight_is_exact():
    robot = _robot()
    x0 = nominal_state(robot)
    x0[9:12] = [0.3, -0.2, 1.0]
    plant = IdealPlant(robot, x0, gravity=9.81, dt=1e-3)
    plant.step(ForceCommand(np.zeros((4, 3))), 0.5)
    t = 0.5
    expected = x0[3:6] + x0[9:12] * t + np.array([0, 0, -0.5 * 9.81 * t**2])
    np.testing.assert_allclose(plant.state()[3:6], expected, atol=1e-12)


def test_static_stance_forces_hold_the_torso():
    robot = _robot()
    x0 = nominal_state(robot)
    plant = IdealPlant(robot, x0, gravity=9.81, dt=1e-3)
    # solve for vertical forces with zero net force and zero moment about the CoM
    r = robot.feet_body
    a = np.vstack([np.ones(4), r[:, 1], r[:, 0]])
    fz = np.linalg.lstsq(a, [robot.mass * 9.81, 0, 0], rcond=None)[0]
    forces = np.column_stack([np.zeros(4), np.zeros(4), fz])
    # The CoM is above the force points, so this is an unstable (inverted-pendulum)
    # equilibrium: round-off grows like exp(11 t). Over 0.2 s it must stay at round-off.
    for _ in range(6):
        plant.step(ForceCommand(forces), 1 / 30)
    np.testing.assert_allclose(plant.state(), x0, atol=1e-12)


def test_impulse_changes_momentum_by_its_value():
    robot = _robot()
    plant = IdealPlant(robot, nominal_state(robot), gravity=0.0, dt=1e-3)
    plant.apply_impulse(np.array([0.05, -0.02, 0.01]), np.array([0.0, 0.0, 0.001]))
    x = plant.state()
    np.testing.assert_allclose(robot.mass * x[9:12], [0.05, -0.02, 0.01], atol=1e-15)
    np.testing.assert_allclose(robot.inertia_body @ x[6:9], [0, 0, 0.001], atol=1e-15)


def test_robot_geometry_matches_paper():
    robot = _robot()
    assert abs(robot.mass - 2.16) < 1e-12
    # torso centre ~0.04 m up (paper p_z* = 0.04): root on the bottom face, 21.75 mm above the tip
    assert 0.035 < robot.stance_height < 0.042
    # feet point out of the corners at the configured yaw
    yaw = (
        np.degrees(
            np.arctan2(
                robot.feet_body[:, 1] - robot.corners_body[:, 1], robot.feet_body[:, 0] - robot.corners_body[:, 0]
            )
        )
        % 360
    )
    np.testing.assert_allclose(yaw, [45, 135, 225, 315], atol=1e-9)
    assert np.all(np.linalg.eigvalsh(robot.inertia_body) > 0)


def test_the_soft_plants_attitude_step_is_the_quaternion_exponential():
    # advance_quaternion is written out in scalars for speed; it must be q exp(h w / 2) in the array form.
    from slotexp.body import advance_quaternion, quat_mul

    rng = np.random.default_rng(3)
    q = rng.normal(size=4)
    torso = np.concatenate([rng.normal(size=3), q / np.linalg.norm(q), rng.normal(size=6)])
    w, h = rng.normal(size=3), 2e-4
    half = 0.5 * h * w
    angle = np.linalg.norm(half)
    qn = quat_mul(torso[3:7], np.concatenate([[np.cos(angle)], half * np.sin(angle) / angle]))
    advance_quaternion(torso, *w, h)
    np.testing.assert_allclose(torso[3:7], qn / np.linalg.norm(qn), rtol=1e-13, atol=1e-15)
    still = np.array([0.0, 0.0, 0.1, 1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0])  # no rotation: the quaternion is kept
    advance_quaternion(still, 0.0, 0.0, 0.0, h)
    np.testing.assert_array_equal(still[3:7], [1.0, 0, 0, 0])


def test_the_soft_plants_small_solve_matches_numpy():
    from slotexp.body import solve_spd

    rng = np.random.default_rng(4)
    for n in (1, 3, 6):
        a = rng.normal(size=(n, n))
        spd = a @ a.T + n * np.eye(n)
        b = rng.normal(size=n)
        x = np.empty(n)
        solve_spd(spd.copy(), b, x)
        np.testing.assert_allclose(x, np.linalg.solve(spd, b), rtol=1e-12)
