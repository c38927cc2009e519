"""The coupled soft-leg plant: action and reaction between legs and torso, and static load sharing."""

import numpy as np
import pytest

from slotexp.errors import ConfigError, DivergenceError
from slotexp.locomotion.primitives import GaitStyle, Primitive
from slotexp.plants import TendonCommand, nominal_state
from slotexp.plants.cosserat import CosseratPlant
from slotexp.robot import build_robot
from slotexp.soft.loads import coulomb_friction, friction_coefficient
from slotexp.soft.params import O_F, O_N
from slotexp.soft.servo import RPM_TO_RAD_S, servo_step
from tests.helpers import load


def _plant(*overrides):
    cfg = load("plant=cosserat", *overrides)
    robot = build_robot(cfg.robot)
    return cfg, CosseratPlant(cfg, robot, nominal_state(robot))


def _total_mass(plant):
    return plant.torso_mass + 4 * plant.model.mass[1:].sum()


def _walk(plant, cfg, seconds):
    """Drive the tendons with the library's forward gait, open loop, for ``seconds``."""
    style_cfg = cfg.controller.library["walk"]
    style = GaitStyle(style_cfg.frequency_hz, style_cfg.duty, style_cfg.sharpness)
    gait = Primitive.from_config(style_cfg.primitives[0])
    for k in range(int(round(seconds * 30))):
        plant.step(TendonCommand(gait.angles(style, k / 30 * style.frequency_hz, cfg.robot.leg.tendon_max_deg)), 1 / 30)


def test_free_fall_conserves_momentum_through_the_coupling():
    # No ground: internal forces (leg elasticity, tendon, root reactions) cancel, so the
    # whole robot's momentum changes by exactly -M g t.
    cfg, plant = _plant("sim.ground=false")
    momentum0, _ = plant.momentum_world()  # the legs may still move after being set down
    total_mass = _total_mass(plant)
    assert total_mass == pytest.approx(cfg.robot.torso.mass + 4 * plant.model.mass.sum())
    for k in range(6):
        plant.step(TendonCommand(np.full(4, 20.0 * k)), 1 / 30)
    t = 6 / 30
    momentum, _ = plant.momentum_world()
    assert momentum[2] - momentum0[2] == pytest.approx(-total_mass * 9.81 * t, rel=1e-9)
    np.testing.assert_allclose(momentum[0:2], momentum0[0:2], atol=1e-14)


@pytest.mark.parametrize("dt", ["default", "5e-5", "5e-3 newton", "anchor split"])
def test_in_free_space_a_walking_gait_moves_neither_the_momentum_nor_the_centre_of_mass(dt):
    # Gravity and ground off, the tendons driven by the forward gait (its legs swing and the torso rocks
    # +-2 deg): nothing outside acts, so the momentum holds to round-off and the centre of mass moves at
    # P / M. Bound: 1e-12 N s on the momentum (measured 1e-16) and 1 um on the centre of mass over 1.5 s
    # (measured < 0.1 um at both steps). Before the root's share of the tendon's tension change was
    # counted, the centre of mass moved 23.7 mm in 8 s at 2e-4 s and 6.3 mm at 5e-5 s.
    # (5e-3 newton: backward Euler by Newton corrections, whose halved steps hand the torso their mean reaction;
    # anchor split: an uneven mesh, the element before the tendon's anchor in 8, robot.leg.anchor_refinement)
    steps = {
        "default": [],
        "5e-5": ["sim.dt=5e-5"],
        "5e-3 newton": ["sim.dt=5e-3", "plant.newton=8"],
        "anchor split": ["robot.leg.anchor_refinement=8"],
    }
    overrides = ["sim.gravity=0", "sim.ground=false"] + steps[dt]
    cfg, plant = _plant(*overrides)
    momentum0, _ = plant.momentum_world()
    com0 = plant.centre_of_mass()
    seconds = 1.5
    _walk(plant, cfg, seconds)
    momentum, _ = plant.momentum_world()
    np.testing.assert_allclose(momentum, momentum0, atol=1e-12)
    drift = plant.centre_of_mass() - com0 - momentum0 * seconds / _total_mass(plant)
    assert np.linalg.norm(drift) < 1e-6
    assert np.ptp(plant.leg_world()[:, -1, 0]) > 0.1  # the legs did move (the feet are spread)
    assert plant.model.n_nodes == cfg.robot.leg.n_nodes + 7 * (dt == "anchor split")


def test_on_frictionless_ground_a_gait_makes_no_progress():
    # mu = 0: the ground pushes only vertically, so no gait can move the centre of mass sideways
    # (bound 1 um in 3 s; measured < 1e-9 m). The torso still sways against its legs (under 1 mm) and
    # turns a little: the leg planes stay vertical, so a tilt's second-order geometry is not a rigid
    # leg's (measured 0.3 deg in 4 s with the library's forward gait; before the fixes, with the old
    # library's, 7.5 mm and 5.9 deg in 8 s).
    cfg, plant = _plant("robot.contact.friction=0")
    com0 = plant.centre_of_mass()
    x0 = plant.state()
    _walk(plant, cfg, 3.0)
    assert np.linalg.norm((plant.centre_of_mass() - com0)[0:2]) < 1e-6
    assert np.linalg.norm(plant.state()[3:5] - x0[3:5]) < 1e-3
    assert abs(np.degrees(plant.state()[2] - x0[2])) < 1.0


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_rigidly_spinning_robot_keeps_its_angular_momentum(axis):
    # Free space, tendons held, released spinning at 0.5 rad/s with its legs moving along: nothing outside
    # acts, so the angular momentum holds and, with the legs carried rigidly, so does the rate. Yaw: 1 s,
    # to the step's order (measured 1.2e-5 relative at 2e-4 s, 3e-6 at 5e-5 s); roll and pitch: while the
    # torso turns 2.9 deg (0.1 s), within 1e-3 (measured 3.4e-4; the leg planes stay vertical, so the
    # error grows with the tilt squared: 0.5 % after 11.5 deg, at every step size). Before, the damping
    # pulled the legs towards the root's translation only: the roll rate fell from 0.5 to 0.004 rad/s in 1 s.
    cfg = load("plant=cosserat", "sim.gravity=0", "sim.ground=false")
    robot = build_robot(cfg.robot)
    x0 = nominal_state(robot)
    x0[6 + axis] = 0.5
    plant = CosseratPlant(cfg, robot, x0)
    _, spin0 = plant.momentum_world()
    held = np.rad2deg(plant.servo).copy()
    seconds, tol = (1.0, 1e-4) if axis == 2 else (0.1, 1e-3)
    for _ in range(int(round(seconds * 30))):
        plant.step(TendonCommand(held), 1 / 30)
    _, spin = plant.momentum_world()
    assert np.max(np.abs(spin - spin0)) < tol * abs(spin0[axis])
    assert plant.state()[6 + axis] == pytest.approx(0.5, rel=0.01)
    if axis == 2:  # the legs carry about half the yaw inertia (0.0037 kg m^2 beside the torso's 0.0039)
        assert spin0[2] / 0.5 == pytest.approx(plant.inertia[2, 2] + 0.0037, rel=0.05)


