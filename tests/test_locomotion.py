"""Locomotion on the soft legs: gait primitives, the library's mixing, the search, the closed loop."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from slotexp.controllers import make_controller
from slotexp.errors import ConfigError
from slotexp.jobs import gait_search
from slotexp.locomotion.library import GaitLibrary
from slotexp.locomotion.openloop import GaitMetrics, run_gait
from slotexp.locomotion.primitives import GaitStyle, Primitive, interpolate, mix, stance
from slotexp.locomotion.search import cost, from_vector, search, to_vector
from slotexp.plants import TendonCommand, make_plant, nominal_state
from slotexp.robot import build_robot
from slotexp.simulation import run_closed_loop
from tests.helpers import load

STYLE = GaitStyle(1.8, 0.43, 7.8)
TOP = 116.28


def _prim(name: str = "p", heading: float | None = 0.0, speed: float = 0.02) -> Primitive:
    return Primitive(
        name,
        np.array([70.0, 50.0, 55.0, 72.0]),
        np.array([60.0, 65.0, 62.0, 70.0]),
        np.array([0.0, -0.1, 0.4, 0.5]),
        heading,
        speed,
    )


def test_waveform_spans_zero_to_one_and_is_high_for_its_duty() -> None:
    u = np.linspace(0.0, 1.0, 4001, endpoint=False)
    w = STYLE.wave(u)
    assert w.min() == pytest.approx(0.0, abs=1e-12) and w.max() == pytest.approx(1.0, abs=1e-12)
    assert np.mean(w > 0.5) == pytest.approx(STYLE.duty, abs=2e-3)  # the edges are symmetric about 0.5
    np.testing.assert_allclose(STYLE.wave(u + 1.0), w, atol=1e-12)  # periodic


def test_mirror_images_swap_legs_reflect_the_heading_and_undo_themselves() -> None:
    p = _prim(heading=30.0)
    mx, my = p.mirrored("x"), p.mirrored("y")
    assert mx.heading_deg == pytest.approx(-30.0) and my.heading_deg == pytest.approx(150.0)
    np.testing.assert_array_equal(mx.base_deg, p.base_deg[[3, 2, 1, 0]])  # FL<->FR, RL<->RR
    np.testing.assert_array_equal(my.base_deg, p.base_deg[[1, 0, 3, 2]])  # FL<->RL, FR<->RR
    back = mx.mirrored("x")
    for field in ("base_deg", "amplitude_deg", "phase"):
        np.testing.assert_array_equal(getattr(back, field), getattr(p, field))
    assert back.heading_deg == pytest.approx(30.0)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_a_glide_symmetric_gait_is_its_own_mirror_image_half_a_cycle_later(axis: str) -> None:
    """Primitive.glide_symmetric: every leg's schedule is its mirror leg's half a cycle on (the property that
    makes a gait unable to turn a symmetric body over a cycle); a gait that already has it is left as it is."""
    p = replace(_prim(heading=0.0 if axis == "x" else 90.0), phase=np.array([0.0, -0.17, 0.34, 0.48]))
    g = p.glide_symmetric(axis)
    psi = np.linspace(0.0, 1.0, 61)
    np.testing.assert_allclose(g.mirrored(axis).angles(STYLE, psi + 0.5, TOP), g.angles(STYLE, psi, TOP), atol=1e-9)
    assert not np.allclose(p.mirrored(axis).angles(STYLE, psi + 0.5, TOP), p.angles(STYLE, psi, TOP))
    again = g.glide_symmetric(axis)
    for field in ("base_deg", "amplitude_deg", "phase"):
        np.testing.assert_allclose(getattr(again, field), getattr(g, field), atol=1e-12)
    assert (p.along_axis(), replace(p, heading_deg=45.0).along_axis(), replace(p, heading_deg=None).along_axis()) == (
        axis,
        None,
        None,
    )


def test_mix_is_the_weighted_sum_and_stance_is_the_pressing_half() -> None:
    a, b = _prim("a"), _prim("b", heading=90.0)
    psi = np.linspace(0.0, 1.0, 37)
    both = mix(STYLE, [(0.3, a), (0.7, b)], psi, TOP)
    np.testing.assert_allclose(both, 0.3 * a.angles(STYLE, psi, TOP) + 0.7 * b.angles(STYLE, psi, TOP))
    flags = stance(STYLE, [(1.0, a)], psi, TOP)
    cycle = a.angles(STYLE, np.arange(48) / 48, TOP).mean(axis=0)
    np.testing.assert_array_equal(flags, a.angles(STYLE, psi, TOP) >= cycle)
    still = stance(STYLE, [(1.0, Primitive.still("s", 60.0))], psi, TOP)
    assert still.all()  # a standing robot has every foot in stance


def test_a_primitives_kept_cycle_is_its_angles_and_stance_from_it_is_the_mix_over_the_whole_cycle() -> None:
    # the stance plan takes each primitive's cycle once (Primitive.cycle) instead of mixing it every MPC step: the
    # flags must be those of the mix over the cycle's samples and the asked phases together, bit for bit
    a, b = _prim("a"), replace(_prim("b", heading=90.0), phase=np.array([0.2, 0.1, -0.3, 0.05]))
    parts = [(0.35, a), (0.4, b), (0.25, Primitive.still("s", 60.0))]
    psi = 0.37 + np.arange(15) / 16
    kept = a.cycle(STYLE, TOP, 48)
    np.testing.assert_array_equal(kept, a.angles(STYLE, np.arange(48) / 48, TOP))
    assert a.cycle(STYLE, TOP, 48) is kept and not kept.flags.writeable
    assert replace(a, phase=a.phase + 0.25).cycle(STYLE, TOP, 48) is not kept  # a changed primitive, its own cycle
    both = mix(STYLE, parts, np.concatenate([np.arange(48) / 48, psi]), TOP)
    expected = (both[48:] >= both[:48].mean(axis=0)) | (np.ptp(both[:48], axis=0) < 1.0)
    np.testing.assert_array_equal(stance(STYLE, parts, psi, TOP), expected)
    np.testing.assert_array_equal(stance(STYLE, parts, psi, TOP, angles=mix(STYLE, parts, psi, TOP)), expected)


def test_interpolated_primitive_runs_from_a_to_b_along_the_shorter_phase_arc() -> None:
    a = _prim("a")
    b = Primitive("b", a.base_deg + 10.0, a.amplitude_deg - 20.0, np.array([0.0, 0.3, 0.45, -0.45]), 90.0, 0.02)
    for lam, want in ((0.0, a), (1.0, b)):
        p = interpolate(a, b, lam)
        np.testing.assert_allclose(p.base_deg, want.base_deg)
        np.testing.assert_allclose(p.amplitude_deg, want.amplitude_deg)
        np.testing.assert_allclose((p.phase - want.phase + 0.5) % 1.0 - 0.5, 0.0, atol=1e-12)  # same phase mod 1
    half = interpolate(a, b, 0.5)
    # RL: -0.1 -> 0.3 directly (0.4 of a cycle); FR: 0.5 -> -0.45 = 0.55 the short way (0.05 of a cycle)
    np.testing.assert_allclose(half.phase, [0.0, 0.1, 0.425, 0.525])
    np.testing.assert_allclose(half.base_deg, a.base_deg + 5.0)


def test_library_brackets_headings_and_scales_speed_against_standing() -> None:
    prims = [
        _prim("f", 0.0, 0.03),
        _prim("l", 90.0, 0.02),
        _prim("b", 180.0, 0.03),
        _prim("r", -90.0, 0.02),
        Primitive("turn", np.full(4, 60.0), np.full(4, 40.0), np.array([0, 0.25, 0.5, 0.75]), None, 0.0, 6.0),
    ]
    lib = GaitLibrary(STYLE, prims, 70.0, TOP, blend="schedules")
    assert lib.max_speed(45.0) == pytest.approx(0.025)  # halfway between 0.03 (0 deg) and 0.02 (90 deg)
    cmd = lib.command(np.array([0.015, 0.0]), 0.0)
    weights = {p.name: w for w, p in cmd.parts}
    assert weights["f"] == pytest.approx(0.5) and weights["still"] == pytest.approx(0.5)
    assert sum(w for w, _ in cmd.parts) == pytest.approx(1.0)
    turning = lib.command(np.array([0.03, 0.0]), 3.0)  # full speed and half the turn rate: scaled to fit
    w = {p.name: w for w, p in turning.parts}
    assert w["turn"] == pytest.approx(1 / 3) and w["f"] == pytest.approx(2 / 3)
    assert lib.command(np.array([0.0, -0.02]), 0.0).parts[0][1].name in ("r", "b")  # bracket by heading


def test_the_bracket_searches_a_ring_made_once_exactly_as_one_made_per_call() -> None:
    # _bracket's headings are computed once at build time (the path loop asks for a bracket ~30 times a step):
    # the same arithmetic as building them per call, so the same brackets and fractions to the last bit
    prims = [_prim("f", 0.0, 0.03), _prim("d", 44.0, 0.025), _prim("l", 90.0, 0.02), _prim("b", 181.5, 0.03),
             _prim("r", -92.0, 0.02)]  # fmt: skip
    lib = GaitLibrary(STYLE, prims, 70.0, TOP)

    def per_call(heading: float) -> tuple[str, str, float]:  # the computation as it was, from the primitives
        h = np.asarray([p.heading_deg for p in lib.translation], float)
        x = (heading - h[0]) % 360.0
        rel = (h - h[0]) % 360.0
        j = int(np.searchsorted(rel, x, side="right") - 1)
        k = (j + 1) % len(h)
        span = (rel[k] - rel[j]) % 360.0 if k != j else 360.0
        span = span or 360.0
        return lib.translation[j].name, lib.translation[k].name, float((x - rel[j]) / span)

    rng = np.random.default_rng(3)
    for heading in [*rng.uniform(-720.0, 720.0, 2000), 0.0, 44.0, 90.0, 181.5, -92.0, 268.0, 360.0]:
        a, b, lam = lib._bracket(float(heading))
        assert (a.name, b.name, lam) == per_call(float(heading))


def test_cycle_blend_alternates_whole_primitives_so_the_mean_velocity_points_where_commanded() -> None:
    prims = [_prim("f", 0.0, 0.03), _prim("f_slow", 4.0, 0.02), _prim("l", 90.0, 0.02), _prim("b", 180.0, 0.03)]
    lib = GaitLibrary(STYLE, prims, 70.0, TOP)  # blend="cycles" by default
    assert [p.name for p in lib.translation] == ["f", "l", "b"]  # a slower gait 4 deg from a faster one is dropped
    # across 45 deg: f at 0.03 m/s makes -0.0212 m/s, l at 0.02 m/s +0.0141: 60 % of the cycles are l's
    along = 0.4 * 0.03 * np.cos(np.pi / 4) + 0.6 * 0.02 * np.cos(np.pi / 4)
    assert lib.max_speed(45.0) == pytest.approx(along)
    cmd = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)]) * along * 0.5  # half the envelope
    total = np.zeros(2)
    for cycle in range(200):
        chosen = {lib.command(cmd, 0.0, cycle).parts[0][1].name for _ in range(3)}  # one choice per cycle
        assert len(chosen) == 1 and chosen <= {"f", "l"}
        parts = lib.command(cmd, 0.0, cycle).parts
        (w, p), (w_still, still) = parts
        assert w == pytest.approx(0.5) and still.name == "still" and w_still == pytest.approx(0.5)
        total += w * p.speed_mps * np.array([np.cos(np.radians(p.heading_deg)), np.sin(np.radians(p.heading_deg))])
    assert np.degrees(np.arctan2(total[1], total[0])) == pytest.approx(45.0, abs=0.5)
    assert np.hypot(*total) / 200 == pytest.approx(along * 0.5, rel=0.01)
    # near a primitive (within a tenth of the gap) the schedules are mixed by angle, as blend="schedules" does
    near = lib.command(np.array([0.01, 0.01 * np.tan(np.radians(4.5))]), 0.0, 0)
    weights = {p.name: w for w, p in near.parts}
    assert weights["l"] / (weights["f"] + weights["l"]) == pytest.approx(0.05)


@pytest.mark.parametrize("hold", [2, 3])
def test_a_held_cycle_blend_switches_only_every_hold_cycles_and_keeps_the_mean_direction(hold: int) -> None:
    """``hold`` cycles per choice: the same error diffusion over runs of cycles, so the choice changes only at a
    run's start, and the mean velocity still points where commanded."""
    prims = [_prim("f", 0.0, 0.03), _prim("l", 90.0, 0.02), _prim("b", 180.0, 0.03)]
    lib = GaitLibrary(STYLE, prims, 70.0, TOP, hold=hold)
    cmd = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)]) * lib.max_speed(45.0) * 0.5
    names = [lib.command(cmd, 0.0, cycle).parts[0][1].name for cycle in range(240)]
    runs = [names[k : k + hold] for k in range(0, len(names), hold)]
    assert all(len(set(r)) == 1 for r in runs)  # one choice per run of `hold` cycles
    assert sum(a != b for a, b in zip(names, names[1:])) > 240 // (4 * hold)  # and it does alternate
    total = sum(
        p.speed_mps * np.array([np.cos(np.radians(p.heading_deg)), np.sin(np.radians(p.heading_deg))])
        for p in (next(q for q in lib.translation if q.name == n) for n in names)
    )
    assert np.degrees(np.arctan2(total[1], total[0])) == pytest.approx(45.0, abs=1.0)
    with pytest.raises(ValueError, match="at least one cycle"):
        GaitLibrary(STYLE, prims, 70.0, TOP, hold=0)


