"""Heading feedback on the soft legs (slotexp/locomotion/heading.py): the lean's pattern, the PI loop, the
friction mechanism it relies on, and the closed loop turning the robot back to its heading."""

from __future__ import annotations

import numpy as np
import pytest

from slotexp.controllers import make_controller
from slotexp.locomotion.heading import MIN_SPEED, HeadingLoop, lean_pattern
from slotexp.plants import make_plant, nominal_state
from slotexp.robot import build_robot
from slotexp.scenarios import advance, perturbations
from tests.helpers import load

LEG_YAW = np.radians([45.0, 135.0, 225.0, 315.0])  # FL, RL, RR, FR


def test_the_lean_loads_the_legs_left_of_travel_in_every_direction() -> None:
    forward = lean_pattern(LEG_YAW, 0.0)
    np.testing.assert_allclose(forward, [1.0, 1.0, -1.0, -1.0], atol=1e-12)  # left legs FL, RL up
    left = lean_pattern(LEG_YAW, np.pi / 2)
    np.testing.assert_allclose(left, [-1.0, 1.0, 1.0, -1.0], atol=1e-12)  # travelling +y, the rear is on the left
    diagonal = lean_pattern(LEG_YAW, np.pi / 4)  # FL and RR point along the travel: no slip across, no share
    np.testing.assert_allclose(diagonal, [0.0, 1.0, 0.0, -1.0], atol=1e-12)
    for h in np.linspace(-np.pi, np.pi, 13):  # reversing the travel swaps the sides; the largest share is 1
        p = lean_pattern(LEG_YAW, h)
        np.testing.assert_allclose(lean_pattern(LEG_YAW, h + np.pi), -p, atol=1e-12)
        assert np.max(np.abs(p)) == pytest.approx(1.0)


def test_the_loop_leans_against_the_error_holds_a_constant_drift_and_does_not_wind_up() -> None:
    period, window = 1.0 / 30.0, 16
    loop = HeadingLoop(kp=10.0, ki=1.0, max_lean_deg=15.0, period=period, window_steps=window)
    assert loop.update(1.0, 0.02) < 0.0  # turned left of the reference: lean right
    # a plant whose yaw rate is b * lean + d: the integral settles at the lean that cancels the drift d
    b, d, yaw = 0.03, 0.2, 0.0
    loop = HeadingLoop(kp=10.0, ki=1.0, max_lean_deg=15.0, period=period, window_steps=window)
    for _ in range(30 * 120):
        yaw += period * (b * loop.update(yaw, 0.02) + d)
    assert abs(loop.error_deg) < 0.05 and loop.lean == pytest.approx(-d / b, rel=0.02)
    # a drift beyond its reach: the lean holds at the limit and the integral stops growing
    loop = HeadingLoop(kp=10.0, ki=1.0, max_lean_deg=15.0, period=period, window_steps=window)
    for _ in range(30 * 60):
        loop.update(5.0, 0.02)
    held = loop.integral
    for _ in range(30 * 60):
        loop.update(5.0, 0.02)
    assert loop.lean == -15.0 and loop.integral == held
    for _ in range(window):  # back on heading, the lean unwinds at once (no stored wind-up to pay off)
        lean = loop.update(0.0, 0.02)
    assert abs(lean) < 15.0
    # standing there is nothing to lean through: no lean, the integral kept
    assert loop.update(3.0, MIN_SPEED / 2) == 0.0 and not loop.steers(MIN_SPEED / 2)
    assert not HeadingLoop(0.0, 0.0, 15.0, period, window).steers(0.02)


def test_the_deadband_leaves_small_errors_alone_and_acts_on_what_lies_beyond() -> None:
    period, window = 1.0 / 30.0, 16
    loop = HeadingLoop(kp=10.0, ki=1.0, max_lean_deg=15.0, period=period, window_steps=window, deadband_deg=1.5)
    for _ in range(30 * 60):  # a minute 1.4 deg off: inside the band, nothing winds and nothing leans
        assert loop.update(1.4, 0.02) == 0.0
    assert loop.integral == 0.0
    # beyond it the loop sees only the excess: 2 deg off is 0.5 deg to it (against the same loop with no band)
    plain = HeadingLoop(kp=10.0, ki=1.0, max_lean_deg=15.0, period=period, window_steps=window)
    banded = HeadingLoop(kp=10.0, ki=1.0, max_lean_deg=15.0, period=period, window_steps=window, deadband_deg=1.5)
    for _ in range(window):
        plain.update(0.5, 0.02)
        lean = banded.update(2.0, 0.02)
    assert lean == pytest.approx(plain.lean) and banded.integral == pytest.approx(plain.integral)
    # a drift still ends cancelled: the integral holds the lean that stops it, the error near the band's edge (not 0)
    b, d, yaw = 0.03, 0.2, 0.0
    loop = HeadingLoop(kp=10.0, ki=1.0, max_lean_deg=15.0, period=period, window_steps=window, deadband_deg=1.5)
    for _ in range(30 * 120):
        yaw += period * (b * loop.update(yaw, 0.02) + d)
    assert loop.lean == pytest.approx(-d / b, rel=0.02) and 1.3 < loop.error_deg < 1.6