@pytest.mark.parametrize("static", [None, 0.9])
def test_friction_opposes_the_slip_and_never_exceeds_mu_n(static: float | None):
    # One node: isotropic Coulomb friction, regularised below the slip velocity; with a static coefficient
    # (0.9 over the sliding 0.6) the Gaussian Stribeck curve, mu_s at rest falling to mu over v_s = 10 mm/s.
    rng = np.random.default_rng(5)
    mu, nrm, v_eps, v_s = 0.6, 2.5, 1e-3, 0.01
    mu_s = mu if static is None else static
    for _ in range(2000):
        v = rng.normal(size=2) * 10.0 ** rng.uniform(-5, -1)
        f = np.array(coulomb_friction(v[0], v[1], nrm, mu, v_eps, mu_s, v_s))
        speed = np.linalg.norm(v)
        coefficient = mu + (mu_s - mu) * np.exp(-((speed / v_s) ** 2))
        assert np.linalg.norm(f) <= mu_s * nrm * (1 + 1e-12)  # the cone at rest bounds it
        assert abs(f[0] * v[1] - f[1] * v[0]) <= 1e-12 * np.linalg.norm(f) * speed  # along the slip
        assert f @ v < 0.0  # against it
        if speed >= v_eps:
            assert np.linalg.norm(f) == pytest.approx(coefficient * nrm, rel=1e-12)
        else:
            assert np.linalg.norm(f) == pytest.approx(coefficient * nrm * speed / v_eps, rel=1e-12)
    # plain friction is mu at every speed; the static one mu_s just above the slip velocity, mu far above v_s
    speeds = np.geomspace(v_eps, 1.0, 50)
    coefficients = [friction_coefficient(s, mu, mu_s, v_s) for s in speeds]
    assert np.all(np.diff(coefficients) <= 0.0)
    assert coefficients[0] == pytest.approx(mu_s, rel=0.02) and coefficients[-1] == pytest.approx(mu, rel=1e-12)


@pytest.mark.parametrize("friction", ["secant", "solved"])
def test_a_push_between_the_sliding_and_the_static_friction_slides_a_robot_only_without_static_friction(friction):
    # The pad's friction cone: standing on 80 deg tendons (weight W = 21.2 N) and pushed sideways with 3.5 N,
    # above mu W = 2.1 N at mu = 0.1 and below mu_s W = 5.3 N at mu_s = 0.25. With plain friction the robot
    # slides off; with the static coefficient its feet hold, to the regularisation's creep (the push over
    # mu_s W, times v_eps: about 0.7 mm/s). The push rises over 1 s: a step load on the soft legs overshoots
    # (to twice the push, undamped) and would break the feet loose, after which they slide at mu. The same with
    # the friction solved at each step's end (plant.friction=solved), where the Stribeck fall makes the law
    # non-monotone.
    shift = {}
    for static in ("null", "0.25"):
        _, plant = _plant(f"robot.contact.static_friction={static}", f"plant.friction={friction}")
        for _ in range(15):
            plant.step(TendonCommand(np.full(4, 80.0)), 1 / 30)
        y0 = plant.torso[1]
        for k in range(60):
            push = np.array([0.0, 3.5 * min(1.0, (k + 1) / 30), 0.0])
            plant.step(TendonCommand(np.full(4, 80.0)), 1 / 30, external_force=push)
        shift[static] = plant.torso[1] - y0
    assert shift["null"] > 0.05  # measured 482 mm
    assert 0.0 < shift["0.25"] < 5e-3  # measured 1.6 mm, and 1.6 mm at 5e-5 s


@pytest.mark.parametrize(
    "step",
    [[], ["sim.dt=5e-3", "plant.newton=8"], ["plant.friction=solved"], ["plant.friction=solved", "sim.dt=1e-3"]],
    ids=["default", "5e-3 newton", "solved", "solved 1 ms"],
)
def test_a_sliding_robot_is_braked_by_at_most_mu_m_g_against_its_slip(step):
    # Released sliding forwards at 0.1 m/s: only friction acts sideways, so the momentum it loses in 10 ms is
    # the friction impulse. The feet slip at 45 deg to their legs; box-shaped friction (per axis) braked it
    # with sqrt(2) mu M g, isotropic friction with at most mu M g (measured 0.96), straight against the slip.
    # In two backward Euler steps of 5 ms the same: the friction at each step's end never exceeds the cone; and
    # with the friction along the legs' planes solved at each step's end (plant.friction=solved).
    cfg = load("plant=cosserat", *step)
    robot = build_robot(cfg.robot)
    x0 = nominal_state(robot)
    x0[9] = 0.1
    plant = CosseratPlant(cfg, robot, x0)
    momentum0, _ = plant.momentum_world()
    plant.step(TendonCommand(np.rad2deg(plant.servo)), 0.01)
    impulse = (plant.momentum_world()[0] - momentum0)[0:2]
    mu_m_g = cfg.robot.contact.friction * _total_mass(plant) * cfg.sim.gravity
    assert 0.8 * mu_m_g * 0.01 < -impulse[0] <= 1.02 * mu_m_g * 0.01
    assert abs(impulse[1]) < 1e-12