def test_the_library_times_each_primitive_to_its_neighbour_and_starts_the_clock_where_the_search_did() -> None:
    f = _prim("f", 0.0, 0.03)
    late = Primitive("l", f.base_deg, f.amplitude_deg, f.phase + 0.4, 90.0, 0.02)  # f's legs, 0.4 cycles off
    odd = Primitive("b", f.base_deg, f.amplitude_deg, np.array([0.3, 0.1, -0.2, 0.05]), 180.0, 0.02)  # other sequence
    lib = GaitLibrary(STYLE, [f, late, odd, _prim("r", -90.0, 0.02).shifted(0.7)], 70.0, TOP)
    psi = np.linspace(0.0, 1.0, 61)
    by_name = {p.name: p for p in lib.translation}
    np.testing.assert_array_equal(by_name["f"].phase, f.phase)  # the fastest is the reference
    # a copy of f delayed in time is put back in step with it, to the alignment's 1/240 of a cycle
    np.testing.assert_allclose((by_name["l"].phase - f.phase + 0.5) % 1.0 - 0.5, 0.0, atol=1e-12)
    for p in lib.translation:  # a shift of the whole clock: same legs, same measurements, same schedule in time
        original = {"f": f, "l": late, "b": odd}.get(p.name)
        if original is not None:
            shift = p.phase[0] - original.phase[0]
            np.testing.assert_allclose(p.phase - original.phase, shift, atol=1e-12)
            np.testing.assert_allclose(p.angles(STYLE, psi, TOP), original.angles(STYLE, psi + shift, TOP), atol=1e-9)
            assert (p.heading_deg, p.speed_mps) == (original.heading_deg, original.speed_mps)
    # b is timed to its neighbour l (already in step with f): no shift of b correlates better with l
    b, left = by_name["b"], by_name["l"]
    score = [
        np.sum(
            (b.angles(STYLE, psi + d, TOP) - b.angles(STYLE, psi + d, TOP).mean(0))
            * (left.angles(STYLE, psi, TOP) - left.angles(STYLE, psi, TOP).mean(0))
        )
        for d in np.arange(60) / 60
    ]
    assert int(np.argmax(score)) in (0, 59, 1)
    # a robot sent along a moved primitive starts its clock where that primitive's search started it
    for original, velocity in ((late, [0.0, 0.01]), (odd, [-0.01, 0.0]), (f, [0.01, 0.001])):
        psi0 = lib.start_phase(np.array(velocity))
        moved = by_name[original.name]
        assert 0.0 <= psi0 < 1.0
        np.testing.assert_allclose(moved.angles(STYLE, psi0, TOP), original.angles(STYLE, 0.0, TOP), atol=1e-9)
    assert lib.start_phase(np.zeros(2)) == 0.0


