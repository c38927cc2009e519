"""Experiment ``replay``: the physical robot's own gaits on the soft plant, beside what they do on the robot.

Each schedule (``experiment.schedules``, from ``conf/schedule/``) is played open loop
(``controller=schedule``, horn angles through the robot's horn map, no Profile Velocity
as on the robot) for ``experiment.duration`` and logged to ``logs/<schedule>.mcap``.
From the logs alone: per gait the distance per cycle, speed, heading in our convention
(counter-clockwise from forward, the robot starting at zero yaw) and the robot's compass
(clockwise from forward), yaw rate and heave, each over the whole cycles after
``experiment.measure_from_s``; each foot's stroke along its leg, the stroke ceiling and
the grip efficiency (which of the two limits on distance the gait meets on the model),
beside the robot's heading and distance (``replay.csv``, ``replay.md``,
``metrics.json``); ``fig_replay.png`` (headings on a compass, distances per cycle) and a
GIF per gait. A Hydra multirun over model options compares them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ..atomic import write_csv, write_json, write_text
from ..config import (
    ConfigError,
    ScheduleConfig,
    SlotConfig,
    check_run_length,
    check_schedule_reach,
    check_schedule_ticks,
    num_field,
)
from ..controllers.schedule import ScheduleControllerConfig
from ..locomotion.schedules import (
    cycle_s,
    foot_slides,
    foot_strokes,
    gait_metrics,
    with_profile_velocity,
    wrap_deg,
)
from ..runlog import find_logs, load_run
from . import EXPERIMENTS, Experiment
from ._logged import git_commit, run_logged

VISIBLE = ["forward", "backward", "right_walk", "left_walk", "walk_45", "crawl_forward", "crawl_backward"]


@dataclass
class ReplayExperiment:
    """Play schedules open loop on the soft plant and compare with the robot (docs/results/gaits.md)."""

    name: str = "replay"
    schedules: list[str] = field(default_factory=lambda: list(VISIBLE))
    duration: float = num_field(12.0, lo=0.0, lo_open=True, hi=3600.0, unit="s")
    measure_from_s: float = num_field(3.0, lo=0.0, unit="s")  # whole cycles from here on are measured
    # the controller's tick: every step of every schedule must last a whole number of them (0.42 and 0.40 s: 50 Hz)
    rate_hz: float = num_field(50.0, lo=1.0, hi=1000.0, unit="Hz")
    # the robot's gait code writes no Profile Velocity: the servos turn as fast as their load lets them
    profile_velocity_rpm: float = num_field(0.0, lo=0.0, hi=61.0, unit="rpm")
    gif: bool = True

    def check(self, cfg: SlotConfig) -> None:
        if cfg.plant.name != "cosserat":
            raise ConfigError(
                f"experiment=replay plays tendon schedules on the soft legs: use plant=cosserat, not {cfg.plant.name}"
            )
        check_played_schedules(cfg, self.schedules, self.rate_hz, self.duration, self.measure_from_s)
        check_run_length(cfg, self.duration)


def check_played_schedules(
    cfg: SlotConfig, names: list[str], rate_hz: float, duration: float, measure_from_s: float
) -> None:
    """``experiment.schedules``: named, shipped, whole ticks of ``rate_hz`` per step, a whole cycle measured."""
    if not names:
        raise ConfigError("experiment.schedules is empty: name at least one schedule (conf/schedule/)")
    for name in names:
        if name not in cfg.schedules:
            raise ConfigError(
                f"experiment.schedules names {name!r}, which is not a schedule: choose from "
                f"{', '.join(sorted(cfg.schedules))} (conf/schedule/)"
            )
        check_schedule_ticks(cfg, cfg.schedules[name], rate_hz, "experiment.rate_hz")
        check_schedule_reach(cfg, name)
        check_whole_cycle(cfg.schedules[name], duration, measure_from_s)


def check_whole_cycle(schedule: ScheduleConfig, duration: float, measure_from_s: float) -> None:
    """A run of ``duration`` must hold a whole cycle of ``schedule`` after ``measure_from_s``."""
    cycle = cycle_s(schedule)
    first = math.ceil(measure_from_s / cycle - 1e-9) * cycle  # cycles are measured from here
    if first + cycle > duration + 1e-9:
        raise ConfigError(
            f"experiment.duration = {duration:g} s holds no whole cycle of {schedule.name} ({cycle:g} s) after "
            f"experiment.measure_from_s = {measure_from_s:g} s: give experiment.duration >= {first + cycle:g}"
        )


def schedule_config(cfg: SlotConfig, name: str) -> SlotConfig:
    """``cfg`` set to play schedule ``name`` as the replay does (controller, tick, Profile Velocity)."""
    exp = cfg.experiment
    return replace(
        with_profile_velocity(cfg, exp.profile_velocity_rpm),
        controller=ScheduleControllerConfig(library=cfg.controller.library, schedule=name),
        mpc=replace(cfg.mpc, rate_hz=exp.rate_hz),
        gait=replace(cfg.gait, name=name, velocity=[0.0, 0.0], yaw_rate=0.0),
    )


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    from rich.console import Console
    from rich.progress import Progress

    exp = cfg.experiment
    commit = git_commit()
    with Progress(console=Console(stderr=True), transient=False) as bar:
        for name in exp.schedules:
            task = bar.add_task(f"{name:<15}", total=int(round(exp.duration * exp.rate_hz)))
            run_logged(
                schedule_config(cfg, name),
                cfg.scenarios["baseline"],
                exp.duration,
                out_dir / "logs" / f"{name}.mcap",
                resolved_yaml,
                commit,
                lambda done, total, task=task: bar.update(task, completed=done),
            )
    report(out_dir, cfg)


def report(out_dir: Path, cfg: SlotConfig) -> pd.DataFrame:
    """The table and figure of a replay, from its logs and the schedules' robot evidence."""
    from rich.console import Console
    from rich.progress import Progress

    exp = cfg.experiment
    logs = {p.stem: p for p in find_logs(out_dir)}
    rows = []
    # each gait's log read back, measured and (with experiment.gif) animated: tens of seconds a gait
    with Progress(console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task("report", total=sum(name in logs for name in exp.schedules))
        for name in exp.schedules:
            if name not in logs:
                continue
            bar.update(task, description=f"report {name:<15}")
            rows.append(_gait_row(name, logs[name], cfg, out_dir))
            bar.advance(task)
    table = pd.DataFrame(rows)
    write_csv(table, out_dir / "replay.csv", index=False)
    write_text(out_dir / "replay.md", replay_markdown(table))
    write_json(out_dir / "metrics.json", {r["gait"]: r for r in rows})
    from ..figures.replay import plot_replay

    plot_replay(table, out_dir / "fig_replay.png")
    return table


def _gait_row(name: str, log: Path, cfg: SlotConfig, out_dir: Path) -> dict:
    """One gait's row of the replay table from its log (and its GIF, with experiment.gif)."""
    exp = cfg.experiment
    schedule = cfg.schedules[name]
    run = load_run(log)
    legs = list(cfg.robot.leg.names)
    row = {"gait": name, **gait_metrics(run.t, run.x, cycle_s(schedule), exp.measure_from_s)}
    row.update(
        foot_strokes(
            run.t,
            feet_reach(run, legs),
            cycle_s(schedule),
            exp.measure_from_s,
            np.radians(cfg.robot.leg.yaw_deg),
            row["heading_deg"],
        )
    )
    row.update(foot_slides(run.t, feet_xy(run, legs), cycle_s(schedule), exp.measure_from_s))
    row["grip_efficiency"] = row["distance_per_cycle_mm"] / row["stroke_ceiling_mm"]
    row["robot_compass_deg"] = schedule.heading_deg
    row["robot_turn"] = schedule.turn or ""  # a turning gait's spin on the robot (cw, ccw)
    row["robot_distance_per_cycle_mm"] = (
        schedule.robot_distance_per_cycle_m * 1e3 if schedule.robot_distance_per_cycle_m is not None else math.nan
    )
    row["heading_error_deg"] = (
        wrap_deg(row["compass_deg"] - schedule.heading_deg) if schedule.heading_deg is not None else math.nan
    )
    row["distance_ratio"] = row["distance_per_cycle_mm"] / row["robot_distance_per_cycle_mm"]
    if exp.gif:
        from ..figures.animation import animate_log

        animate_log(run.path, out_dir / f"{name}.gif")
    return row


def feet_reach(run, legs: list[str]) -> np.ndarray:
    """Each foot's horizontal distance from its leg's root (n, 4), m, from the log's markers: how far out along
    its leg it is (the legs move in their vertical planes)."""
    roots = np.stack([run.markers[[f"{leg}_n0.0", f"{leg}_n0.1"]].to_numpy(float) for leg in legs], axis=1)
    offset = feet_xy(run, legs) - roots
    return np.hypot(offset[..., 0], offset[..., 1])


def feet_xy(run, legs: list[str]) -> np.ndarray:
    """Each foot's horizontal position in the world (n, 4, 2), m, from the log's markers."""
    m = run.markers
    return np.stack([m[[f"{leg}_foot.0", f"{leg}_foot.1"]].to_numpy(float) for leg in legs], axis=1)


def replay_markdown(table: pd.DataFrame) -> str:
    """The replay beside the robot, one row per gait."""
    head = (
        "| gait | robot: compass heading | ours: compass heading (error) | ours: heading, CCW | distance per cycle "
        "(mm): ours / robot | speed (mm/s) | yaw rate (deg/s) | heave (mm) | largest foot stroke (mm) "
        "| stroke ceiling (mm per cycle) | grip efficiency |\n|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for _, r in table.iterrows():
        robot_d = "—" if math.isnan(r["robot_distance_per_cycle_mm"]) else f"{r['robot_distance_per_cycle_mm']:.0f}"
        if math.isnan(r["robot_compass_deg"]):  # a turn: its spin, ours by the yaw rate's sign (CCW positive)
            turn = r.get("robot_turn", "") or "—"
            robot, error = f"turns {turn}", f"turns {'cw' if r['yaw_rate_deg_s'] < 0 else 'ccw'}; "
        else:
            robot, error = f"{r['robot_compass_deg']:.0f}°", ""
        heading_error = "" if math.isnan(r["heading_error_deg"]) else f" ({r['heading_error_deg']:+.0f}°)"
        ours, ccw = f"{round(r['compass_deg']) % 360}°{heading_error}", f"{r['heading_deg']:+.0f}°"
        if not r.get("heading_defined", True):  # its cycles do not agree on a direction (gait_metrics)
            ours, ccw = "— (moves too little)", "—"
        lines.append(
            f"| {r['gait']} | {robot} | {error}{ours} "
            f"| {ccw} | {r['distance_per_cycle_mm']:.1f} / {robot_d} | {r['speed_mm_s']:.1f} "
            f"| {r['yaw_rate_deg_s']:+.2f} | {r['heave_mm']:.1f} | {r['stroke_max_mm']:.1f} "
            f"| {r['stroke_ceiling_mm']:.1f} | {r['grip_efficiency']:.2f} |"
        )
    return head + "\n".join(lines) + "\n"


EXPERIMENTS.add("replay", Experiment(ReplayExperiment, run, report, summary="replay.md"))
