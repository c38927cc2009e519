"""Run scenarios to MCAP logs, in parallel processes, with one progress bar."""

from __future__ import annotations

import contextlib
import ctypes
import datetime as _dt
import multiprocessing as mp
import os
import queue
import signal
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from .. import __version__
from ..config import ScenarioConfig, SlotConfig
from ..errors import Interrupted
from ..parallel import n_workers
from ..record import Recorder
from ..signals import STOP_SIGNALS, interrupts_between_steps
from ..simulation import RunSummary, run_closed_loop
from ..telemetry import Tee

PR_SET_PDEATHSIG = 1  # prctl(2): the signal a process gets when its parent dies


def git_commit() -> str:
    """The commit the code runs from, with ``-dirty`` if the tree has changes."""
    root = Path(__file__).resolve().parents[2]
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def open_live(cfg: SlotConfig) -> contextlib.AbstractContextManager[Any]:
    """The live view ``cfg.live`` asks for (a started server, announced on stderr), or a no-op context."""
    from ..live import open_view

    return open_view(
        cfg.live,
        cfg.live_port,
        lambda line: print(line, file=sys.stderr),
        pace=cfg.live_pace,
        wait_s=cfg.live_wait_s,
        linger_s=cfg.live_linger_s,
    )


def run_logged(
    cfg: SlotConfig,
    scenario: ScenarioConfig,
    duration: float,
    log_path: Path,
    resolved_yaml: str,
    commit: str,
    progress=None,
    live: Any = None,
) -> RunSummary:
    """One closed-loop run streamed to ``log_path``; the log is closed validly even on Ctrl-C.

    ``live`` is a running :class:`slotexp.live.LiveView` to stream to as well; without one,
    ``cfg.live`` starts one for this run.
    """
    if live is None and cfg.live:
        with open_live(cfg) as view:
            return run_logged(cfg, scenario, duration, log_path, resolved_yaml, commit, progress, view)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "config": {"yaml": resolved_yaml},
        "run": {
            "experiment": cfg.experiment.name,
            "scenario": scenario.name,
            "gait": cfg.gait.name,
            "plant": cfg.plant.name,
            "solver": cfg.solver.name,
            "git_commit": commit,
            "slotexp_version": __version__,
            "duration_s": repr(duration),
            "started_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        },
    }
    # opened before the log: a stop signal while the run sets up (kernels compiling) closes the log too
    with interrupts_between_steps(), Recorder(log_path, metadata=meta) as rec:
        sink = rec if live is None else Tee(rec, live)
        summary = run_closed_loop(cfg, scenario, duration, sink, progress)
        rec.add_metadata(
            "summary",
            {
                "steps": str(summary.steps),
                "infeasible_steps": str(summary.infeasible_steps),
                "wall_time_s": f"{summary.wall_time_s:.3f}",
            },
        )
    if summary.infeasible_steps:
        print(
            f"warning: {scenario.name}: {summary.infeasible_steps} of {summary.steps} MPC steps were infeasible or "
            f"failed; the last feasible forces were applied (/mpc/stats in {log_path.name})",
            file=sys.stderr,
        )
    return summary


_parent_pid: int | None = None  # a pool worker's parent, and the queue it reports progress on
_progress: Any = None
_stopped: int | None = None  # the stop signal a pool worker has received: it starts no further run


def _orphaned() -> bool:
    return _parent_pid is not None and os.getppid() != _parent_pid


def _worker(args) -> RunSummary:
    cfg, scenario, duration, log_path, resolved_yaml, commit, index = args

    def report(done: int, total: int) -> None:
        if done % 15 == 0 or done == total:
            _progress.put((index, done, total))

    global _stopped
    if _stopped is not None:  # a run queued before the stop: not started
        raise Interrupted(_stopped)
    try:
        return run_logged(cfg, scenario, duration, log_path, resolved_yaml, commit, report)
    except Interrupted as exc:  # the log is closed; with no parent left there is nobody to tell
        _stopped = exc.signum
        if _orphaned():
            os._exit(128 + exc.signum)
        raise


def _between_runs(signum, frame) -> None:
    """A pool worker between runs: a stop signal has nothing to stop (the parent cancels what is left),
    unless the parent is gone, and then the worker has nothing left to do."""
    global _stopped
    _stopped = signum
    if _orphaned():
        os._exit(128 + signum)


def _worker_init(progress) -> None:
    """Each pool worker: stop signals are taken between MPC steps while a run is on
    (:func:`slotexp.signals.interrupts_between_steps`) and dropped between runs; and on Linux the
    worker gets SIGTERM when its parent dies, so a killed ``slot run`` leaves no worker computing."""
    global _parent_pid, _progress
    _parent_pid, _progress = os.getppid(), progress
    for signum in STOP_SIGNALS:
        signal.signal(signum, _between_runs)
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):  # not Linux: the parent's own handling still stops its workers
        pass
    if _orphaned():  # the parent died before the death signal was armed
        os._exit(128 + signal.SIGTERM)


def _stop_workers(pool: ProcessPoolExecutor, signum: int) -> None:
    """Pass a stop signal on to every worker (each stops at its next MPC step and closes its log), drop the
    runs not yet started, and wait for the workers to exit."""
    for process in list(getattr(pool, "_processes", {}).values()):
        with contextlib.suppress(OSError):
            os.kill(process.pid, signum)
    pool.shutdown(wait=True, cancel_futures=True)


def run_many(
    cfg: SlotConfig, scenarios: list[ScenarioConfig], duration: float, log_dir: Path, resolved_yaml: str, n_jobs: int
) -> list[RunSummary]:
    """Run every scenario (in parallel when ``n_jobs`` allows) to ``log_dir/<name>.mcap``."""
    commit = git_commit()
    workers = 1 if cfg.live else n_workers(n_jobs, len(scenarios))  # one live server: the scenarios take turns
    steps = int(round(duration * cfg.mpc.rate_hz))
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, console=Console(stderr=True), transient=False) as bar:
        tasks = [bar.add_task(f"{s.name:<10}", total=steps) for s in scenarios]
        if workers == 1:
            out = []
            with open_live(cfg) as live:
                for i, s in enumerate(scenarios):

                    def report(done: int, total: int, i: int = i) -> None:
                        bar.update(tasks[i], completed=done)

                    log = log_dir / f"{s.name}.mcap"
                    out.append(run_logged(cfg, s, duration, log, resolved_yaml, commit, report, live))
            return out
        ctx = mp.get_context("spawn")  # numba/cvxpy state is not fork-safe
        q = ctx.Queue()  # progress, handed to each worker as it starts (no manager process to outlive us)
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=(q,)) as pool:
            futures = {
                pool.submit(_worker, (cfg, s, duration, log_dir / f"{s.name}.mcap", resolved_yaml, commit, i)): i
                for i, s in enumerate(scenarios)
            }
            results: dict[int, RunSummary] = {}
            pending = set(futures)
            try:
                while pending:
                    try:
                        while True:
                            index, done, _ = q.get(timeout=0.2)
                            bar.update(tasks[index], completed=done)
                    except queue.Empty:
                        pass
                    for fut in [f for f in pending if f.done()]:
                        pending.discard(fut)
                        results[futures[fut]] = fut.result()
                        bar.update(tasks[futures[fut]], completed=steps)
            except KeyboardInterrupt as exc:  # SIGINT or SIGTERM to this process: stop the workers too
                _stop_workers(pool, getattr(exc, "signum", signal.SIGINT))
                raise
            return [results[i] for i in range(len(scenarios))]