def test_search_cost_prefers_speed_along_the_heading_and_charges_drift() -> None:
    base = dict(
        vx=20.0,
        vy=0.0,
        speed=20.0,
        heading_deg=0.0,
        yaw_rate_dps=0.0,
        yaw_total_deg=0.0,
        dz_mean_mm=0.0,
        dz_range_mm=4.0,
        roll_max_deg=5.0,
        pitch_max_deg=3.0,
        window_s=3.0,
    )
    fast = GaitMetrics(**base)
    slow = GaitMetrics(**{**base, "vx": 10.0, "speed": 10.0})
    drifting = GaitMetrics(**{**base, "vy": 5.0, "yaw_rate_dps": 1.0})
    assert cost(fast, 0.0) == pytest.approx(-20.0)
    assert cost(fast, 0.0) < cost(slow, 0.0) and cost(fast, 0.0) < cost(drifting, 0.0)
    assert cost(fast, 180.0) > 0  # going the wrong way costs
    # a neighbour's gait 45 deg off beats standing still, so an oblique heading's search has a slope to follow
    still = GaitMetrics(**{**base, "vx": 0.0, "speed": 0.0})
    assert cost(fast, 45.0) < cost(still, 45.0) == pytest.approx(0.0)
    assert cost(fast, 0.0) < cost(fast, 20.0) < cost(fast, 45.0)
    x = to_vector(_prim(), TOP)
    np.testing.assert_allclose(to_vector(from_vector(x, TOP), TOP), x)