def test_backward_euler_stands_the_robot_at_the_control_period_where_the_linear_step_diverges():
    # Standing on 80 deg tendons for 5 s, one step per 1/30 s control period: the linearly implicit step
    # diverges within 0.1 s; backward Euler (plant.newton: Newton on each leg, the torso taking the legs'
    # answer to its velocity and its own step implicit) stands still at the height the default step
    # reaches (35.76 against 35.78 mm, which still rocks by 0.17 mm) and its feet carry the weight.
    heights = {}
    for name, step in (("default", []), ("newton", ["sim.dt=0.0333333333", "plant.newton=8"])):
        _, plant = _plant(*step)
        z = []
        for _ in range(150):
            plant.step(TendonCommand(np.full(4, 80.0)), 1 / 30)
            z.append(plant.torso[2])
        heights[name] = np.mean(z[-30:])
        assert plant.normal.sum() == pytest.approx(_total_mass(plant) * 9.81, rel=0.01)
    assert np.ptp(z[-30:]) < 1e-5  # backward Euler: still
    assert heights["newton"] == pytest.approx(heights["default"], abs=1e-4)
    # (it diverges already setting the robot down, in steps of 2 ms, when the tendons are taken at once;
    # wound in, plant.wind_in_s, it stands 1.2 s first)
    with pytest.raises(DivergenceError):
        _, plant = _plant("sim.dt=0.0333333333")
        for _ in range(60):
            plant.step(TendonCommand(np.full(4, 80.0)), 1 / 30)


def test_standing_robot_carries_its_weight_on_its_feet():
    # The torso bounces on its soft legs at about 1 Hz, lightly damped: average the fourth second
    # (the servos wind the tendons in at their rated speed first).
    cfg, plant = _plant()
    normals, vz = [], []
    for k in range(120):  # 4 s with the tendons commanded to a fixed angle
        plant.step(TendonCommand(np.full(4, 80.0)), 1 / 30)
        if k >= 90:
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
            plant.step(TendonCommand(np.full(4, angle)), 1 / 30)
        heights.append(plant.state()[5])
    assert heights[1] > heights[0] + 0.002


def test_symplectic_above_its_limit_stops_with_the_limit_named():
    with pytest.raises(DivergenceError) as exc:
        _, plant = _plant("plant.integrator=symplectic", "sim.dt=2e-4")
        for _ in range(30):
            plant.step(TendonCommand(np.full(4, 60.0)), 1 / 30)
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
    low.step(TendonCommand(np.full(4, 80.0)), 1 / 30)
    assert np.linalg.norm(low.state()[9:12]) < 0.1  # no launch


def test_a_tilted_initial_pose_leaves_every_leg_in_its_standing_shape():
    # Table I's combined offsets put the front-right corner lowest and tilt its leg down: set down
    # at once, its resting foot started ~25 mm in the ground and the contact folded the leg under
    # the body (reach 144 mm against 250). Lowered onto the pose, every leg keeps its standing reach.
    cfg = load("plant=cosserat")
    robot = build_robot(cfg.robot)
    level = CosseratPlant(cfg, robot, nominal_state(robot))
    x0 = nominal_state(robot)
    x0[0] = x0[1] = 0.05  # roll, pitch (rad)
    x0[5] -= 0.005
    tilted = CosseratPlant(cfg, robot, x0)
    reach_level, reach_tilted = level.pos[:, -1, 0], tilted.pos[:, -1, 0]
    np.testing.assert_allclose(reach_tilted, reach_level, atol=0.01)
    np.testing.assert_allclose(tilted.state()[0:2], 0.05, atol=1e-9)  # released at the scenario's pose
    assert tilted.state()[5] == pytest.approx(level.state()[5] - 0.005, abs=1e-9)


def test_markers_follow_the_paper_nodes():
    _, plant = _plant()
    markers = plant.markers()
    for leg in ("FL", "RL", "RR", "FR"):
        for node in (0, 10, 20, 30):
            assert f"{leg}_n{node}" in markers
        np.testing.assert_allclose(markers[f"{leg}_n30"], markers[f"{leg}_foot"])
    # set-down legs rest on the ground (the wound tendon curls the tip: the lowest node carries the foot)
    np.testing.assert_allclose(plant.leg_world()[:, :, 2].min(axis=1), 0.0, atol=5e-4)


def test_servo_speed_follows_the_xl430_speed_torque_line() -> None:
    """No load: 57 rpm (342 deg/s); winding against a load: slower along the line to zero at stall;
    unwinding: the no-load speed; never above the Profile Velocity; small moves: the 5 ms lag."""
    w0 = 57.0 * RPM_TO_RAD_S
    h, tau, stall = 1e-4, 0.005, 1.4
    for torque in (0.0, 0.35, 0.7, 1.05, 1.4, 2.0):
        angle, steps = 0.0, 2000  # 0.2 s towards a far command
        for _ in range(steps):
            angle = servo_step(angle, 10.0, h, tau, torque, stall, w0, 0.0)
        assert angle == pytest.approx(w0 * max(0.0, 1 - torque / stall) * steps * h, rel=1e-9, abs=1e-12)
    back = 2.0
    for _ in range(1000):
        back = servo_step(back, -10.0, h, tau, 1.0, stall, w0, 0.0)
    assert back == pytest.approx(2.0 - w0 * 0.1, rel=1e-9)
    profile = 40.0 * RPM_TO_RAD_S
    capped = 0.0
    for _ in range(1000):
        capped = servo_step(capped, 10.0, h, tau, 0.0, stall, w0, profile)
    assert capped == pytest.approx(profile * 0.1, rel=1e-9)
    small = 0.0
    for _ in range(50):  # 5 ms: a 0.01 rad step stays inside the speed limit and follows the lag
        small = servo_step(small, 0.01, h, tau, 0.0, stall, w0, 0.0)
    assert small == pytest.approx(0.01 * (1 - (1 / (1 + h / tau)) ** 50), rel=1e-12)


