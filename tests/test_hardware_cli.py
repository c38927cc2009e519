"""`slot hardware` as a user runs it: a subprocess against the servo emulator (pty) and a ZeroMQ publisher.

Covers what only a separate process can show: Ctrl-C, SIGTERM and a closed terminal
(SIGHUP) turn every servo's torque off with the watchdog off, a second run on the same
port is refused, a killed process is stopped by the servos' bus watchdog, a dry run writes nothing,
bad input is one line and exit 2, and the hardware log works with `slot figures`
and `slot run experiment=validate`.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from slotexp.record import read_log
from tests.helpers import (
    SLOT_CMD,
    as_from_a_terminal,
    assert_one_line_error,
    assert_png,
    last_line,
    ok,
    run_on_emulator,
    slot,
    turned_off_after_on,
)
from tests.servo_emulator import OdometryPublisher, ServoEmulator


def start(emu: ServoEmulator, pub: OdometryPublisher, run_dir: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [
            *SLOT_CMD,
            "hardware",
            f"hardware.port={emu.port}",
            f"odometry.endpoint={pub.endpoint}",
            f"hydra.run.dir={run_dir}",
            *extra,
        ],
        cwd=run_dir.parent,
        env=dict(os.environ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=as_from_a_terminal,
    )


def wait_for_torque(emu: ServoEmulator, proc: subprocess.Popen, timeout: float = 40) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if all(emu.torque().values()) and len(emu.goal_writes()) >= 4 * 6:  # torque on, a few cycles run
            return
        time.sleep(0.02)
    proc.kill()
    raise AssertionError(f"the loop never started:\n{proc.communicate()[1]}")


def _stop_with(proc: subprocess.Popen, signum: int, timeout: float = 30) -> tuple[str, str]:
    try:
        os.killpg(proc.pid, signum)
        return proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_signal_turns_the_torque_off_without_the_watchdog(signum: int, tmp_path: Path) -> None:
    """Ctrl-C (what a terminal sends the foreground group) and SIGTERM (a service manager, a timeout) with the
    bus watchdog off: the run itself turns every servo off, closes its log and exits 128 + n."""
    run_dir = tmp_path / "run"
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        proc = start(emu, pub, run_dir, "hardware.watchdog_ms=0")
        wait_for_torque(emu, proc)
        stdout, stderr = _stop_with(proc, signum)
        time.sleep(0.05)
        torque = emu.torque()
        history = emu.torque_writes()
        trips = [s.watchdog_trips for s in emu.servos.values()]
    name = signal.Signals(signum).name
    assert proc.returncode == 128 + signum, stderr
    assert "Traceback" not in stderr and f"interrupted ({name})" in stderr
    assert last_line(stdout) == str(run_dir)
    assert torque == {1: 0, 2: 0, 3: 0, 4: 0} and trips == [0, 0, 0, 0]
    assert all(turned_off_after_on(h) for h in history.values()), history
    log = read_log(run_dir / "logs" / "hardware.mcap")
    assert not log.truncated and len(log["/state"]) >= 5
    assert log.metadata["summary"]["stop_reason"] == name
    assert (run_dir / "fig4_com.png").is_file()


def test_a_closed_terminal_turns_the_torque_off_without_the_watchdog(tmp_path: Path) -> None:
    """A closed terminal or a dropped SSH connection: the terminal's output goes away (writes fail with EIO)
    and the session gets SIGHUP. With the watchdog off, the run turns every servo off itself, closes its log
    and exits 129, although it can no longer print anything."""
    import pty

    run_dir = tmp_path / "run"
    master, slave = pty.openpty()
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        proc = subprocess.Popen(
            [
                *SLOT_CMD,
                "hardware",
                f"hardware.port={emu.port}",
                f"odometry.endpoint={pub.endpoint}",
                f"hydra.run.dir={run_dir}",
                "hardware.watchdog_ms=0",
            ],
            cwd=tmp_path,
            stdin=slave,
            stdout=slave,
            stderr=slave,
            start_new_session=True,
            preexec_fn=as_from_a_terminal,
        )
        os.close(slave)
        drained = threading.Thread(target=_drain, args=(master,), daemon=True)
        drained.start()
        try:
            wait_for_torque(emu, proc)
        finally:
            os.close(master)  # the terminal goes away ...
        _stop_with(proc, signal.SIGHUP)  # ... and its session is told
        time.sleep(0.05)
        torque = emu.torque()
        history = emu.torque_writes()
        trips = [s.watchdog_trips for s in emu.servos.values()]
    assert proc.returncode == 129
    assert torque == {1: 0, 2: 0, 3: 0, 4: 0} and trips == [0, 0, 0, 0]
    assert all(turned_off_after_on(h) for h in history.values()), history
    log = read_log(run_dir / "logs" / "hardware.mcap")
    assert not log.truncated and len(log["/state"]) >= 5
    assert log.metadata["summary"]["stop_reason"] == "SIGHUP"


def _drain(fd: int) -> None:
    """Read a pty's output until it closes (a terminal that keeps up)."""
    try:
        while os.read(fd, 4096):
            pass
    except OSError:
        pass