def test_search_improves_on_its_starting_point_on_a_tiny_budget() -> None:
    cfg = load("plant=cosserat")
    style_cfg = cfg.controller.library["walk"]
    style = GaitStyle(style_cfg.frequency_hz, style_cfg.duty, style_cfg.sharpness)
    seed = min((p for p in style_cfg.primitives if p.heading_deg is not None), key=lambda p: abs(p.heading_deg))
    # the library's forward gait with its strokes cut to 5 deg: it hardly moves, and a few candidates show it
    start = Primitive("start", np.asarray(seed.base_deg), np.full(4, 5.0), np.asarray(seed.phase))

    def evaluate(xs: list[np.ndarray]) -> list[float]:
        out = []
        for x in xs:
            p = from_vector(x, TOP)
            m = run_gait(cfg, lambda t, p=p: p.angles(style, style.frequency_hz * t, TOP), style.frequency_hz, 2.0, 0.5)
            out.append(cost(m, 0.0))
        return out

    x0 = to_vector(start, TOP)
    start_cost = evaluate([x0])[0]
    best_cost, best_x = search(evaluate, x0, sigma0=0.2, popsize=6, max_evals=12, seed=3)
    assert best_cost < start_cost - 1.0, (start_cost, best_cost)  # at least 1 mm/s better, measured