def test_plant_servo_never_exceeds_342_deg_per_s() -> None:
    cfg = load("plant=cosserat")
    robot = build_robot(cfg.robot)
    plant = CosseratPlant(cfg, robot, nominal_state(robot))
    before = np.rad2deg(plant.servo.copy())
    plant.step(TendonCommand(np.full(4, 116.0)), 1 / 30)
    moved = np.rad2deg(plant.servo) - before
    assert np.all(moved <= 342.0 / 30 + 1e-9) and np.all(moved > 0.5 * 342.0 / 30)  # loaded: below no-load speed


def test_the_default_step_answers_a_standing_push_as_the_converged_reference():
    # The bench's standing push (a 0.4 N s sideways push at 3 s, judged from 3 s) at the default step and Jacobian
    # age against the exact implicit step at 2.5e-5 s (slot bench leg's reference): within every tolerance. A case
    # the reference resolves (its own half step is well within the tolerances there, docs/results/plant.md);
    # a short walk is not one (the start-up's stick-slip carries differences of the tolerance's size into it).
    from slotexp.bench._accuracy import CASES, START_UP_S, TOLERANCE, compare, run_case, with_plant, within

    cfg = load("plant=cosserat")
    case = next(c for c in CASES if c.name == "standing push")
    assert case.judged_from == START_UP_S == 3.0
    assert cfg.plant.jacobian_age > 1  # the default reuses its factored Jacobian
    reference = run_case(with_plant(cfg, "implicit", 2.5e-5, 1), case)
    result = compare(run_case(cfg, case), reference, case.judged_from)
    assert within(result), (result, TOLERANCE)
    assert result["max_dxy_mm"] > 0.0  # a different step is a different run: the comparison sees it


def test_the_default_step_walks_the_forward_gait_as_fast_as_the_converged_reference():
    # Gait speed, the robust figure of a stick-slip walk (slotexp.bench._accuracy), of the forward gait played open
    # loop for 6 s (no feedback to hide a plant's error): within the bench's 2 % of the exact step at 2.5e-5 s.
    from slotexp.bench._accuracy import TOLERANCE, Case, compare, run_case, with_plant

    cfg = load("plant=cosserat", "controller=open_loop")
    case = Case("walk", "baseline", (0.02, 0.0), 6.0)
    reference = run_case(with_plant(cfg, "implicit", 2.5e-5, 1), case)
    result = compare(run_case(cfg, case), reference, case.judged_from)
    assert result["speed_ref_mm_s"] > 15.0  # the reference walks
    assert abs(result["speed_error_fraction"]) <= TOLERANCE["speed_error_fraction"], result


def test_the_accuracy_comparison_measures_speed_and_differences_analytically():
    from slotexp.bench._accuracy import Trace, compare, gait_speed, real_time_factor

    t = np.arange(300) / 30.0
    x = np.zeros((300, 12))
    x[:, 3], x[:, 4] = 0.012 * t, 0.016 * t  # 20 mm/s along a 3-4-5 line
    run = Trace(t, x, np.full((300, 4), 5.0), np.full(300, 1.0 / 300))
    assert gait_speed(run) == pytest.approx(0.02, rel=1e-12)
    assert real_time_factor(run) == pytest.approx(10.0)
    same = compare(run, run)
    assert same["speed_error_fraction"] == 0.0 and same["max_dxy_mm"] == 0.0 and same["rms_dnormal_n"] == 0.0
    other = Trace(t, x.copy(), np.full((300, 4), 5.5), run.step_wall_s)
    other.x[:, 5] += 0.001  # 1 mm higher
    other.x[:, 1] += np.radians(0.5)
    other.x[:, 2] += 2.0 * np.pi - np.radians(0.25 * t)  # yaw drifting 0.25 deg/s, a whole turn apart
    diff = compare(other, run)
    assert diff["max_dz_mm"] == pytest.approx(1.0) and diff["max_dattitude_deg"] == pytest.approx(0.5)
    assert diff["max_dyaw_deg"] == pytest.approx(0.25 * t[-1])
    assert diff["yaw_rate_error_dps"] == pytest.approx(-0.25, rel=1e-9)  # the drift's rate, the turn unwrapped
    assert same["yaw_rate_error_dps"] == 0.0
    assert diff["rms_dnormal_n"] == pytest.approx(0.5) and diff["max_dxy_mm"] == 0.0


def test_a_case_whose_reference_is_not_converged_gives_no_verdict():
    """The bench's rule: a setting is as accurate as the yardstick can tell where the reference's own half step
    is within the tolerance; where that half step is out, no row of the case is called in or out."""
    from slotexp.bench import BenchRow
    from slotexp.bench._accuracy import resolved
    from slotexp.bench.leg import HALF_STEP

    def rows(half_in: bool) -> list[BenchRow]:
        return [
            BenchRow("accuracy", "c, implicit dt=0.0002 age 5", 1.0, 1.0, 1.0, {"within_tolerance": False}),
            BenchRow("accuracy", "c, implicit dt=0.0001 age 1", 1.0, 1.0, 1.0, {"within_tolerance": True}),
            BenchRow(
                "accuracy",
                f"c, implicit dt=1.25e-05 age 1 {HALF_STEP}",
                1.0,
                1.0,
                1.0,
                {"within_tolerance": half_in},
            ),  # fmt: skip
            BenchRow("accuracy", "c, implicit dt=0.01: diverged", np.nan, np.nan, 0.0, {"error": "diverged"}),
        ]

    converged = resolved(rows(True), HALF_STEP)
    assert [r.extra.get("within_tolerance") for r in converged] == [False, True, True, None]
    assert all(r.extra["resolved"] for r in converged[:3])
    outcomes = [dict(r.extra, outcome_within=r.extra.get("within_tolerance")) for r in rows(True)]
    outcomes[2]["outcome_within"] = False  # the half step in run by run, out on the means
    judged = resolved([BenchRow(r.component, r.variant, 1.0, 1.0, 1.0, e) for r, e in zip(rows(True), outcomes)],
                      HALF_STEP, "outcome_within", "outcome_resolved")  # fmt: skip
    assert [r.extra.get("outcome_within") for r in judged] == [None, None, None, None]
    assert [r.extra.get("within_tolerance") for r in judged] == [False, True, True, None]
    assert not judged[0].extra["outcome_resolved"] and "resolved" not in judged[0].extra
    unresolved = resolved(rows(False), HALF_STEP)
    assert [r.extra.get("within_tolerance") for r in unresolved] == [None, None, None, None]
    assert not any(r.extra["resolved"] for r in unresolved[:3]) and "resolved" not in unresolved[3].extra