def _walk(overrides: list[str], seconds: float, lean: float | None = None, record: list | None = None) -> np.ndarray:
    """Yaw (deg) every step of a closed-loop soft walk; ``lean`` fixes the lean (deg of tendon) instead of the
    loop; ``record`` collects the loop's lean every step."""
    cfg = load("plant=cosserat", *overrides)
    robot = build_robot(cfg.robot)
    scenario = cfg.scenarios["baseline"]
    x0 = nominal_state(robot) + np.asarray(scenario.offset.as_array())
    plant = make_plant(cfg, robot, x0)
    ctrl = make_controller(cfg, robot)
    if lean is not None:
        ctrl.heading.update = lambda error, speed, judge_sign=True: lean
    rng = np.random.default_rng(0)
    yaw = []
    for k in range(int(round(seconds * cfg.mpc.rate_hz))):
        t = k * ctrl.period
        step = ctrl.step(t, plant.state(), plant.feet())
        yaw.append(np.degrees(plant.state()[2]))
        if record is not None:
            record.append(step.telemetry["lean_deg"])
        advance(plant, step.command, t, ctrl.period, perturbations(scenario), rng)
    return np.asarray(yaw)


def test_leaning_onto_the_left_legs_turns_a_walking_robot_left() -> None:
    """The mechanism: feet sliding across their legs' planes brake the body by mu N each, and loading the legs on
    the left of the travel more than those on the right turns it left (heading.py). A fixed lean either way, the
    forward walk: the yaw rates differ in the lean's sign."""
    rates = {}
    for lean in (10.0, -10.0):
        yaw = _walk(["gait.velocity=[0.02,0]"], 10.0, lean=lean)
        rates[lean] = (yaw[-1] - yaw[90]) / 7.0
    assert rates[10.0] > rates[-10.0] + 0.1, rates


@pytest.mark.parametrize("offset_deg", [20.0, -20.0])
def test_the_heading_loop_turns_the_walking_robot_back_towards_its_heading(offset_deg: float) -> None:
    """Started 20 deg off its heading, walking: the loop leans the way that turns it back, and the robot ends
    nearer its heading than it started. (A robot that leaned the other way, or not at all, ends at 20-22 deg
    from +20: the forward walk's own drift is to the left.)"""
    start = [f"scenarios.baseline.offset.yaw={np.radians(offset_deg)}", "gait.velocity=[0.02,0]"]
    leans: list[float] = []
    yaw = _walk(start, 16.0, record=leans)
    assert abs(yaw[-1]) < abs(offset_deg) - 2.0, yaw[-1]
    assert np.sign(np.mean(leans)) == -np.sign(offset_deg)


def _first_order(b: float, d: float, seconds: float, learn_sign: bool, yaw0: float = 0.0) -> tuple[HeadingLoop, list]:
    """The loop on a plant whose yaw rate (deg/s) is ``b * lean + d``, with a gait cycle of 16 steps."""
    period, cycle = 1.0 / 30.0, 16
    loop = HeadingLoop(10.0, 1.0, 15.0, period, 2 * cycle, cycle_steps=cycle, learn_sign=learn_sign)
    yaw, trace = yaw0, []
    for _ in range(int(seconds / period)):
        yaw += period * (b * loop.update(yaw, 0.02) + d)
        trace.append(yaw)
    return loop, trace


def test_the_loop_learns_a_reversed_lean_and_then_holds_the_heading() -> None:
    """A plant on which the lean turns the robot the other way (the loaded side pushes harder than it brakes):
    assuming the braking sign the loop winds the heading away without bound; learning it, it flips once and
    holds the heading, and its estimate of the authority has the plant's sign."""
    b, d = -0.03, -0.25  # deg/s per deg of lean, and the gait's own drift (the low-friction model's, measured)
    fixed, fixed_trace = _first_order(b, d, 40.0, learn_sign=False)
    learned, trace = _first_order(b, d, 40.0, learn_sign=True)
    assert abs(fixed_trace[-1]) > 10.0 and fixed.sign == 1.0
    assert learned.sign == -1.0 and len(learned.flips) == 1 and learned.authority < 0.0
    assert abs(trace[-1]) < 0.1 and max(abs(y) for y in trace[len(trace) // 2 :]) < 0.5


@pytest.mark.parametrize("yaw0", [0.0, 20.0, -20.0])
def test_the_loop_keeps_a_right_sign_through_its_own_transients(yaw0: float) -> None:
    """The lean turns the way the loop assumes: from on heading or 20 deg off either way, with the wound-up lean
    that takes, it never flips, and it brings the heading back (a flip would turn a transient into a run-away)."""
    loop, trace = _first_order(0.02, 0.1, 150.0, learn_sign=True, yaw0=yaw0)
    assert loop.sign == 1.0 and not loop.flips
    assert abs(trace[-1]) < 0.1
    assert loop.authority > 0.0 or np.isnan(loop.authority)