def test_the_search_verifies_a_mirror_image_as_it_stands_and_it_walks_the_mirrored_way() -> None:
    cfg = load("plant=cosserat")
    style_cfg = cfg.controller.library["walk"]
    style = GaitStyle(style_cfg.frequency_hz, style_cfg.duty, style_cfg.sharpness)
    seed = min((p for p in style_cfg.primitives if p.heading_deg is not None), key=lambda p: abs(p.heading_deg))
    forward = Primitive.from_config(seed)
    image = forward.mirrored("y")  # front and back swapped: its first leg's phase is no longer zero
    assert image.phase[0] != 0.0
    ahead, back = (gait_search._evaluate((cfg, style, p, 2.0, 0.5)) for p in (forward, image))
    # the torso, legs and friction are symmetric about the body y axis: the image walks the mirrored way
    assert ahead["vx"] > 5.0
    assert back["vx"] == pytest.approx(-ahead["vx"], rel=0.01) and back["vy"] == pytest.approx(ahead["vy"], abs=0.2)
    # the same schedule shifted in time (what the search's vector keeps of it) meets other 30 Hz ticks
    shifted = gait_search._evaluate((cfg, style, from_vector(to_vector(image, TOP), TOP), 2.0, 0.5))
    assert abs(shifted["vx"] - back["vx"]) > 1.0


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_closed_loop_soft_robot_walks_the_commanded_way_and_reverses(sign: float) -> None:
    cfg = load("plant=cosserat", "experiment=simulate", f"gait.velocity=[{0.02 * sign},0]")
    states: list[np.ndarray] = []

    class Sink:
        def write(self, topic, t, message):
            if topic == "/state":
                states.append(np.asarray(message["p"], float))

        def write_pose(self, *args):
            pass

    summary = run_closed_loop(cfg, cfg.scenarios["baseline"], 4.0, Sink())
    moved = states[-1] - states[0]
    assert summary.infeasible_steps == 0
    assert sign * moved[0] > 0.03, moved  # 4 s at 20 mm/s, less the start: more than 30 mm the right way
    assert abs(moved[1]) < 0.3 * abs(moved[0])


