import numpy as np

from slotexp.gait import GaitMatrix, contact_plan
from tests.helpers import load

# Seed 001: a walking trot with 4-feet stance transitions, MPC dt 0.02 s, period 0.32 s.
GAIT0 = [[1, 1, 1, 1, 1], [7, 1, 0, 0, 1], [1, 1, 1, 1, 1], [7, 0, 1, 1, 0]]
GAIT1 = [[7, 1, 0, 0, 1], [1, 1, 1, 1, 1], [7, 0, 1, 1, 0], [1, 1, 1, 1, 1], [0, 0, 0, 0, 0]]
GAIT2 = [[6, 1, 0, 0, 1], [1, 1, 1, 1, 1], [7, 0, 1, 1, 0], [1, 1, 1, 1, 1], [1, 1, 0, 0, 1]]
GAIT3 = [[5, 1, 0, 0, 1], [1, 1, 1, 1, 1], [7, 0, 1, 1, 0], [1, 1, 1, 1, 1], [2, 1, 0, 0, 1]]


def test_rolling_reproduces_seed_eq_18():
    g = GaitMatrix(GAIT0, n_rows=6)
    for expected in (GAIT1, GAIT2, GAIT3):
        g.roll()
        np.testing.assert_array_equal(g.matrix[:5], expected)
        assert not g.matrix[5:].any()


def test_period_is_invariant_and_schedule_is_periodic():
    g = GaitMatrix([[15, 1, 0, 1, 0], [15, 0, 1, 0, 1]])
    first = g.contacts(60)
    np.testing.assert_array_equal(first[:30], first[30:])
    for k in range(100):
        assert g.period == 30
        # after k rolls the schedule is the original one shifted by k steps
        np.testing.assert_array_equal(g.contacts(30), np.roll(first[:30], -(k % 30), axis=0))
        g.roll()


def test_contact_plan_swing_modes():
    cfg = load()
    stance = np.array([[True, False, True, False]])
    sliding = contact_plan(stance, cfg.gait, 1.0, 6.0)
    np.testing.assert_allclose(sliding.mu, [[0.6, 0.2, 0.6, 0.2]])
    np.testing.assert_allclose(sliding.fz_max, [[6, 6, 6, 6]])
    np.testing.assert_allclose(sliding.fz_min, [[1, 0, 1, 0]])
    cfg.gait.swing_contact = False
    lifted = contact_plan(stance, cfg.gait, 1.0, 6.0)
    np.testing.assert_allclose(lifted.fz_max, [[6, 0, 6, 0]])
    np.testing.assert_allclose(lifted.mu, [[0.6, 0, 0.6, 0]])