def test_a_setting_is_judged_by_where_its_runs_land_among_the_references_branches():
    """The bench's ensemble yardstick on traces made by hand: a reference whose runs make two motions (two
    branches, 5 mm apart in height), a setting whose runs land on either is in, and one whose run lands between
    them is out by that run's distance to its nearest reference run."""
    from slotexp.bench._accuracy import TOLERANCE, Trace, branches, judge, score, within

    t = np.arange(300) / 30.0
    walk = np.zeros((300, 12))
    walk[:, 3] = 0.02 * t

    def trace(dz_mm: float) -> Trace:
        x = walk.copy()
        x[:, 5] = 0.04 + 1e-3 * dz_mm * (t > 4.0)  # the branch shows after 4 s
        return Trace(t, x, np.full((300, 4), 5.0), np.full(300, 1e-3))

    references = [trace(0.0), trace(5.0), trace(0.1), trace(0.0)]
    assert branches(references, 3.0) == [1, 2, 1, 1]
    on_both = judge([trace(0.5), trace(5.5), trace(4.8), trace(0.0)], references, 3.0)
    assert within(on_both) and on_both["runs_in"] == 4 and on_both["branches_visited"] == "1,2"
    assert on_both["reference_branches"] == 2 and on_both["max_dz_mm"] == pytest.approx(0.5)  # the farthest run
    between = judge([trace(0.5), trace(2.6)], references, 3.0)
    assert not within(between) and between["runs_in"] == 1 and between["runs"] == 2
    assert between["max_dz_mm"] == pytest.approx(2.4)  # 2.6 mm is nearest the 5 mm branch, 2.4 away
    assert score(between) == pytest.approx(2.4 / TOLERANCE["max_dz_mm"])
    # the ensembles' means: the window from 3 s, the branches' heights after 4 s of it
    after = np.mean(t[t >= 3.0] > 4.0)
    assert on_both["mean_dz_mm"] == pytest.approx((2.7 - 1.275) * after)
    assert on_both["mean_speed_error_fraction"] == pytest.approx(0.0, abs=1e-12)
    assert on_both["mean_dattitude_deg"] == 0.0 and on_both["outcome_within"]
    # a run between the branches is out run by run and in on the means; three runs on the far branch are out there
    assert between["outcome_within"] and between["mean_dz_mm"] == pytest.approx((1.55 - 1.275) * after)
    far = judge([trace(5.0)] * 3, references, 3.0)
    assert within(far) and not far["outcome_within"]  # each run is a reference motion; the mix is not
    # the speed error's standard error, from each ensemble's scatter: none where every run walks alike
    assert far["mean_speed_error_se_fraction"] == pytest.approx(0.0, abs=1e-12)
    faster = [Trace(r.t, r.x * np.where(np.arange(12) == 3, 1.05, 1.0), r.normal, r.step_wall_s) for r in references]
    level = references[:1] + references[3:]  # two reference runs on the same branch
    spread = judge(references[:1] + faster[:1], level, 3.0)  # speeds 0.020 and 0.021 against 0.020 twice
    assert spread["mean_speed_error_fraction"] == pytest.approx(0.025)
    assert spread["mean_speed_error_se_fraction"] == pytest.approx(np.sqrt(0.001**2 / 2 / 2) / 0.02)
    # within two standard errors of the 2 % tolerance either way the means give no verdict; beyond them they do
    assert spread["outcome_within"] is None
    assert judge([faster[0], faster[3]], level, 3.0)["outcome_within"] is False  # 5 % faster, no scatter
    # judged from after the branching, a case whose runs agree has one branch, and a run judged against itself is 0
    assert branches(references[:1] + references[2:], 3.0) == [1, 1, 1]
    assert judge(references[:1], references[:1], 0.0)["max_dz_mm"] == 0.0


def test_an_ensemble_runs_each_case_with_the_feet_friction_scaled_and_leaves_the_config_alone(monkeypatch):
    import slotexp.bench._accuracy as acc

    seen = []
    monkeypatch.setattr(acc, "run_closed_loop", lambda cfg, *a, **k: seen.append(cfg.robot.contact))
    cfg = load("plant=cosserat", "robot.contact.static_friction=0.2")
    acc.run_ensemble(cfg, acc.CASES[0])
    assert [c.friction for c in seen] == pytest.approx([0.1 * f for f in acc.ENSEMBLE], rel=1e-12)
    assert [c.static_friction for c in seen] == pytest.approx([0.2 * f for f in acc.ENSEMBLE], rel=1e-12)
    assert all(c.stiffness == cfg.robot.contact.stiffness for c in seen)
    assert cfg.robot.contact.friction == 0.1 and cfg.robot.contact.static_friction == 0.2
    assert len(set(acc.ENSEMBLE)) == len(acc.ENSEMBLE) >= 3 and all(abs(f - 1) <= 2e-3 for f in acc.ENSEMBLE)