def test_open_loop_and_gait_mpc_take_tendon_commands_the_plant_can_use() -> None:
    cfg = load("plant=cosserat", "controller=open_loop")
    robot = build_robot(cfg.robot)
    plant = make_plant(cfg, robot, nominal_state(robot))
    ctrl = make_controller(cfg, robot)
    step = ctrl.step(0.0, plant.state(), plant.feet())
    assert step.tendon_deg.shape == (4,) and np.all((0 <= step.tendon_deg) & (step.tendon_deg <= TOP))
    plant.step(TendonCommand(step.tendon_deg), ctrl.period)
    assert set(step.telemetry) >= {"phase", "velocity_command", "speed_fraction"}


def test_gait_search_refuses_a_start_primitive_the_library_lacks() -> None:
    assert load("plant=cosserat", "experiment=gait_search", "experiment.start_from=walk_turn").experiment.start_from
    with pytest.raises(ConfigError, match="experiment.start_from = 'nope' is neither a walk primitive nor a sched"):
        load("plant=cosserat", "experiment=gait_search", "experiment.start_from=nope")


def test_the_normal_force_offsets_drop_only_the_twist_the_plan_leaves_open() -> None:
    from slotexp.controllers.gait_mpc import without_twist

    rng = np.random.default_rng(4)
    lever = np.array([[0.09, 0.07, -0.04], [-0.10, 0.06, -0.04], [-0.08, -0.07, -0.04], [0.10, -0.06, -0.04]])
    a = np.vstack([np.ones(4), lever[:, 0], lever[:, 1]])  # net normal force, roll and pitch moments
    # offsets that change the net force or moments (the plan's height and attitude) pass unchanged
    planned = a.T @ rng.normal(size=3)
    np.testing.assert_allclose(without_twist(planned, lever), planned, atol=1e-12)
    # any offsets come out with the same net force and moments, and no twist is left to remove
    offsets = rng.normal(size=4) * 10.0
    out = without_twist(offsets, lever)
    np.testing.assert_allclose(a @ out, a @ offsets, atol=1e-12)
    np.testing.assert_allclose(without_twist(out, lever), out, atol=1e-12)
    # on a rectangle the twist is the diagonal pattern (+, -, +, -): it is removed entirely
    square = np.array([[0.1, 0.05, 0.0], [-0.1, 0.05, 0.0], [-0.1, -0.05, 0.0], [0.1, -0.05, 0.0]])
    np.testing.assert_allclose(without_twist(np.array([1.0, -1.0, 1.0, -1.0]), square), 0.0, atol=1e-12)


def test_the_attitude_trim_lowers_the_high_corners_at_its_rate_and_holds_within_its_reach() -> None:
    from slotexp.controllers.gait_mpc import MAX_TRIM_DEG, MM_PER_DEG

    cfg = load("plant=cosserat", "controller.attitude_trim=0.5", "controller.heading_kp=0", "controller.heading_ki=0")
    robot = build_robot(cfg.robot)
    ctrl = make_controller(cfg, robot)
    x = nominal_state(robot)
    x[5] = cfg.gait.height
    feet = x[3:6] + robot.feet_body
    level = np.tile([0.0, 0.0, ctrl.weight / 4.0], (4, 1))  # a plan with no normal-force offsets
    x[1] = -0.03  # nose up: the front corners (x > 0) sit high by 0.03 rad x their lever
    ctrl.adjust(x, feet, level, None)
    expected = -0.5 * ctrl.period * 1000.0 * 0.03 * robot.corners_body[:, 0] / MM_PER_DEG
    np.testing.assert_allclose(ctrl.trim, expected, rtol=1e-12)
    front = robot.corners_body[:, 0] > 0
    assert np.all(ctrl.trim[front] < 0) and np.all(ctrl.trim[~front] > 0)
    x[1], x[0] = 0.0, 0.03  # rolled left side up: the left legs (y > 0) wind out, the right ones in
    for _ in range(2000):
        ctrl.adjust(x, feet, level, None)
    left = robot.corners_body[:, 1] > 0
    np.testing.assert_allclose(ctrl.trim[left], -MAX_TRIM_DEG)
    np.testing.assert_allclose(ctrl.trim[~left], MAX_TRIM_DEG)


