"""Experiment ``simulate``: one gait in closed loop; Figs. 4 and 6 and tracking metrics."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..config import SlotConfig
from ..figures.simulate import plot_com, plot_path
from ..metrics import rmse
from ..runlog import RunData, find_logs, load_run
from .logged import git_commit, run_logged


def lateral_drift(xy: np.ndarray, direction: np.ndarray, distance: float) -> tuple[float, float]:
    """Largest deviation across the direction of travel within the first ``distance`` m along it.

    Returns (drift, along-track distance actually covered, capped at ``distance``).
    """
    d = direction / np.linalg.norm(direction)
    n = np.array([-d[1], d[0]])
    rel = xy - xy[0]
    along = rel @ d
    covered = np.maximum.accumulate(along)
    mask = covered <= distance
    mask[0] = True
    return float(np.max(np.abs(rel[mask] @ n))), float(min(covered[-1], distance))


def metrics(run: RunData, velocity: list[float], drift_distance: float) -> dict:
    xy, xy_ref = run.x[:, 3:5], run.x_ref[:, 3:5]
    direction = np.asarray(velocity, dtype=float)
    if np.linalg.norm(direction) < 1e-12:
        direction = np.array([1.0, 0.0])
    drift, covered = lateral_drift(xy, direction, drift_distance)
    return {
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


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    exp = cfg.experiment
    scenario = cfg.scenarios[exp.scenario]
    log = out_dir / "logs" / f"{cfg.gait.name}.mcap"
    from rich.console import Console
    from rich.progress import Progress

    with Progress(console=Console(stderr=True), transient=False) as bar:
        task = bar.add_task(f"{cfg.gait.name:<10}", total=int(round(exp.duration * cfg.mpc.rate_hz)))
        run_logged(cfg, scenario, exp.duration, log, resolved_yaml, git_commit(),
                   lambda done, total: bar.update(task, completed=done))
    report(out_dir, list(cfg.gait.velocity), exp.drift_distance, list(cfg.robot.leg.names))


def report(out_dir: Path, velocity: list[float], drift_distance: float, legs: list[str]) -> dict:
    run = load_run(find_logs(out_dir)[0])
    result = metrics(run, velocity, drift_distance)
    (out_dir / "metrics.json").write_text(json.dumps(result, indent=2))
    plot_com(run, out_dir / "fig4_com.png")
    plot_path(run, legs, out_dir / "fig6_path.png")
    from ..figures.animation import animate_log

    animate_log(run.path, out_dir / f"{run.run.get('gait', 'run')}.gif")  # soft-leg runs only
    return result