def test_a_second_run_on_the_same_port_is_refused(tmp_path: Path) -> None:
    """Two runs on one bus would interleave packets: the second is refused in one line, before it touches the
    port, and the first goes on undisturbed (no communication error, torque still on, stops cleanly)."""
    first_dir = tmp_path / "first"
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        first = start(emu, pub, first_dir, "hardware.watchdog_ms=0")
        try:
            wait_for_torque(emu, first)
            for extra in ([], ["--dry-run"]):
                second = slot(
                    "hardware",
                    *extra,
                    f"hardware.port={emu.port}",
                    f"odometry.endpoint={pub.endpoint}",
                    f"hydra.run.dir={tmp_path / ('second' + '_'.join(extra))}",
                    cwd=tmp_path,
                )
                line = assert_one_line_error(second, emu.port, "in use by another process", f"PID {first.pid}")
                assert "slot hardware" in line
            assert first.poll() is None and all(emu.torque().values())
            writes_before = len(emu.goal_writes())
            time.sleep(0.5)
            assert len(emu.goal_writes()) > writes_before  # still driving the servos
        finally:
            _stop_with(first, signal.SIGINT)
        torque = emu.torque()
        crc_errors = emu.crc_errors
    assert first.returncode == 130
    assert torque == {1: 0, 2: 0, 3: 0, 4: 0}
    # nothing foreign reached the bus: a second writer's packets would interleave with the first's and fail
    # their CRC at the servos. The first run's own transactions: a 2-core machine starting two Python processes
    # beside the 30 Hz loop and the emulator's thread has delayed one reply past its timeout (1 retry, twice in
    # about ten full runs); a second run on the port fails many
    assert crc_errors == 0
    summary = read_log(first_dir / "logs" / "hardware.mcap").metadata["summary"]
    assert int(summary["comm_errors"]) <= 1 and int(summary["comm_retries"]) <= 1


