"""Run scenarios to MCAP logs, in parallel processes, with one progress bar."""

from __future__ import annotations

import datetime as _dt
import multiprocessing as mp
import os
import queue
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from .. import __version__
from ..config import ScenarioConfig, SlotConfig
from ..record import Recorder
from ..simulation import RunSummary, run_closed_loop


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


def run_logged(
    cfg: SlotConfig,
    scenario: ScenarioConfig,
    duration: float,
    log_path: Path,
    resolved_yaml: str,
    commit: str,
    progress=None,
) -> RunSummary:
    """One closed-loop run streamed to ``log_path``; the log is closed validly even on Ctrl-C."""
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
    with Recorder(log_path, metadata=meta) as rec:
        summary = run_closed_loop(cfg, scenario, duration, rec, progress)
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


def _worker(args) -> RunSummary:
    cfg, scenario, duration, log_path, resolved_yaml, commit, q, index = args

    def report(done: int, total: int) -> None:
        if done % 15 == 0 or done == total:
            q.put((index, done, total))

    return run_logged(cfg, scenario, duration, log_path, resolved_yaml, commit, report)


def n_workers(requested: int, n_tasks: int) -> int:
    cores = os.cpu_count() or 1
    return max(1, min(n_tasks, requested if requested > 0 else cores))


def run_many(
    cfg: SlotConfig, scenarios: list[ScenarioConfig], duration: float, log_dir: Path, resolved_yaml: str, n_jobs: int
) -> list[RunSummary]:
    """Run every scenario (in parallel when ``n_jobs`` allows) to ``log_dir/<name>.mcap``."""
    commit = git_commit()
    workers = n_workers(n_jobs, len(scenarios))
    steps = int(round(duration * cfg.mpc.rate_hz))
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, console=Console(stderr=True), transient=False) as bar:
        tasks = [bar.add_task(f"{s.name:<10}", total=steps) for s in scenarios]
        if workers == 1:
            out = []
            for i, s in enumerate(scenarios):

                def report(done: int, total: int, i: int = i) -> None:
                    bar.update(tasks[i], completed=done)

                out.append(run_logged(cfg, s, duration, log_dir / f"{s.name}.mcap", resolved_yaml, commit, report))
            return out
        ctx = mp.get_context("spawn")  # numba/cvxpy state is not fork-safe
        with ctx.Manager() as manager:
            q = manager.Queue()
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                futures = {
                    pool.submit(_worker, (cfg, s, duration, log_dir / f"{s.name}.mcap", resolved_yaml, commit, q, i)): i
                    for i, s in enumerate(scenarios)
                }
                results: dict[int, RunSummary] = {}
                pending = set(futures)
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
                return [results[i] for i in range(len(scenarios))]
