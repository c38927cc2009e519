"""The robot's own gaits as schedules: one horn map for the soft plant and the servos, and their replay."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from slotexp.errors import ConfigError
from slotexp.jobs._logged import run_logged
from slotexp.jobs.replay import schedule_config
from slotexp.locomotion.schedules import (
    cycle_s,
    gait_metrics,
    play,
    schedule_tendon_deg,
    schedule_velocity,
    step_index,
    with_profile_velocity,
    wrap_deg,
)
from slotexp.record import read_log
from slotexp.runlog import load_run
from slotexp.soft.servo import HornMap
from tests.helpers import CONF, assert_one_line_error, last_line, load, ok, run_on_emulator, slot
from tests.servo_emulator import OdometryPublisher, ServoEmulator

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "slot_hardware_gaits.yaml"
OURS = {"FL": "FL", "FR": "FR", "BL": "RL", "BR": "RR"}  # the robot authors' leg names -> ours


def test_the_shipped_schedules_are_the_robots_gaits_and_only_those_in_shared_data_are_not_held_out():
    # Every visible gait of the robot's file is a schedule config with the same numbers (the file's legs
    # FL FR BL BR are our FL FR RL RR); every other shipped schedule is one of the robot's held-out gaits,
    # marked so. Without the shared data beside the repository, against our copy alone.
    cfg = load()
    source = yaml.safe_load(SHARED.read_text())["gaits"] if SHARED.exists() else None
    names = set(p.stem for p in (CONF / "schedule").glob("*.yaml"))
    visible = {"forward", "backward", "right_walk", "left_walk", "walk_45", "crawl_forward", "crawl_backward"}
    assert names == set(cfg.schedules) and {n for n in names if not cfg.schedules[n].heldout} == visible
    assert len(names - visible) == 15  # eleven headings, two turns and the forward gait's other two variants
    for name in names - visible:
        s = cfg.schedules[name]
        assert (s.heading_deg is None) == (s.turn is not None) and s.robot_distance_per_cycle_m is None
    if source is None:
        pytest.skip("shared/data is not beside this checkout")
    assert set(source) == visible
    for name, gait in source.items():
        ours = cfg.schedules[name]
        assert ours.step_s == gait["step_s"] and ours.heading_deg == gait["heading_deg"] and ours.units == "horn"
        assert [{OURS[k]: v for k, v in step.items()} for step in gait["steps"]] == ours.steps


def test_horn_angles_become_tendon_angles_through_the_one_horn_map():
    cfg = load("plant=cosserat")
    horn = HornMap.from_config(cfg.robot.servo)
    tendon = schedule_tendon_deg(cfg.schedules["forward"], list(cfg.robot.leg.names), horn)
    # horn 105 ("step height") is 25 deg below the zero, 130: slack; 210 ("standing height") winds 80 deg
    np.testing.assert_allclose(tendon, [[-25.0, 80.0, 80.0, 80.0], [80.0, 80.0, 80.0, -25.0]])
    np.testing.assert_allclose(horn.horn_deg(tendon), [[105.0, 210.0, 210.0, 210.0], [210.0, 210.0, 210.0, 105.0]])
    # held within the robot's own limits, 10-350 deg (its gait code clamps there)
    assert horn.tendon_deg(np.array([5.0, 355.0, 130.0, 130.0]))[0:2].tolist() == [-120.0, 220.0]
    # a step held 0.42 s: step 1 from 0.42 s to 0.84 s, then the cycle again
    schedule = cfg.schedules["forward"]
    assert [step_index(schedule, t) for t in (0.0, 0.41, 0.42, 0.83, 0.84, 1.3)] == [0, 0, 1, 1, 0, 1]


def test_a_schedule_whose_steps_miss_the_controller_ticks_is_refused():
    with pytest.raises(ConfigError, match="step_s = 0.42 s is not a whole number of ticks at mpc.rate_hz = 30"):
        load("plant=cosserat", "controller=schedule", "mpc.rate_hz=30")
    with pytest.raises(ConfigError, match="each step needs exactly the legs"):
        load("schedules.forward.steps=[{FL: 1.0, RL: 2.0, RR: 3.0}]")
    with pytest.raises(ConfigError, match="holds no whole cycle of forward .* give experiment.duration >= 4.2"):
        load("plant=cosserat", "experiment=replay", "experiment.duration=4")
    with pytest.raises(ConfigError, match="use plant=cosserat"):
        load("experiment=replay")


def test_a_schedule_angle_the_servo_cannot_reach_is_refused_not_clipped():
    # a clipped step is not the gait that was written: the horn range is the robot's own 10-350 deg. Checked
    # where a schedule is played (controller=schedule, experiment=replay, identify, a search's start_from)
    step = "{FL: %s, RL: 210.0, RR: 210.0, FR: 210.0}"
    played = ("plant=cosserat", "controller=schedule", "controller.schedule=forward", "mpc.rate_hz=50")
    for angle in (355.0, 5.0, -50.0):
        with pytest.raises(ConfigError, match=rf"steps\[0\]\.FL = {angle:g} deg is outside the servo's range 10-350"):
            load(*played, f"schedules.forward.steps=[{step % angle}]")
        load(f"schedules.forward.steps=[{step % angle}]")  # not played: not refused
    load(*played, f"schedules.forward.steps=[{step % 10.0}]")  # the range's ends are reachable
    load(*played, f"schedules.forward.steps=[{step % 350.0}]")
    replayed = ("plant=cosserat", "experiment=replay", "experiment.schedules=[forward]")
    with pytest.raises(ConfigError, match="outside the servo's range"):
        load(*replayed, f"schedules.forward.steps=[{step % 5.0}]")
    # in tendon units through the horn map (zero 130 deg): 300 deg of tendon is horn 430
    tendon = f"schedules.forward.steps=[{step % 300.0}]".replace("210.0", "80.0")
    with pytest.raises(ConfigError, match=r"300 deg of tendon \(horn 430 deg\) is outside the servo's range"):
        load(*played, "schedules.forward.units=tendon", tendon)
    with pytest.raises(ConfigError, match="horn_min_deg = 360 deg is not below horn_max_deg = 350 deg for FL"):
        load("robot.servo.horn_min_deg=[360,10,10,10]")


def test_a_schedule_sends_the_same_goal_ticks_to_the_servos_as_to_the_soft_plant(tmp_path: Path):
    # The same schedule, played by the soft plant and by `slot hardware` against the servo emulator: the
    # tendon command at each tick is the schedule's, and the servos receive its horn angles as ticks.
    overrides = ("controller=schedule", "controller.schedule=crawl_forward")
    cfg = load("plant=cosserat", *overrides, "experiment=simulate")
    run_logged(cfg, cfg.scenarios["baseline"], 1.0, tmp_path / "sim.mcap", "{}", "test")
    sim = read_log(tmp_path / "sim.mcap")["/tendon"]
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        result, _ = run_on_emulator(emu, pub, tmp_path / "hw", "duration=1", *overrides)
    assert result.exit_code == 0, result.message
    hw = read_log(result.log_path)
    schedule = cfg.schedules["crawl_forward"]
    horn = np.array([[step[leg] for leg in cfg.robot.leg.names] for step in schedule.steps])
    legs = [f"command_deg.{i}" for i in range(4)]
    for log in (sim, hw["/tendon"]):
        expected = horn[[step_index(schedule, t) for t in log["t"]]] - 130.0
        np.testing.assert_allclose(log[legs].to_numpy(float), expected)
    goals = hw["/servos"][[f"goal.{i}" for i in range(4)]].to_numpy(float)
    expected_ticks = np.rint(horn[[step_index(schedule, t) for t in hw["/servos"]["t"]]] * 4096 / 360)
    np.testing.assert_array_equal(goals, expected_ticks)  # 105 and 255 included: the robot's own range
    assert len(set(map(tuple, goals))) >= 3  # the run went through several steps
    assert not hw["/servos"][[f"clamped.{i}" for i in range(4)]].to_numpy().any()
    # named and paced as its schedule, in simulation and on the robot: crawl_forward, 40 mm a cycle forward
    assert cfg.gait.name == "crawl_forward" and result.log_path.name == "hardware.mcap"
    assert hw.metadata["run"]["gait"] == "crawl_forward"
    pace = 0.04 / cycle_s(schedule)
    np.testing.assert_allclose(cfg.gait.velocity, [pace, 0.0], atol=1e-12)


def test_a_schedule_run_is_judged_against_the_robots_own_pace_on_its_heading():
    # it was judged as the walk it carried (crawl_forward: -114 % and -113 deg against the walk's 15 mm/s)
    played = ("plant=cosserat", "controller=schedule", "mpc.rate_hz=50")
    right = load(*played, "controller.schedule=right_walk")  # compass 90 (right): -y in the body frame, no distance
    assert right.gait.name == "right_walk" and right.gait.velocity == [0.0, 0.0]  # the robot's pace is not known
    forward = load(*played, "controller.schedule=forward")
    np.testing.assert_allclose(forward.gait.velocity, [0.05 / 0.84, 0.0], atol=1e-12)
    assert schedule_velocity(replace(forward.schedules["right_walk"], robot_distance_per_cycle_m=0.084)) == (
        pytest.approx([0.0, -0.1], abs=1e-12)
    )


def test_replay_metrics_measure_whole_cycles_in_both_heading_conventions():
    # 20 mm per 0.84 s cycle along +y (our heading +90 deg, counter-clockwise; the robot's compass 270: left)
    t = np.arange(0, 12.0001, 0.02)
    x = np.zeros((len(t), 12))
    x[:, 4] = 0.02 * t / 0.84
    x[:, 2] = np.radians(1.0) * t
    x[:, 5] = 0.04 + 0.002 * np.sin(2 * np.pi * t / 0.84)
    m = gait_metrics(t, x, 0.84, 3.0)
    assert m["cycles"] == int(12 / 0.84) - 4
    assert m["distance_per_cycle_mm"] == pytest.approx(20.0, rel=1e-9)
    assert m["heading_deg"] == pytest.approx(90.0) and m["compass_deg"] == pytest.approx(270.0)
    assert m["yaw_rate_deg_s"] == pytest.approx(1.0, rel=1e-9)
    assert m["heave_mm"] == pytest.approx(4.0, rel=5e-3)  # the sampled sine misses its peaks by a little
    assert wrap_deg(350.0 - 0.0) == -10.0 and wrap_deg(-190.0) == 170.0 and wrap_deg(180.0) == 180.0


def test_schedules_played_in_a_batch_follow_the_closed_loop_schedule_runs(tmp_path: Path):
    # The batch player (identification's) and the closed-loop controller=schedule run (replay's) must be the
    # same experiment: same start, same commands at the same ticks, same plant arithmetic. Not bit for bit: the
    # closed loop steps (t + period) - t, which from the third tick differs from the period in its last bit, and
    # the feet's stick-slip grows that with the step. At 2e-4 s the poses stay within 0.05 um over the 1 s and
    # the rates within 6e-6; at the default 5e-4 s the crawl's poses part by 2.8 um and its rates by 1.8e-4 (with
    # the secant friction at 5e-4 s, 25 um and 4.7e-3), so the check is made at 2e-4 s, where round-off stays
    # small enough to tell the two paths' arithmetic apart from the step's sensitivity.
    cfg = load("plant=cosserat", "experiment=replay", "sim.dt=2e-4")
    names = ["forward", "crawl_forward"]
    t, xs, retaken = play(with_profile_velocity(cfg, 0.0), names, 1.0, 50.0)
    for b, name in enumerate(names):
        run_logged(schedule_config(cfg, name), cfg.scenarios["baseline"], 1.0, tmp_path / f"{name}.mcap", "{}", "t")
        run = load_run(tmp_path / f"{name}.mcap")
        np.testing.assert_allclose(run.t, t[: len(run.t)])
        np.testing.assert_allclose(run.x[:, :6], xs[b, : len(run.t), :6], rtol=0, atol=1e-6)  # pose: um, urad
        np.testing.assert_allclose(run.x[:, 6:], xs[b, : len(run.t), 6:], rtol=0, atol=1e-4)  # rates: m/s, rad/s
        assert len(run.t) >= len(t) - 1
    assert np.abs(xs[0, -1, 3:5] - xs[0, 0, 3:5]).max() > 1e-5  # the robots moved: the comparison is not vacuous
    assert retaken.tolist() == [0, 0]  # the default model never needs a period retaken (plant.retakes)


def test_foot_strokes_measure_each_feet_travel_and_the_distance_they_would_give_gripped_whole() -> None:
    """Feet moving sinusoidally along legs at 45 deg + k 90 deg: each stroke is its peak-to-peak, and the ceiling
    along 0 deg the strokes' sum times cos 45 deg (each leg's stroke used once a cycle); a leg along the heading
    counts whole and one across it not at all."""
    from slotexp.locomotion.schedules import foot_strokes

    cycle, n = 0.84, 84
    t = np.arange(8 * n + 1) * (cycle / n)
    amplitude = np.array([0.012, 0.008, 0.0, 0.004])  # m, peak to peak
    reach = 0.2 + 0.5 * amplitude * np.sin(2 * np.pi * t / cycle)[:, None]
    leg_yaw = np.radians([45.0, 135.0, 225.0, 315.0])
    out = foot_strokes(t, reach, cycle, 3.0, leg_yaw, 0.0)
    np.testing.assert_allclose([out[f"stroke_{i}_mm"] for i in range(4)], amplitude * 1e3, atol=1e-9)
    assert out["stroke_max_mm"] == pytest.approx(12.0)
    assert out["stroke_ceiling_mm"] == pytest.approx(24.0 * np.cos(np.radians(45.0)))
    along = foot_strokes(t, reach, cycle, 3.0, leg_yaw, 45.0)  # FL along the travel, RL and FR across it
    assert along["stroke_ceiling_mm"] == pytest.approx(12.0 + 0.0 * 8.0 + 0.0 * 4.0, abs=1e-9)


def test_foot_slides_are_each_feet_path_over_the_ground_per_cycle() -> None:
    """A foot that anchors travels nothing; one that circles its radius travels its circumference per cycle; one
    that goes out and back along a line travels twice the line; only the measured cycles count (a foot that slid
    before them and then held travels nothing)."""
    from slotexp.locomotion.schedules import foot_slides

    cycle, n = 0.84, 840
    t = np.arange(8 * n + 1) * (cycle / n)
    phase = 2 * np.pi * t / cycle
    feet = np.zeros((len(t), 4, 2))
    feet[:, 1] = 0.01 * np.column_stack([np.cos(phase), np.sin(phase)])  # a circle of 10 mm radius
    feet[:, 2, 0] = 0.004 * (1 - np.cos(phase))  # out 8 mm and back along x
    feet[:, 3, 0] = np.where(t < 2.0, t * 0.01, 0.02)  # slid before the measured cycles, then held
    out = foot_slides(t, feet, cycle, 3.0)
    assert out["slide_0_mm"] == 0.0 and out["slide_3_mm"] == 0.0
    assert out["slide_1_mm"] == pytest.approx(2 * np.pi * 10.0, rel=1e-4)  # the chords of 840 samples a cycle
    assert out["slide_2_mm"] == pytest.approx(16.0, rel=1e-9)
    assert out["slide_min_mm"] == 0.0 and out["slide_max_mm"] == out["slide_1_mm"]


def test_a_users_own_schedule_in_their_config_directory_plays_like_a_shipped_one(tmp_path: Path):
    # docs/schedules.md, "Your own schedule": a YAML in <dir>/schedule/, hydra.searchpath and the schedules entry
    (tmp_path / "myconf" / "schedule").mkdir(parents=True)
    shipped = (CONF / "schedule" / "forward.yaml").read_text()
    (tmp_path / "myconf" / "schedule" / "deep_step.yaml").write_text(
        shipped.replace("name: forward", "name: deep_step").replace("105.0", "95.0")
    )
    user = ["hydra.searchpath=[file://myconf]", "+schedule@schedules.deep_step=deep_step"]
    run = ok(slot("run", "experiment=replay", "plant=cosserat", "experiment.schedules=[deep_step]",
                  "experiment.gif=false", "experiment.duration=4.2", *user, cwd=tmp_path))  # fmt: skip
    table = pd.read_csv(Path(last_line(run.stdout)) / "replay.csv")
    assert list(table["gait"]) == ["deep_step"]
    wrong = ["hydra.searchpath=[file://myconf]", "+schedule@schedules.deep_step=nothere"]
    unknown = slot("run", "experiment=replay", "plant=cosserat", "experiment.schedules=[deep_step]", *wrong,
                   cwd=tmp_path)  # fmt: skip
    assert_one_line_error(unknown, "unknown schedule 'nothere'", "deep_step", "myconf/schedule/")


def test_a_heading_is_defined_only_where_the_cycles_agree_on_a_direction() -> None:
    from slotexp.locomotion.schedules import gait_metrics

    cycle, n = 0.8, 30
    t = np.arange(0, n * cycle + 1e-9, cycle / 8)
    rng = np.random.default_rng(3)

    def walked(per_cycle: np.ndarray) -> np.ndarray:  # the state (n, 12) of a body whose cycles move it so
        x = np.zeros((len(t), 12))
        ends = np.vstack([[0.0, 0.0], np.cumsum(per_cycle, axis=0)])
        for axis in (0, 1):
            x[:, 3 + axis] = np.interp(t, np.arange(n + 1) * cycle, ends[:, axis])
        return x

    steady = walked(np.tile([0.001, 0.0002], (n, 1)) + rng.normal(0, 2e-4, (n, 2)))  # 1 mm a cycle, 0.2 scatter
    shuffling = walked(rng.normal(0, 3e-3, (n, 2)) + [2e-4, 0.0])  # 0.2 mm a cycle under 3 mm of scatter
    assert gait_metrics(t, steady, cycle, 0.0)["heading_defined"]
    assert not gait_metrics(t, shuffling, cycle, 0.0)["heading_defined"]