def test_the_trim_levels_across_the_heading_loops_lean_and_standing_holds_the_height_too() -> None:
    """Walking forward, the heading loop's lean is a roll pattern (left legs against right): the trim must not
    integrate against it, or the two wind up; it still levels pitch. Standing, it also holds the stance's
    height (every leg alike); walking, the gait keeps its own posture."""
    from slotexp.controllers.gait_mpc import MM_PER_DEG

    cfg = load("plant=cosserat", "controller.attitude_trim=0.5", "gait.velocity=[0.02,0]")
    robot = build_robot(cfg.robot)
    ctrl = make_controller(cfg, robot)
    x = nominal_state(robot)
    x[5] = cfg.gait.height - 0.002  # 2 mm low: walking, the trim leaves the height to the gait
    feet = x[3:6] + robot.feet_body
    level = np.tile([0.0, 0.0, ctrl.weight / 4.0], (4, 1))
    x[0], x[1] = 0.03, -0.03  # rolled and pitched
    for _ in range(30):
        ctrl.adjust(x, feet, level, None)
    left = robot.corners_body[:, 1] > 0
    front = robot.corners_body[:, 0] > 0
    roll_part = ctrl.trim @ np.where(left, 1.0, -1.0)
    assert abs(roll_part) < 1e-9 and abs(ctrl.trim.sum()) < 1e-9  # nothing along the lean, nothing common
    assert np.all(ctrl.trim[front] < 0) and np.all(ctrl.trim[~front] > 0)  # pitch is levelled
    standing = make_controller(load("plant=cosserat", "controller.attitude_trim=0.5", "gait.velocity=[0,0]"), robot)
    x[0] = x[1] = 0.0
    standing.adjust(x, feet, level, None)
    np.testing.assert_allclose(standing.trim, 0.5 * standing.period * 2.0 / MM_PER_DEG, rtol=1e-12)  # all wind in


def test_a_command_beyond_the_gait_librarys_envelope_gets_one_warning_naming_it_and_a_reachable_override():
    from slotexp.controllers._gait import envelope_warning

    fast = load("plant=cosserat", "experiment=simulate", "gait.velocity=[0.08,0]")  # the paper's walk
    message = envelope_warning(fast)
    top = fast.controller.library["walk"].primitives  # the library's measured forward speed is in the message
    assert message is not None and "80.0 mm/s at 0 deg" in message and "gait.velocity=[" in message
    assert any(f"{p.speed_mps * 1e3:.1f} mm/s" in message for p in top)
    assert envelope_warning(load("plant=cosserat", "experiment=simulate", "gait.velocity=[0.015,0]")) is None
    spin = load("plant=cosserat", "experiment=simulate", "gait.velocity=[0,0]", "gait.yaw_rate=1.0")
    assert "gait.yaw_rate = 1 rad/s" in envelope_warning(spin)
    assert envelope_warning(load("experiment=simulate")) is None  # the ideal plant has no library to outrun


@pytest.mark.parametrize("gait", ["walk", "backward", "lateral", "omni60", "crawl"])
def test_the_soft_plant_walks_each_gait_by_default_inside_the_librarys_envelope(gait: str) -> None:
    # plant=cosserat's reference is each gait's soft_velocity (the paper's speeds are beyond the soft legs), a
    # command the gait library reaches; the ideal plant keeps the paper's, and the command line still wins
    from slotexp.controllers._gait import envelope_warning

    soft = load("plant=cosserat", "experiment=simulate", f"gait={gait}")
    assert soft.gait.velocity == soft.gait.soft_velocity != load("experiment=simulate", f"gait={gait}").gait.velocity
    assert 0.0 < np.hypot(*soft.gait.velocity) <= 0.0151
    assert envelope_warning(soft) is None
    asked = load("plant=cosserat", "experiment=simulate", f"gait={gait}", "gait.velocity=[0.001,0.002]")
    assert asked.gait.velocity == [0.001, 0.002]


