"""Experiment ``simulate``: one gait in closed loop; Figs. 4 and 6 and tracking metrics."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import write_json
from ..config import SlotConfig, check_run_length, check_scenario, num_field
from ..metrics import lateral_drift, rmse
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
    """Tracking metrics (docs/results/index.md, "Definitions"). Speed, heading and the speed error are
    the mean over t >= ``measure_from_s`` (net displacement over time); the commanded direction is
    the reference's at the start (the world frame, the robot starting at zero yaw)."""
    xy, xy_ref = run.x[:, 3:5], run.x_ref[:, 3:5]
    direction = np.asarray(velocity, dtype=float)
    commanded = float(np.linalg.norm(direction))
    if commanded < 1e-12:
        direction = np.array([1.0, 0.0])
    drift, covered = lateral_drift(xy, direction, drift_distance)
    start = int(np.searchsorted(run.t, run.t[0] + measure_from_s))
    start = min(start, len(run.t) - 2)
    span = float(run.t[-1] - run.t[start])
    mean_v = (xy[-1] - xy[start]) / span
    d = direction / np.linalg.norm(direction)
    along = float(mean_v @ d)
    heading_error = float(np.degrees(np.arctan2(mean_v[1], mean_v[0]) - np.arctan2(d[1], d[0])))
    heading_error = (heading_error + 180.0) % 360.0 - 180.0
    yaw_drift = float(np.degrees(run.x[-1, 2] - run.x_ref[-1, 2]))
    yaw = np.unwrap(run.x[:, 2])
    mean_yaw_rate = float((yaw[-1] - yaw[start]) / span)  # turning in place is measured by this
    return {
        "speed_mps": float(np.linalg.norm(mean_v)),
        "speed_along_mps": along,
        "speed_error_fraction": (along - commanded) / commanded if commanded > 0 else float("nan"),
        "heading_error_deg": heading_error if commanded > 0 else float("nan"),
        "yaw_drift_deg": yaw_drift,
        "yaw_rate_radps": mean_yaw_rate,
        "yaw_rate_error_fraction": (mean_yaw_rate - yaw_rate) / yaw_rate if abs(yaw_rate) > 0 else float("nan"),
        "lateral_drift_per_m": drift / covered if covered > 0 else float("nan"),
        "measured_from_s": float(run.t[start]),
        "gait": run.run.get("gait"),
        "duration_s": float(run.t[-1] - run.t[0]),
        "com_rmse_x_m": rmse(run.x[:, 3], run.x_ref[:, 3]),
        "com_rmse_y_m": rmse(run.x[:, 4], run.x_ref[:, 4]),
        "com_rmse_z_m": rmse(run.x[:, 5], run.x_ref[:, 5]),
        "path_rmse_m": float(np.sqrt(np.mean(np.sum((xy - xy_ref) ** 2, axis=1)))),
        "mean_vx": float(np.mean(run.x[:, 9])),
        "mean_vy": float(np.mean(run.x[:, 10])),
        "distance_m": float(np.linalg.norm(xy[-1] - xy[0])),
        "lateral_drift_m": drift,
        "drift_measured_over_m": covered,
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
