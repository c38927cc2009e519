"""The hardware loop, in process, against the protocol-level servo emulator and a ZeroMQ odometry publisher.

The real dynamixel-sdk talks to the emulator over a pseudo-terminal; odometry comes
over tcp on 127.0.0.1. Runs are 1-2 s of wall-clock time each.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from slotexp.errors import UserError
from slotexp.foxglove_scene import schemas
from slotexp.hardware.mapping import ServoMap
from slotexp.hardware.run import EXIT_SAFETY_STOP, run_hardware
from slotexp.record import read_log
from slotexp.runlog import load_run
from tests.helpers import load_hardware, run_on_emulator, turned_off_after_on
from tests.servo_emulator import INST_SYNC_READ, OdometryPublisher, ServoEmulator

SIM_TOPICS = {
    "/state",
    "/state_measured",
    "/reference",
    "/cost",
    "/forces",
    "/contact",
    "/tendon",
    "/mpc/stats",
    "/mpc/plan",
    "/constraints",
    "/markers",
    "/torso/pose",
}


def goal_ticks(log) -> np.ndarray:
    return log["/servos"][[f"goal.{i}" for i in range(4)]].to_numpy(float)


def test_full_loop_commands_the_mapped_tendon_angles(tmp_path: Path) -> None:
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        result, notes = run_on_emulator(emu, pub, tmp_path, "duration=2")
        torque_history = emu.torque_writes()
        watchdog = {i: emu.register(i, "bus_watchdog") for i in emu.servos}
        final_goal = [emu.register(i, "goal_position") for i in (1, 2, 3, 4)]
        torque = emu.torque()
    assert result.exit_code == 0, result.message
    assert result.outcome.stop_reason == "duration" and result.outcome.steps == 60
    log = read_log(result.log_path)
    assert not log.truncated
    assert SIM_TOPICS | {"/servos", "/loop"} <= set(log.topics)
    assert set(log.scene_topics) == set(schemas())  # the transform and the 3D scene, for Foxglove
    # the log has the simulation schema: the run-log reader behind tables/figures loads it
    data = load_run(result.log_path)
    assert len(data.t) == 60 and np.allclose(np.diff(data.t), 1 / 30)
    assert np.allclose(data.x, data.x_meas)
    assert np.allclose(data.x[:, 5], 0.04)
    # goals = documented mapping of the controller's tendon angles, and that is what reached the servos
    cfg = load_hardware()
    smap = ServoMap.from_config(cfg.hardware, cfg.robot.leg.tendon_max_deg)
    tendon = log["/tendon"][[f"command_deg.{i}" for i in range(4)]].to_numpy(float)
    expected = np.rint((130.0 + np.clip(tendon, 0, 116.28)) * 4096 / 360)
    assert np.array_equal(goal_ticks(log), np.clip(expected, smap.min_ticks, smap.max_ticks))
    assert final_goal == goal_ticks(log)[-1].astype(int).tolist()
    assert not log["/servos"][[f"clamped.{i}" for i in range(4)]].to_numpy().any()
    # torque on for the run, watchdog armed (100 ms = 5 units), both cleared at the end
    assert all(turned_off_after_on(h) for h in torque_history.values()), torque_history
    assert torque == {1: 0, 2: 0, 3: 0, 4: 0} and watchdog == {1: 0, 2: 0, 3: 0, 4: 0}
    assert any("position limits set" in n for n in notes)
    loop = log.metadata["loop"]
    assert float(loop["achieved_rate_hz"]) == pytest.approx(30, rel=0.05)  # deadlines, not fixed sleeps
    assert float(loop["overruns"]) <= 6  # a loaded 2-core CI box may overrun now and then
    assert log.metadata["summary"]["stop_reason"] == "duration"


def test_commands_beyond_the_servo_limits_are_clamped_and_logged(tmp_path: Path) -> None:
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        result, notes = run_on_emulator(emu, pub, tmp_path, "duration=1", "robot.servo.horn_max_deg=[200,200,255,255]")
        sent = {
            i: [int.from_bytes(w.data, "little") for w in emu.goal_writes(i) if w.instruction == "sync_write"]
            for i in (1, 2, 3, 4)
        }
        limits = [emu.register(i, "max_position_limit") for i in (1, 2, 3, 4)]
    assert result.exit_code == 0, result.message
    cap = round(200 * 4096 / 360)
    assert limits == [cap, cap, round(255 * 4096 / 360), round(255 * 4096 / 360)]  # also written to EEPROM
    assert max(sent[1]) == cap and max(sent[2]) == cap and max(sent[3]) > cap
    log = read_log(result.log_path)
    clamped = log["/servos"][[f"clamped.{i}" for i in range(4)]].to_numpy(bool)
    assert clamped[:, :2].all() and not clamped[:, 2:].any()
    assert log.metadata["summary"]["clamped_cycles"] == f"{len(clamped)},{len(clamped)},0,0"
    assert any("FL command clamped" in n for n in notes)


def test_stale_odometry_stops_the_loop_with_torque_off(tmp_path: Path) -> None:
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        waiter = _when_running(emu, pub.silence, delay=0.4)  # the estimator dies once the loop runs
        result, _ = run_on_emulator(emu, pub, tmp_path, "duration=5", "odometry.max_age_s=0.15")
        waiter.join()
        torque = emu.torque()
    assert result.exit_code == EXIT_SAFETY_STOP
    assert result.outcome.stop_reason == "stale odometry"
    assert "odometry is" in result.message and "odometry.max_age_s" in result.message
    assert torque == {1: 0, 2: 0, 3: 0, 4: 0}
    log = read_log(result.log_path)
    assert not log.truncated and 5 < len(log["/state"]) < 40
    assert log.metadata["summary"]["stop_reason"] == "stale odometry"


def test_corrupted_and_missing_replies_are_retried(tmp_path: Path) -> None:
    with ServoEmulator() as emu, OdometryPublisher() as pub:

        def spoil() -> None:
            emu.inject("corrupt", 1, instruction=INST_SYNC_READ)
            emu.inject("drop", 2, servo_id=3, instruction=INST_SYNC_READ)
            emu.inject("garbage", 1, instruction=INST_SYNC_READ)
            emu.inject("truncate", 1, servo_id=2, instruction=INST_SYNC_READ)

        waiter = _when_running(emu, spoil)
        result, _ = run_on_emulator(emu, pub, tmp_path, "duration=1.5")
        waiter.join()
        spoiled = emu.replies_faulted
    assert result.exit_code == 0, result.message
    assert spoiled == 5
    assert 2 <= result.outcome.comm_retries <= 5  # a retry per spoiled sync read (several faults can share one)
    log = read_log(result.log_path)
    assert log["/servos"]["comm_retries"].sum() == result.outcome.comm_retries
    assert len(log["/state"]) == 45


def test_persistent_bus_failure_stops_cleanly(tmp_path: Path) -> None:
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        waiter = _when_running(emu, lambda: emu.inject("drop", 10, servo_id=2, instruction=INST_SYNC_READ))
        result, _ = run_on_emulator(emu, pub, tmp_path, "duration=3", "hardware.comm_retries=2")
        waiter.join()
        torque = emu.torque()
    assert result.exit_code == EXIT_SAFETY_STOP
    assert result.outcome.stop_reason == "bus"
    assert "failed 3 times in a row" in result.message and "torque off" in result.message
    assert torque == {1: 0, 2: 0, 3: 0, 4: 0}  # replies to the torque-off writes still arrive
    assert not read_log(result.log_path).truncated


def _when_running(emu: ServoEmulator, action, timeout: float = 20.0, delay: float = 0.1) -> threading.Thread:
    """Run ``action`` once every servo's torque is on (the loop is past start-up), not at a fixed
    time: start-up (pings, checks, the MPC's warm-up solve) takes a machine-dependent while."""

    def wait_then_act() -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(v == 1 for v in emu.torque().values()):
                time.sleep(delay)
                action()
                return
            time.sleep(0.01)

    thread = threading.Thread(target=wait_then_act, daemon=True)
    thread.start()
    return thread


def test_a_servo_hardware_error_stops_the_run(tmp_path: Path) -> None:
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        waiter = _when_running(emu, lambda: emu.set_hardware_error(3, 0x20))
        result, _ = run_on_emulator(emu, pub, tmp_path, "duration=3", "hardware.error_check_every=3")
        waiter.join()
        torque = emu.torque()
    assert result.exit_code == EXIT_SAFETY_STOP
    assert result.outcome.stop_reason == "hardware error"
    assert "servo 3 (RR)" in result.message and "overload" in result.message
    assert torque == {1: 0, 2: 0, 3: 0, 4: 0}


def test_hil_runs_the_same_loop_on_the_simulator_and_replay_feeds_it_back(tmp_path: Path) -> None:
    hil = tmp_path / "hil"
    result = run_hardware(load_hardware("odometry=sim", "duration=1", "robot.servo.profile_velocity_rpm=40"), hil, "{}")
    assert result.exit_code == 0, result.message
    log = read_log(result.log_path)
    assert log.metadata["run"]["bus"] == "simulated" and log.metadata["run"]["plant"] == "ideal"
    z = log["/state"]["p.2"].to_numpy()
    assert np.ptp(z) > 1e-4  # the plant moved under the servo-made normal forces
    present = log["/servos"][[f"present_position.{i}" for i in range(4)]].to_numpy()
    goal = goal_ticks(log)
    assert np.ptp(present, axis=0).max() > 10 and np.ptp(goal, axis=0).max() > 10  # commanded, and moved
    # ... at no more than the profile velocity (40 rpm = 2731 ticks/s) between two reads (cycle starts)
    loop = log["/loop"]
    read_at = loop["t"].to_numpy() + loop["lateness_s"].to_numpy()
    assert np.all(np.abs(np.diff(present, axis=0)) <= 40 / 60 * 4096 * np.diff(read_at)[:, None] + 2)
    # replay that run's states as odometry into the emulated servos; the run ends with the log
    with ServoEmulator() as emu:
        replay, _ = run_on_emulator(
            emu, None, tmp_path / "replay", "odometry=replay", f"odometry.path={hil}", "duration=5"
        )
    assert replay.exit_code == 0, replay.message
    assert replay.outcome.stop_reason == "replay finished"
    states = read_log(replay.log_path)["/state"]
    assert 10 <= len(states) <= 31  # the replay clock starts before the controller's warm-up
    replayed = states["p.2"].to_numpy()
    assert np.abs(replayed[:, None] - z[None, :]).min(axis=1).max() < 1e-12  # exactly the logged states


@pytest.mark.parametrize(
    "setup, words",
    [
        ({"ids": [1, 2, 3]}, ["servo ID 4 (FR)", "does not answer ping", "hardware.ids"]),
        ({"models": {2: 1020}}, ["servo ID 2 (RL)", "model number 1020", "1060"]),
        ({"error": (3, 0x04)}, ["servo ID 3 (RR)", "hardware error 0x04 (overheating)"]),
        ({"no_odometry": True}, ["no odometry from tcp://127.0.0.1:1 within 0.3 s", "startup_timeout_s"]),
    ],
)
def test_start_up_problems_are_user_errors_before_any_write(setup: dict, words: list[str], tmp_path: Path) -> None:
    with ServoEmulator(setup.get("ids", [1, 2, 3, 4]), models=setup.get("models")) as emu:
        if "error" in setup:
            emu.set_hardware_error(*setup["error"])
        with pytest.raises(UserError) as err:
            run_hardware(
                load_hardware(
                    f"hardware.port={emu.port}",
                    "hardware.comm_retries=0",
                    "odometry.startup_timeout_s=0.3",
                    "odometry.endpoint=tcp://127.0.0.1:1",
                ),
                tmp_path,
                "{}",
            )
        writes = list(emu.writes)
    text = str(err.value)
    assert "\n" not in text
    for w in words:
        assert w in text, text
    assert writes == []  # nothing is written to a servo until the bus and the odometry both check out
    assert not (tmp_path / "logs").exists()


def test_a_busy_live_port_leaves_the_robot_running_with_a_warning(tmp_path: Path) -> None:
    from slotexp.live import LiveView

    with LiveView(port=0) as busy, ServoEmulator() as emu, OdometryPublisher() as pub:
        port = busy.port
        result, notes = run_on_emulator(emu, pub, tmp_path, "duration=0.5", f"live_port={port}")
    assert result.exit_code == 0, result.message
    (warning,) = [n for n in notes if n.startswith("warning: live view")]
    assert f"cannot listen on 127.0.0.1:{port}" in warning and "live=false" in warning
    assert len(read_log(result.log_path)["/state"]) == 15  # the run went on: 0.5 s at 30 Hz


def test_the_stop_flag_takes_every_stop_signal_and_nothing_cuts_the_shutdown_short() -> None:
    """The first signal asks for a stop; a second raises (a loop stuck in a solve); once the torque-off path has
    begun, further signals are only noted; the handlers are put back afterwards; nohup's ignored SIGHUP stays."""
    import signal

    from slotexp.signals import STOP_SIGNALS, StopFlag

    inherited = signal.signal(signal.SIGHUP, signal.SIG_DFL)  # as from a terminal, even if the tests run under nohup
    before = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    stop = StopFlag()
    with stop.installed():
        signal.raise_signal(signal.SIGHUP)
        assert stop.requested and stop.name == "SIGHUP"
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGTERM)
        stop.shutting_down()
        signal.raise_signal(signal.SIGINT)  # a second Ctrl-C during torque off: noted, not raised
        signal.raise_signal(signal.SIGTERM)
        assert stop.name == "SIGHUP"
    assert {s: signal.getsignal(s) for s in STOP_SIGNALS} == before
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with StopFlag().installed() as ignoring:
            signal.raise_signal(signal.SIGHUP)
            assert not ignoring.requested and signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)
        signal.signal(signal.SIGHUP, inherited)