def test_a_step_schedule_seeds_a_primitive_of_its_shape() -> None:
    """The robot's forward gait: FL then FR reach (low) for a step each, the rear legs stand: as a primitive the
    front legs swing half a cycle apart over their range and the rear legs hold their angle."""
    from slotexp.locomotion.primitives import from_steps

    steps = np.array([[0.0, 80.0, 80.0, 80.0], [80.0, 80.0, 80.0, 0.0]])  # FL, RL, RR, FR
    p = from_steps("forward", steps, TOP)
    np.testing.assert_allclose(p.base_deg, [0.0, 80.0, 80.0, 0.0])
    np.testing.assert_allclose(p.amplitude_deg, [80.0, 0.0, 0.0, 80.0])
    assert abs(((p.phase[3] - p.phase[0]) % 1.0) - 0.5) < 1e-12
    psi = np.linspace(0.0, 1.0, 400, endpoint=False)
    angles = p.angles(STYLE, psi, TOP)
    high = angles > 40.0
    assert high[:, 0].any() and high[:, 3].any() and not np.any(high[:, 0] & high[:, 3])  # the front legs alternate
    np.testing.assert_allclose(angles[:, 1:3], 80.0)
    assert load("plant=cosserat", "experiment=gait_search", "experiment.start_from=forward").experiment.start_from


def test_max_evals_caps_the_search_at_whole_generations():
    # 10 evaluations at 4 a generation: the start and two generations (8), never a third that would pass the cap
    seen: list[int] = []

    def evaluate(xs):
        seen.append(len(xs))
        return [float(np.sum((np.asarray(x) - 0.3) ** 2)) for x in xs]

    bounds = (np.zeros(3), np.ones(3))
    search(evaluate, np.full(3, 0.5), sigma0=0.2, popsize=4, max_evals=10, seed=1, bounds=bounds)
    assert seen == [1, 4, 4]


def test_the_library_envelope_passes_through_each_primitive_and_is_what_the_controller_clips_to() -> None:
    from slotexp.jobs.gait_search import envelope
    from slotexp.locomotion.library import GaitLibrary

    cfg = load("plant=cosserat")
    style = cfg.controller.library["walk"]
    headings, top = envelope(style, TOP)
    assert headings[0] == 0.0 and headings[-1] == 360.0 and np.all(top > 0)
    lib = GaitLibrary.from_config(style, 0.0, TOP)
    for p in lib.translation:  # at a primitive's own heading the envelope is its measured speed
        assert lib.max_speed(p.heading_deg) == pytest.approx(p.speed_mps, rel=1e-9)
    np.testing.assert_allclose(top, [lib.max_speed(h) for h in headings])
    assert envelope(replace(style, primitives=style.primitives[:1]), TOP) is None  # one direction cannot steer


def test_without_the_plans_attitude_the_legs_get_its_height_alone() -> None:
    """`controller.attitude_from_plan=false`: a plan that presses the front legs harder than the rear moves
    every tendon by the plan's common offset (its height part), the same on every leg; on, the front legs
    get more than the rear by the plan's difference."""
    offsets = {}
    for flag in ("true", "false"):
        cfg = load(
            "plant=cosserat",
            f"controller.attitude_from_plan={flag}",
            "controller.attitude_trim=0",
            "controller.heading_kp=0",
            "controller.heading_ki=0",
        )
        robot = build_robot(cfg.robot)
        ctrl = make_controller(cfg, robot)
        x = nominal_state(robot)
        x[5] = cfg.gait.height
        feet = x[3:6] + robot.feet_body
        front = robot.corners_body[:, 0] > 0
        plan = np.tile([0.0, 0.0, ctrl.weight / 4.0], (4, 1))
        plan[:, 2] += np.where(front, 1.0, -0.5)  # 1 N more on each front leg, 0.5 N less on each rear one
        offsets[flag] = ctrl.adjust(x, feet, plan, None)
    slope = cfg.robot.actuation.slope_n_per_deg
    np.testing.assert_allclose(offsets["false"], offsets["false"][0], atol=1e-12)
    np.testing.assert_allclose(offsets["false"].mean(), offsets["true"].mean(), atol=1e-12)
    assert offsets["false"][0] > 0  # the plan asks for more force in all: the legs press harder
    difference = offsets["true"][front].mean() - offsets["true"][~front].mean()
    np.testing.assert_allclose(difference, 1.5 / slope, rtol=1e-9)
