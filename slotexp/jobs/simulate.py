"""Experiment ``simulate``: one gait in closed loop; Figs. 4 and 6 and tracking metrics."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from ..atomic import write_json
from ..config import SlotConfig, check_run_length, check_scenario, num_field
from ..metrics import tracking
from ..runlog import RunData, find_logs, load_run
from . import EXPERIMENTS, Experiment
from ._logged import git_commit, run_logged


@dataclass
class SimulateExperiment:
    """Closed-loop run of one gait (paper Figs. 4 and 6)."""

    name: str = "simulate"
    duration: float = num_field(10.0, lo=0.0, lo_open=True, hi=3600.0, unit="s")
    scenario: str = "baseline"
    drift_distance: float = num_field(0.8, lo=0.0, lo_open=True, unit="m")
    measure_from_s: float = num_field(2.0, lo=0.0, unit="s")  # speed and heading are measured after this
    gif: bool = True  # the soft-leg walk's animation (about 13 s of the report's time): false skips it

    def check(self, cfg: SlotConfig) -> None:
        check_run_length(cfg, self.duration)
        check_scenario(cfg, self.scenario, "experiment.scenario names")


def metrics(
    run: RunData, velocity: list[float], drift_distance: float, measure_from_s: float = 2.0, yaw_rate: float = 0.0
) -> dict:
    """Tracking metrics (docs/results/index.md, "Definitions"): :func:`slotexp.metrics.tracking` of the run's
    states against its reference, with the run's own record (its gait, infeasible steps, solve time)."""
    return {
        "gait": run.run.get("gait"),
        **tracking(run.t, run.x, run.x_ref, velocity, drift_distance, measure_from_s, yaw_rate),
        "infeasible_steps": run.infeasible_steps,
        "median_solve_wall_ms": float(run.stats["wall_time_s"].median() * 1e3),
    }


def measured_from(exp: SimulateExperiment) -> float:
    """Where speed and heading are measured from: ``experiment.measure_from_s``, or the run's last fifth when
    that is past the run's end (short runs at the default 2 s)."""
    return exp.measure_from_s if exp.measure_from_s < 0.8 * exp.duration else 0.8 * exp.duration


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    exp = cfg.experiment
    scenario = cfg.scenarios[exp.scenario]
    if exp.measure_from_s >= exp.duration:
        print(
            f"warning: experiment.measure_from_s = {exp.measure_from_s:g} s is past the run's end "
            f"({exp.duration:g} s): speed and heading are measured over its last fifth",
            file=sys.stderr,
        )
    log = out_dir / "logs" / f"{cfg.gait.name}.mcap"
    from rich.console import Console
    from rich.progress import Progress

    with Progress(console=Console(stderr=True), transient=False) as bar:
        task = bar.add_task(f"{cfg.gait.name:<10}", total=int(round(exp.duration * cfg.mpc.rate_hz)))
        run_logged(
            cfg,
            scenario,
            exp.duration,
            log,
            resolved_yaml,
            git_commit(),
            lambda done, total: bar.update(task, completed=done),
        )
    report(out_dir, cfg)


def report(out_dir: Path, cfg: SlotConfig) -> dict:
    """Metrics, Figs. 4 and 6 (and the walk animation of a soft-leg run) from the log alone."""
    exp = cfg.experiment
    return write_report(
        out_dir,
        list(cfg.gait.velocity),
        exp.drift_distance,
        list(cfg.robot.leg.names),
        measured_from(exp),
        yaw_rate=cfg.gait.yaw_rate,
        gif=exp.gif,
    )


def write_report(
    out_dir: Path,
    velocity: list[float],
    drift_distance: float,
    legs: list[str],
    measure_from_s: float = 2.0,
    yaw_rate: float = 0.0,
    gif: bool = True,
) -> dict:
    """:func:`report` with its settings given (hardware runs share it)."""
    from ..figures.simulate import plot_com, plot_path

    run = load_run(find_logs(out_dir)[0])
    result = metrics(run, velocity, drift_distance, measure_from_s, yaw_rate)
    write_json(out_dir / "metrics.json", result)
    plot_com(run, out_dir / "fig4_com.png")
    plot_path(run, legs, out_dir / "fig6_path.png")
    if gif:
        from ..figures.animation import animate_log

        animate_log(run.path, out_dir / f"{run.run.get('gait', 'run')}.gif")  # soft-leg runs only
    return result


EXPERIMENTS.add("simulate", Experiment(SimulateExperiment, run, report, walks_gait=True))
