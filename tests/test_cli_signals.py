"""End-to-end tests of the ``slot`` command line that stop it: Ctrl-C and the other stop signals, sweeps and
their workers, a controller that never succeeds, and outputs that cannot be written (run as a subprocess like a
user would; kept apart from ``test_cli.py`` so the two share the test workers evenly)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from slotexp.record import is_closed, read_log
from slotexp.signals import child_processes
from tests.helpers import (
    SLOT_CMD,
    as_from_a_terminal,
    assert_one_line_error,
    last_line,
    ok,
    slot,
)

# --------------------------------------------------------------------------- 5. Ctrl-C


def test_ctrl_c_exits_130_and_leaves_a_closed_log(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    log_path = run_dir / "logs" / "baseline.mcap"
    proc = subprocess.Popen(
        [
            *SLOT_CMD,
            "run",
            "experiment=perturb",
            "experiment.scenarios=[baseline]",
            "experiment.duration=600",  # a loaded machine cannot finish it before the signal
            "experiment.n_jobs=1",
            f"hydra.run.dir={run_dir}",
        ],
        cwd=tmp_path,
        env=dict(os.environ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        # as from a terminal: a test run started in the background (`make test &`, CI runners) ignores
        # SIGINT, and an ignored SIGINT is inherited, so the run would rightly never see the Ctrl-C
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 180  # a clean checkout compiles its kernels first
        while time.monotonic() < deadline and proc.poll() is None:
            if log_path.exists() and log_path.stat().st_size > 100_000:
                break
            time.sleep(0.1)
        assert proc.poll() is None, f"run ended before it could be interrupted:\n{proc.stderr.read()}"
        assert log_path.exists(), "no log appeared within 180 s"
        os.killpg(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)  # generous: a loaded machine shuts down slowly
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 130, f"exit {proc.returncode}\nstderr:\n{stderr}"
    assert "Traceback" not in stderr, stderr
    assert "interrupted" in stderr
    assert last_line(stdout) == str(run_dir)

    log = read_log(log_path)
    assert log.truncated is False, "the interrupted run's log was not closed properly"
    t = log["/state"]["t"].to_numpy()
    assert 0 < len(t) < 600 * 30, "the run was not actually interrupted part-way"
    assert np.all(np.diff(t) > 0)
    assert "config" in log.metadata and "run" in log.metadata
    assert "summary" not in log.metadata  # only written when the run completes


# --------------------------------------------------------------------------- 7. multirun


def test_multirun_sweeps_solvers_with_joblib(tmp_path: Path) -> None:
    sweep_dir = tmp_path / "sweep"
    proc = ok(
        slot(
            "run",
            "-m",
            "experiment=simulate",
            "experiment.duration=0.5",
            "solver=clarabel,scs",
            f"hydra.sweep.dir={sweep_dir}",
            cwd=tmp_path,
        )
    )
    jobs = sorted(p for p in sweep_dir.iterdir() if p.is_dir())
    assert [p.name.split("_", 1)[0] for p in jobs] == ["0", "1"]
    printed = {ln.strip() for ln in proc.stdout.splitlines()}
    for job, solver in zip(jobs, ["clarabel", "scs"]):
        assert job.name.endswith(f"solver={solver}")
        assert str(job) in printed, f"{job} not printed on stdout"
        metrics = json.loads((job / "metrics.json").read_text())
        assert metrics["gait"] == "walk"
        assert metrics["infeasible_steps"] == 0
        log = read_log(job / "logs" / "walk.mcap")
        assert not log.truncated
        assert log.metadata["run"]["solver"] == solver
        assert yaml.safe_load(log.metadata["config"]["yaml"])["solver"]["name"] == solver
    # a second sweep into the same directory would mix its jobs with these: refused, then replaced on request
    again = [
        "run",
        "-m",
        "experiment=simulate",
        "experiment.duration=0.5",
        "solver=daqp",
        f"hydra.sweep.dir={sweep_dir}",
    ]
    before = (jobs[1] / "logs" / "walk.mcap").read_bytes()
    assert_one_line_error(slot(*again, cwd=tmp_path), str(sweep_dir), "overwrite=true")
    assert (jobs[1] / "logs" / "walk.mcap").read_bytes() == before
    ok(slot(*again, "overwrite=true", cwd=tmp_path))
    (job,) = [p for p in sweep_dir.iterdir() if p.is_dir()]  # job 1 of the earlier sweep is gone, not mixed in
    assert job.name.endswith("solver=daqp")


# --------------------------------------------------------------------------- a controller that never works


@pytest.mark.parametrize(
    "overrides",
    [["mpc.f_max=0.1"], ["solver.time_limit_s=1e-9"]],
    ids=["f_max below the weight", "no time to solve"],
)
def test_a_run_whose_mpc_never_succeeds_fails_with_one_line_and_a_readable_log(
    tmp_path: Path, overrides: list[str]
) -> None:
    run_dir = tmp_path / "run"
    proc = slot(
        "run", "experiment=simulate", "experiment.duration=1", *overrides, f"hydra.run.dir={run_dir}", cwd=tmp_path
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("error: ")]
    assert len(errors) == 1 and "no feasible plan in any of the 30 steps" in errors[0], proc.stderr
    assert proc.stderr.rstrip().splitlines()[-1] == errors[0]  # the progress bar before it, nothing after
    log = run_dir / "logs" / "walk.mcap"
    stats = read_log(log).topics["/mpc/stats"]
    assert len(stats) == 30 and not stats["success"].astype(bool).any()
    with log.open("rb") as fh:
        assert sum(1 for _ in make_reader(fh).iter_messages()) > 0
    forces = read_log(log).topics["/forces"]
    if overrides == ["mpc.f_max=0.1"]:  # the fallback before any success respects the force limit
        assert forces[[f"applied.{i}.2" for i in range(4)]].to_numpy().max() <= 0.1 + 1e-12


@pytest.mark.parametrize("where", ["a file", "/proc", "empty"])
def test_an_output_directory_that_cannot_be_written_is_refused_before_any_work(tmp_path: Path, where: str) -> None:
    target = {"a file": tmp_path / "file", "/proc": Path("/proc/slot-run"), "empty": ""}[where]
    if where == "a file":
        target.write_text("not a directory")
    proc = slot("run", "experiment=simulate", "experiment.duration=0.1", f"hydra.run.dir={target}", cwd=tmp_path)
    assert_one_line_error(proc, "hydra.run.dir")
    assert not (tmp_path / "logs").exists() and not (tmp_path / ".hydra").exists()  # nothing written here
    if where != "empty":  # bench checks its --out before measuring, not after
        bench = slot("bench", "mpc", "--out", str(target), cwd=tmp_path, timeout=60)
        assert_one_line_error(bench, "--out")


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _spawn(args: list[str], cwd: Path) -> subprocess.Popen:
    """``slot`` in its own session, as from a terminal (:func:`tests.helpers.as_from_a_terminal`)."""
    return subprocess.Popen(
        args,
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=as_from_a_terminal,
    )


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=["SIGTERM", "SIGINT", "SIGHUP"])
def test_a_stop_signal_to_the_parent_alone_stops_every_worker_and_closes_every_log(tmp_path: Path, signum) -> None:
    # as timeout, SLURM and systemd send it, to the parent's PID only, with two scenarios running in a pool
    # of two and a third queued behind them
    run_dir = tmp_path / "run"
    proc = _spawn(
        [
            *SLOT_CMD,
            "run",
            "experiment=perturb",
            "experiment.scenarios=[baseline,roll,pitch]",
            "experiment.duration=600",
            "experiment.n_jobs=2",
            f"hydra.run.dir={run_dir}",
        ],
        tmp_path,
    )
    logs = [run_dir / "logs" / f"{name}.mcap" for name in ("baseline", "roll")]
    stdout, _ = _stop_parent_once_logging(proc, logs, signum)
    assert last_line(stdout) == str(run_dir)
    assert not (run_dir / "logs" / "pitch.mcap").exists()  # queued, never started


def test_slot_bench_stopped_by_sigterm_exits_143_with_one_line(tmp_path: Path) -> None:
    # Typer turned every stop outside a Hydra job into a silent exit 130 (a SIGTERM from a timeout or SLURM
    # read as a Ctrl-C); slot bench, figures, layout and summarize now end as slot run does
    proc = _spawn([*SLOT_CMD, "bench", "leg", "--out", str(tmp_path / "bench")], tmp_path)
    try:
        time.sleep(10.0)  # started and measuring (the leg bench runs for minutes)
        assert proc.poll() is None, proc.stderr.read()
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert stderr.strip().splitlines()[-1] == "terminated", stderr
    assert "Traceback" not in stderr


@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGTERM, signal.SIGINT])
def test_a_command_outside_a_hydra_job_ends_on_each_stop_signal_with_its_code(capsys, monkeypatch, signum) -> None:
    import slotexp.cli
    from slotexp.cli import _stoppable, _terminate

    monkeypatch.setattr(slotexp.cli, "_received", [])  # this process's signals so far: none

    @_stoppable
    def command() -> None:
        signal.raise_signal(signum)

    previous = signal.signal(signum, _terminate if signum != signal.SIGINT else signal.default_int_handler)
    try:
        with pytest.raises(SystemExit) as stopped:
            command()
    finally:
        signal.signal(signum, previous)
    assert stopped.value.code == 128 + signum
    word = {signal.SIGTERM: "terminated", signal.SIGHUP: "hung up"}.get(signum, "interrupted")
    assert capsys.readouterr().err.strip() == word


def _stop_parent_once_logging(proc: subprocess.Popen, logs: list[Path], signum: int) -> tuple[str, str]:
    """Send ``signum`` to ``proc``'s PID alone once every log has data; check the exit, the one line on
    stderr, that no worker outlives it and that every log reads completely. Returns (stdout, stderr)."""
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and proc.poll() is None:
            if all(p.exists() and p.stat().st_size > 100_000 for p in logs):
                break
            time.sleep(0.1)
        assert proc.poll() is None, proc.stderr.read()
        workers = child_processes(proc.pid)
        os.kill(proc.pid, signum)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 128 + signum, stderr
    assert "Traceback" not in stderr, stderr
    word = {signal.SIGTERM: "terminated", signal.SIGHUP: "hung up"}.get(signum, "interrupted")
    assert [ln for ln in stderr.splitlines() if ln.startswith(word)], stderr
    time.sleep(1.0)
    assert not [pid for pid in workers if _alive(pid) and "resource_tracker" not in _cmdline(pid)], (
        "a worker outlived its parent"
    )
    for path in logs:
        log = read_log(path)
        assert log.truncated is False and 0 < len(log["/state"]) < 600 * 30
        with path.open("rb") as fh:
            assert sum(1 for _ in make_reader(fh).iter_messages()) > 0
    return stdout, stderr


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")
    except OSError:
        return ""


def _spawn_sweep(sweep: Path, gaits: str) -> subprocess.Popen:
    """A long two-at-a-time sweep of simulate over ``gaits`` (comma-separated), writing into ``sweep``."""
    args = ["run", "-m", "experiment=simulate", f"gait={gaits}", "experiment.duration=600", "hydra.launcher.n_jobs=2"]
    return _spawn([*SLOT_CMD, *args, f"hydra.sweep.dir={sweep}"], sweep.parent)


def test_a_stop_signal_to_a_sweeps_parent_closes_every_running_jobs_log_and_starts_no_other(tmp_path: Path) -> None:
    # slot run -m: the joblib launcher ends its workers with SIGKILL when the parent stops; the parent first
    # passes the signal on and waits for each job to close its log (slotexp/signals.py)
    sweep = tmp_path / "sweep"
    proc = _spawn_sweep(sweep, "walk,crawl,omni60")
    logs: list[Path] = []
    deadline = time.monotonic() + 120  # until the two running jobs have opened their logs
    while time.monotonic() < deadline and len(logs) < 2:
        logs = sorted(sweep.glob("*/logs/*.mcap"))
        time.sleep(0.1)
    _stop_parent_once_logging(proc, logs, signal.SIGTERM)
    assert not list(sweep.glob("2_*")), "a job queued behind the running two was started"


def test_a_sweeps_jobs_end_when_its_parent_is_killed(tmp_path: Path) -> None:
    # SIGKILL leaves the parent no handler to pass anything on: the kernel tells each job (prctl's parent-death
    # signal, SIGTERM), which stops at its next MPC step with its log closed
    sweep = tmp_path / "sweep"
    proc = _spawn_sweep(sweep, "walk,crawl")
    try:
        deadline = time.monotonic() + 180  # until both jobs are logging (a clean checkout compiles first)
        logs: list[Path] = []
        while time.monotonic() < deadline and not (len(logs) == 2 and all(p.stat().st_size > 100_000 for p in logs)):
            logs = sorted(sweep.glob("*/logs/*.mcap"))
            time.sleep(0.1)
        assert proc.poll() is None, proc.stderr.read()
        jobs = [pid for pid in child_processes(proc.pid) if "resource_tracker" not in _cmdline(pid)]
        assert jobs
        assert len(logs) == 2, "the jobs' logs did not appear within 180 s"
        os.kill(proc.pid, signal.SIGKILL)
        _, stderr = proc.communicate(timeout=60)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(_alive(pid) for pid in jobs):
            time.sleep(0.1)
        assert not [pid for pid in jobs if _alive(pid)], "a job outlived its sweep's parent"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    for log in logs:
        assert is_closed(log), f"{log} was cut short; stderr:\n{stderr}"