def test_a_batch_steps_each_robot_exactly_as_it_steps_alone():
    from slotexp.plants.cosserat import CosseratBatch

    cfg = load("plant=cosserat")
    robot = build_robot(cfg.robot)
    x0 = nominal_state(robot)
    tilted = x0.copy()
    tilted[0] = 0.04
    commands = [np.array([90.0, 60.0, 70.0, 100.0]), np.array([40.0, 110.0, 80.0, 50.0])]
    alone = [CosseratPlant(cfg, robot, x) for x in (x0, tilted)]
    batch = CosseratBatch([CosseratPlant(cfg, robot, x) for x in (x0, tilted)])
    for k in range(6):
        for plant, command in zip(alone, commands):
            plant.step(TendonCommand(command + 3.0 * k), 1 / 30)
        batch.step(np.array(commands) + 3.0 * k, 1 / 30)
    for plant, twin in zip(alone, batch.plants):
        np.testing.assert_array_equal(twin.state(), plant.state())
        np.testing.assert_array_equal(twin.feet(), plant.feet())
        np.testing.assert_array_equal(twin.telemetry()["/legs/contact"]["normal_n"], plant.out[:, 4])
        assert twin.time == plant.time
    assert not np.allclose(batch.plants[0].state(), batch.plants[1].state())  # two robots, two motions
    twin = batch.plants[1]
    twin.step(TendonCommand(commands[1]), 1 / 30)  # a batched robot still steps alone, on its own row
    np.testing.assert_array_equal(batch.stacked.torso[1], twin.torso)


def test_tendons_wound_in_while_the_robot_is_set_down_do_not_whip_soft_legs():
    # The same soft legs at 1 ms with their tendons wound in over the first settling move (plant.wind_in_s)
    # instead of shortened at once: set down without a retaken period, where at once they need 15 and settle
    # elsewhere (their nodes 119 mm apart, measured: the whip folds them), and on their feet at rest. On the
    # default model the two settle within 0.1 mm of each other (measured 0.08).
    soft = ("robot.leg.youngs_modulus=4e6", "sim.dt=1e-3")
    _, wound = _plant(*soft, "plant.wind_in_s=0.05", "plant.retakes=0")
    _, at_once = _plant(*soft, "plant.wind_in_s=0")
    assert wound.retaken_periods == 0 and at_once.retaken_periods > 0
    assert np.abs(wound.vel).max() < 1e-2 and wound.normal.sum() > 10.0
    _, default_wound = _plant("plant.wind_in_s=0.05")
    _, default_at_once = _plant("plant.wind_in_s=0")
    np.testing.assert_allclose(default_wound.pos, default_at_once.pos, rtol=0, atol=1e-4)
    with pytest.raises(ConfigError, match="plant.wind_in_s"):
        load("plant=cosserat", "plant.wind_in_s=0.1")


def test_every_settling_moves_change_wound_in_sets_a_soft_model_down_at_1_ms_where_taken_at_once_it_fails():
    # The settling moves after the first change the angle that carries the weight by a Newton step on the feet's
    # load; taken at once it whips soft legs (E 5.9e6 Pa, a high horn zero): at 1 ms no retake recovers it (0.056
    # s, the second move). Wound in over plant.wind_in_s like the first, the robot is set down with no retake,
    # at rest on its feet; on the default model the option changes nothing the first move did not.
    from slotexp.bench import stability
    from slotexp.config import with_settings

    soft = {**dict(stability.MODELS)["mu 0.63, E 5.87e6, c 17.8, horn zero 139"], "sim.dt": 1e-3, **stability.BY_TURN}

    def set_down(settings: dict) -> tuple:
        cfg = with_settings(load("plant=cosserat"), {**soft, **settings})
        robot = build_robot(cfg.robot)
        return cfg, CosseratPlant(cfg, robot, nominal_state(robot))

    with pytest.raises(DivergenceError, match=r"diverged at t = 0.05"):
        set_down({})
    cfg, wound = set_down({"plant.wind_in_every_move": True, "plant.retakes": 0})
    assert wound.retaken_periods == 0 and np.abs(wound.vel).max() < 1e-2
    # on its feet: they carry most of the weight the servos were wound to carry while the torso was held (87 %)
    assert wound.normal.sum() > 0.8 * _total_mass(wound) * cfg.sim.gravity