def test_a_killed_process_is_stopped_by_the_bus_watchdog(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        proc = start(emu, pub, run_dir)
        try:
            wait_for_torque(emu, proc)
            os.killpg(proc.pid, signal.SIGKILL)  # no chance to turn anything off
            proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        deadline = time.monotonic() + 10  # watchdog: 100 ms; a loaded machine runs the emulator's clock late
        while time.monotonic() < deadline and any(s.watchdog_trips == 0 for s in emu.servos.values()):
            time.sleep(0.05)
        time.sleep(0.3)  # and no second trip
        trips = [s.watchdog_trips for s in emu.servos.values()]
        flags = [emu.register(i, "bus_watchdog") for i in (1, 2, 3, 4)]
        torque = emu.torque()
    assert trips == [1, 1, 1, 1] and flags == [-1, -1, -1, -1]
    assert torque == {1: 0, 2: 0, 3: 0, 4: 0}


@pytest.fixture(scope="module")
def dry_run(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess, ServoEmulator]:
    run_dir = tmp_path_factory.mktemp("dry") / "run"
    with ServoEmulator() as emu, OdometryPublisher() as pub:
        proc = slot(
            "hardware",
            "--dry-run",
            f"hardware.port={emu.port}",
            f"odometry.endpoint={pub.endpoint}",
            "duration=1",
            f"hydra.run.dir={run_dir}",
            cwd=run_dir.parent,
        )
    return run_dir, proc, emu


def test_dry_run_writes_nothing_to_the_servos(dry_run) -> None:
    run_dir, proc, emu = dry_run
    ok(proc)
    assert last_line(proc.stdout) == str(run_dir)
    assert emu.writes == []  # not a single register write reached any servo, Goal Position included
    assert all(s.torque_history == [] for s in emu.servos.values())
    assert emu.torque() == {1: 0, 2: 0, 3: 0, 4: 0}
    assert "a live run writes" in proc.stderr  # it says what a live run would change
    log = read_log(run_dir / "logs" / "hardware.mcap")
    servos = log["/servos"]
    assert len(servos) == 30 and not servos["sent"].any()
    goals = servos[[f"goal.{i}" for i in range(4)]].to_numpy(float)
    assert np.all((goals > 1479) & (goals <= 2844))  # what it would have sent, logged
    assert log.metadata["run"]["dry_run"] == "true"


def test_slot_figures_and_validate_work_on_a_hardware_log(dry_run, tmp_path: Path) -> None:
    run_dir, _proc, _emu = dry_run
    for f in ("fig4_com.png", "fig6_path.png", "metrics.json"):
        (run_dir / f).unlink()
    out = ok(slot("figures", run_dir, cwd=tmp_path))
    assert last_line(out.stdout) == str(run_dir)
    assert_png(run_dir / "fig4_com.png")
    assert_png(run_dir / "fig6_path.png")
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["loop"]["cycles"] == 30 and metrics["stop_reason"] == "duration"
    val = tmp_path / "val"
    ok(
        slot(
            "run",
            "experiment=validate",
            f"experiment.reference={run_dir}",
            f"experiment.candidate={run_dir}",
            f"hydra.run.dir={val}",
            cwd=tmp_path,
        )
    )
    rows = json.loads((val / "metrics.json").read_text())["rows"]
    assert rows and all(r["rmse_m"] == 0 for r in rows)


def test_missing_serial_port_is_one_line_and_leaves_no_run_directory(tmp_path: Path) -> None:
    # a run that fails before its loop writes no log, so it leaves no directory; one that existed stays
    made, kept = tmp_path / "r", tmp_path / "kept"
    kept.mkdir()
    for run_dir in (made, kept):
        args = ("hardware", "--dry-run", "hardware.port=/dev/no-such-u2d2", f"hydra.run.dir={run_dir}")
        assert_one_line_error(slot(*args, cwd=tmp_path), "/dev/no-such-u2d2")
    assert not made.exists()
    assert kept.is_dir()


def test_a_servo_that_does_not_answer_is_one_line(tmp_path: Path) -> None:
    with ServoEmulator([1, 2, 3]) as emu:
        proc = slot(
            "hardware",
            f"hardware.port={emu.port}",
            "hardware.comm_retries=0",
            f"hydra.run.dir={tmp_path / 'r'}",
            cwd=tmp_path,
        )
        writes = list(emu.writes)
    assert_one_line_error(proc, "servo ID 4 (FR)", "does not answer ping")
    assert writes == []  # checks first: nothing was written to the servos that did answer


@pytest.mark.parametrize(
    "args, words",
    [
        (["hardware.watchdog_ms=90"], ["hardware.watchdog_ms", "20"]),
        (["odometry=vicon"], ["unknown odometry 'vicon'", "replay, sim, zmq"]),
        (["-m", "duration=1,2"], ["multirun"]),
    ],
)
def test_bad_arguments_are_one_line(args: list[str], words: list[str], tmp_path: Path) -> None:
    assert_one_line_error(slot("hardware", *args, cwd=tmp_path), *words)


def test_sigterm_stops_like_ctrl_c(tmp_path: Path) -> None:
    """In process (a service manager's SIGTERM): exit 143, torque off, log closed."""

    def stop_once_handled() -> None:
        # as a service manager would, but only once the loop has its handler in place (a loaded machine can take
        # longer than any fixed delay to get there; the default action would end the test runner itself)
        deadline = time.monotonic() + 60
        while signal.getsignal(signal.SIGTERM) is signal.SIG_DFL and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # a few control cycles
        os.kill(os.getpid(), signal.SIGTERM)

    with ServoEmulator() as emu, OdometryPublisher() as pub:
        timer = threading.Thread(target=stop_once_handled, daemon=True)
        timer.start()
        result, _ = run_on_emulator(emu, pub, tmp_path, "duration=10")
        timer.join()
        torque = emu.torque()
    assert result.exit_code == 143 and "SIGTERM" in result.message
    assert torque == {1: 0, 2: 0, 3: 0, 4: 0}
    assert read_log(result.log_path).metadata["summary"]["stop_reason"] == "SIGTERM"
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # handlers restored after the run