def test_a_diverging_period_is_retaken_by_backward_euler_alone_or_in_a_batch():
    # Soft legs (E 4e6 Pa, the low end of the identification's range) curled by the settle's tendon angle,
    # taken at once, turn their elements tenths of a radian per step: one linearisation per step blows up (the
    # robot could not be set down at all), backward Euler solved by Newton corrections does not. At 1 ms steps
    # the walk's periods diverge now and then too; a batched robot is retaken alone on its own row, as it
    # would be alone.
    from slotexp.plants.cosserat import CosseratBatch

    # (with the secant friction: solved at the step's end the walk's periods at 1 ms no longer diverge)
    soft = ("robot.leg.youngs_modulus=4e6", "sim.dt=1e-3", "plant.wind_in_s=0", "plant.friction=secant")
    with pytest.raises(DivergenceError, match=r"diverged at t = .*\(plant.retakes=4\)$"):
        _plant(*soft, "plant.retakes=0")
    cfg = load("plant=cosserat", *soft)
    robot = build_robot(cfg.robot)
    alone = CosseratPlant(cfg, robot, nominal_state(robot))
    settled = alone.retaken_periods
    assert settled > 0
    batch = CosseratBatch([CosseratPlant(cfg, robot, nominal_state(robot)) for _ in range(2)])
    commands = np.array([[23.2, 13.2, 13.2, 118.2], [118.2, 13.2, 13.2, 23.2], [60.0, 60.0, 60.0, 60.0]])
    for k in range(30):  # robot 0 (and the one alone) goes through the three, robot 1 the other way round
        pair = commands[[k // 10, 2 - k // 10]]
        alone.step(TendonCommand(pair[0]), 1 / 30)
        batch.step(pair, 1 / 30)
    twin = batch.plants[0]
    assert alone.retaken_periods > settled  # the walk's own periods were retaken too ...
    assert twin.retaken_periods == alone.retaken_periods  # ... the same ones in the batch
    np.testing.assert_array_equal(twin.state(), alone.state())
    np.testing.assert_array_equal(twin.pos, alone.pos)
    for plant in (alone, *batch.plants):  # on its feet, no node faster than a swung leg (a blow-up: 100s of m/s)
        assert 0.005 < plant.state()[5] < 0.06
        assert np.abs(plant.vel).max() < 5.0


def test_a_crawl_on_a_grippy_stiff_model_needs_no_retake_at_1_ms_with_its_jacobians_refreshed_by_turn():
    # The robot's crawl winds one tendon to 165 deg at full servo speed while another lets go: the legs whip, their
    # elements turn tenths of a radian within the five steps a factorisation serves, and the linearly implicit step
    # on the old one diverges at 1 ms (grippy, stiff: friction 1.15, E 2.2e7 Pa). Refactored once an element has
    # turned 0.1 rad (plant.jacobian_turn), the same crawl runs through with no period retaken.
    from slotexp.bench import stability
    from slotexp.config import with_settings
    from slotexp.locomotion.schedules import play

    grippy = {**dict(stability.MODELS)["mu 1.15, E 2.19e7, c 9.2, horn zero 89.7"], "sim.dt": 1e-3}
    cfg = load("plant=cosserat")
    with pytest.raises(DivergenceError):
        play(with_settings(cfg, {**grippy, "plant.retakes": 0}), ["crawl_forward"], 3.0, 50.0)
    t, xs, retaken = play(with_settings(cfg, {**grippy, **stability.BY_TURN}), ["crawl_forward"], 3.0, 50.0)
    assert retaken.tolist() == [0] and np.isfinite(xs).all()
    assert xs[0, -1, 3] > 0.02  # it crawled forward (the state: attitude, position, ...), more than 20 mm in 3 s


def test_a_torso_on_the_ground_carries_its_weight_there_and_its_friction_stays_in_the_cone():
    # robot.torso.ground_contact: every tendon 25 deg slack (the robot's horn 105), the legs cannot hold the
    # body up and it settles onto its underside (bottom face 17 mm below the centre). The ground then carries
    # the weight through the underside and the legs' nodes near their roots together.
    cfg, plant = _plant("robot.torso.ground_contact=true", "robot.contact.friction=0.5")
    for _ in range(60):
        plant.step(TendonCommand(np.full(4, -25.0)), 1 / 30)
    weight = _total_mass(plant) * cfg.sim.gravity
    assert plant.state()[5] == pytest.approx(cfg.robot.torso.size[2] / 2, abs=5e-4)  # resting on its underside
    assert plant.belly[0] + plant.out[:, 4].sum() == pytest.approx(weight, rel=1e-3)
    assert plant.belly[0] > 0.3 * weight
    assert np.linalg.norm(plant.belly[1:3]) < 1e-6 * weight  # at rest, no friction
    plant.apply_impulse(np.array([0.3, 0.1, 0.0]), np.zeros(3))  # pushed: the underside slides and brakes
    plant.step(TendonCommand(np.full(4, -25.0)), 0.005)
    friction = plant.belly[1:3]
    assert 0.0 < np.linalg.norm(friction) <= 0.5 * plant.belly[0] * (1 + 1e-9)
    assert friction @ np.array([0.3, 0.1]) < 0.0  # against the slide
    off = _plant("robot.torso.ground_contact=false")[1]
    assert off.belly_points.shape == (0, 3)


@pytest.mark.parametrize("offset", [0.0, -0.015])
def test_standing_still_the_ground_pushes_up_under_the_centre_of_mass_wherever_the_torso_mass_sits(offset):
    # robot.torso.com_offset: the torso's mass centre 15 mm behind its box's centre. Standing still on equal
    # tendons, the ground's normal forces (k times each node's depth) carry the weight and their centre of
    # pressure lies under the whole robot's centre of mass: the rear feet carry more.
    cfg, plant = _plant(f"robot.torso.com_offset=[{offset},0]", "robot.contact.friction=0.6")
    for _ in range(150):
        plant.step(TendonCommand(np.full(4, 80.0)), 1 / 30)
    nodes = plant.leg_world().reshape(-1, 3)
    normal = cfg.robot.contact.stiffness * np.maximum(0.0, -nodes[:, 2])
    # the weight, to the little the penalty's damping still carries while the legs creep (measured < 1 %)
    assert normal.sum() == pytest.approx(_total_mass(plant) * cfg.sim.gravity, rel=0.02)
    pressure = normal @ nodes[:, 0:2] / normal.sum()
    np.testing.assert_allclose(pressure, plant.centre_of_mass()[0:2], atol=1e-3)  # measured < 0.3 mm
    box_centre = plant.torso[0] - offset  # the box's centre, in x (the torso pitches 2.3 deg: cos = 0.999)
    assert abs(plant.state()[1]) < np.radians(3.0)
    front = plant.out[[0, 3], 4].sum()  # FL, FR
    rear = plant.out[[1, 2], 4].sum()
    if offset == 0.0:
        assert front == pytest.approx(rear, rel=0.05) and abs(pressure[0] - box_centre) < 2e-3
    else:
        assert rear > 1.1 * front and pressure[0] < box_centre - 0.01  # measured 11.3 N against 9.5 N


def test_a_sideways_push_below_friction_bends_compliant_legs_while_their_feet_stick():
    # robot.leg.out_of_plane=bending: each foot's contact rides on a sideways spring (31 N/m) in series with
    # its friction. Pushed sideways with 0.5 N, far below mu N (about 13 N), the feet hold, rigid or not:
    # every foot's contact (its rigid place plus its deflection across the plane) stays where it was, the
    # compliant robot gives more than the rigid one, and its springs carry part of the push (the legs'
    # stiffer bending in their planes, at 45 deg to it, the rest). At the default step (0.14 and 0.20 mm;
    # converged, at 5e-5 s, 0.16 and 0.30 mm). Before the friction's secant slope the standing feet
    # chattered at this step and the same push slid both robots 16-24 mm in 2 s.
    push = np.array([0.0, 0.5, 0.0])
    shift = {}
    for option in ("rigid", "bending"):
        cfg, plant = _plant("robot.contact.friction=0.6", f"robot.leg.out_of_plane={option}")
        for _ in range(15):
            plant.step(TendonCommand(np.full(4, 80.0)), 1 / 30)
        _, u = plant._plane()
        lat = np.column_stack([-u[:, 1], u[:, 0]])

        def contacts(plant=plant, lat=lat):
            return plant.feet()[:, 0:2] + plant.lateral[:, 0:1] * lat

        y0, feet0 = plant.torso[1], contacts()
        for _ in range(30):
            plant.step(TendonCommand(np.full(4, 80.0)), 1 / 30, external_force=push)
        shift[option] = plant.torso[1] - y0
        moved = contacts() - feet0
        assert abs(moved[:, 1].mean()) < 1e-4  # the feet hold together: measured 0.04 mm
        assert np.abs(moved).max() < 5e-4  # each creeps outwards at the regularised friction's pace: 0.4 mm
        carried = plant.k_lat * (plant.lateral[:, 0] @ lat[:, 1])  # the springs' force on the torso, y
        if option == "rigid":
            assert np.all(plant.lateral == 0.0) and plant.k_lat == 0.0
        else:
            assert plant.k_lat == pytest.approx(30.8, abs=0.3)
            assert -0.5 < carried < -0.005
    assert 0.0 < shift["rigid"] < shift["bending"] < 1e-3


@pytest.mark.parametrize("friction, dt", [("secant", 2e-4), ("solved", 5e-4)])
def test_standing_feet_rest_at_each_friction_laws_step(friction, dt):
    # The robot stands on 80 deg tendons at mu 0.6, its feet's friction far from mu N. Their contact nodes
    # must rest, not chatter: a sliding node's friction is taken at its secant slope, so the step can stop a
    # slip but never throw it back. Measured at 2e-4 s: 0.5 mm/s rms along the leg's plane (converged,
    # 5e-5 s: 0.1); with the tangent slope (zero along a straight slip) it was 21.5 mm/s, the friction
    # saturated at mu N at every step. Solved at the step's end (the law's tangent in a Newton iteration to
    # convergence, not one linearisation) they rest too, at the default step (5e-4 s), the largest the
    # closed-loop yardstick admits with that law (2e-4 s with the secant).
    cfg, plant = _plant("robot.contact.friction=0.6", f"plant.friction={friction}", f"sim.dt={dt}")
    assert friction != "solved" or (cfg.sim.dt, cfg.plant.friction) == (_plant()[0].sim.dt, "solved")  # the default
    for _ in range(30):
        plant.step(TendonCommand(np.full(4, 80.0)), 1 / 30)
    along, ratio = [], []
    for _ in range(200):
        plant.step(TendonCommand(np.full(4, 80.0)), 1e-3)
        pressed = plant.normal > 0.0
        along.append(plant.vel[:, :, 0][pressed])
        ratio.append(np.abs(plant.out[:, O_F]) / plant.out[:, O_N])
    assert np.sqrt(np.mean(np.square(np.concatenate(along)))) < 2e-3
    assert np.max(ratio) < 0.5  # none of the feet slides: |F| < mu N


def test_raising_the_legs_mount_lowers_the_torso_by_as_much_and_leaves_the_legs_where_they_were() -> None:
    """robot.leg.root_above_bottom moves each root up the torso: set down on the same legs, the torso stands that
    much lower, in the rigid-body model the MPC uses and in the soft plant, and the legs are where they were."""
    rise = 0.00675
    cfg, low = _plant()
    _, high = _plant(f"robot.leg.root_above_bottom={rise}")
    a, b = build_robot(cfg.robot), build_robot(load("plant=cosserat", f"robot.leg.root_above_bottom={rise}").robot)
    # the rigid-body model's mass centre: the torso's, lowered, with the legs' lumped masses, which stay; the
    # roots rise by as much relative to it
    drop = rise * cfg.robot.torso.mass / a.mass
    assert b.stance_height == pytest.approx(a.stance_height - drop, abs=1e-12)
    assert np.allclose(b.corners_body[:, 2] - a.corners_body[:, 2], drop, atol=1e-12)
    assert np.allclose(b.feet_body - b.corners_body, a.feet_body - a.corners_body, atol=1e-12)
    assert high.torso[2] == pytest.approx(low.torso[2] - rise, abs=1e-9)
    assert np.allclose(high.pos, low.pos, atol=1e-4)  # within 0.1 mm: the settling (finite iterations) differs


def test_an_accuracy_case_runs_with_its_own_controller_settings_and_leaves_the_config_alone(monkeypatch):
    import slotexp.bench._accuracy as acc

    seen = {}
    monkeypatch.setattr(acc, "run_closed_loop", lambda cfg, *a, **k: seen.setdefault("cfg", cfg))
    cfg = load("plant=cosserat")
    case = next(c for c in acc.CASES if c.name == "walk, heading loop off")
    acc.run_case(cfg, case)
    assert seen["cfg"].controller.max_lean_deg == 0.0 and cfg.controller.max_lean_deg == 15.0
    assert seen["cfg"].gait.velocity == [0.02, 0.0]


def test_the_stability_bench_varies_the_model_and_the_step_it_names_and_reads_a_divergence_as_a_result():
    from slotexp.bench import stability
    from slotexp.config import with_settings

    cfg = load("plant=cosserat")
    model = with_settings(cfg, dict(stability.MODELS)["mu 1.5, E 4e6, c 5"])
    assert (model.robot.contact.friction, model.robot.leg.youngs_modulus, model.robot.leg.damping_per_s) == (
        1.5,
        4.0e6,
        5.0,
    )
    assert model.robot.leg.length == cfg.robot.leg.length and model.sim == cfg.sim  # nothing else moved
    run = with_settings(model, {**dict(stability.SETTINGS)["1 ms, newton 8"], "plant.retakes": 0})
    assert (run.sim.dt, run.plant.jacobian_age, run.plant.newton, run.plant.retakes) == (1e-3, 1, 8, 0)
    assert isinstance(run.plant.newton, int) and isinstance(run.sim.dt, float)  # each setting keeps its type
    kept = with_settings(model, dict(stability.SETTINGS)["default step"])
    assert kept.sim == cfg.sim and kept.plant == cfg.plant
    # soft legs without retakes blow up while being set down with their tendons taken at once: a row, not an error
    at_once = {**dict(stability.SETTINGS)["default step, no retakes"], "plant.wind_in_s": 0.0}
    result = stability._play(with_settings(model, at_once))
    assert result["ran_to_end"] is False
    assert 0.0 < result["diverged_at_s"] < 0.1
