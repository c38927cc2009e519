"""Step schedules, the physical robot's own way of writing gaits, played on the soft plant.

A schedule (:class:`slotexp.config.ScheduleConfig`, ``conf/schedule/``) is a cycle of steps,
each a set of per-leg angles held for ``step_s``. :func:`play` runs several schedules open
loop as one :class:`slotexp.plants.cosserat.CosseratBatch` (one robot per schedule, one
thread each), with the arithmetic of a closed-loop ``controller=schedule`` run, and
:func:`gait_metrics` measures a run the way the robot's evidence is stated: distance per
cycle and heading. ``experiment=replay`` and ``experiment=identify`` both use them.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..config import ScheduleConfig, SlotConfig
from ..plants import nominal_state
from ..plants.cosserat import CosseratBatch, CosseratPlant
from ..robot import build_robot
from ..soft.servo import HornMap
from .openloop import stroke_ceiling, strokes


def schedule_tendon_deg(schedule: ScheduleConfig, legs: list[str], horn: HornMap) -> np.ndarray:
    """The schedule's tendon angles (steps, 4) in ``legs`` order (horn angles through the horn map)."""
    angles = np.array([[step[leg] for leg in legs] for step in schedule.steps], dtype=float)
    return horn.tendon_deg(angles) if schedule.units == "horn" else angles


def step_index(schedule: ScheduleConfig, t: float) -> int:
    """Which step of the cycle is held at time ``t`` (s from the start)."""
    return int(np.floor(t / schedule.step_s + 1e-9)) % len(schedule.steps)


def cycle_s(schedule: ScheduleConfig) -> float:
    return schedule.step_s * len(schedule.steps)


def schedule_velocity(schedule: ScheduleConfig) -> list[float]:
    """The body-frame velocity (m/s) the robot walks its schedule at: its distance per cycle over the cycle, along
    its compass heading (clockwise from forward, so the body frame's heading is its negative); zero where the
    robot's distance is not known."""
    distance = schedule.robot_distance_per_cycle_m or 0.0
    heading = -math.radians(schedule.heading_deg or 0.0)
    speed = distance / cycle_s(schedule)
    return [speed * math.cos(heading), speed * math.sin(heading)]


def with_profile_velocity(cfg: SlotConfig, rpm: float) -> SlotConfig:
    """``cfg`` with the servos' Profile Velocity set as a schedule is played (the robot's gait code: none)."""
    return replace(cfg, robot=replace(cfg.robot, servo=replace(cfg.robot.servo, profile_velocity_rpm=rpm)))


def play(
    cfg: SlotConfig, names: list[str], duration: float, rate_hz: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Play schedules ``names`` open loop for ``duration`` s, tendon goals sampled at ``rate_hz``.

    Returns the times (n + 1,), each robot's state (len(names), n + 1, 12), sampled every
    tick, and how many of each robot's periods were retaken after diverging (its setting-down
    included; ``plant.retakes``). The robots start standing, as a closed-loop run does, and follow
    the same steps.
    """
    robot = build_robot(cfg.robot)
    legs = list(cfg.robot.leg.names)
    horn = HornMap.from_config(cfg.robot.servo)
    plants = [CosseratPlant.from_config(cfg, robot, nominal_state(robot)) for _ in names]
    batch = CosseratBatch(plants)
    schedules = [cfg.schedules[name] for name in names]
    tendons = [schedule_tendon_deg(s, legs, horn) for s in schedules]
    period = 1.0 / rate_hz
    n = int(round(duration * rate_hz))
    xs = np.empty((len(names), n + 1, 12))
    xs[:, 0] = [p.state() for p in plants]
    for k in range(n):
        t = k * period
        batch.step(np.stack([td[step_index(s, t)] for s, td in zip(schedules, tendons, strict=True)]), period)
        xs[:, k + 1] = [p.state() for p in plants]
    return np.arange(n + 1) * period, xs, np.array([p.retaken_periods for p in plants])


def heading_defined(positions: np.ndarray) -> bool:
    """Whether a gait's direction of travel is defined by its cycles, from the body's planar ``positions`` (m)
    at their boundaries (k + 1, 2): their mean displacement is more than twice its standard error (from the
    cycles' scatter). A gait that barely moves drifts a fraction of a millimetre per cycle in a direction its
    start and its stick-slip decide, and a heading read from that drift (or compared with the robot's) says
    nothing about the gait."""
    steps = np.diff(positions, axis=0)  # each cycle's displacement (m)
    if len(steps) < 2:
        return bool(len(steps) == 1 and np.linalg.norm(steps[0]) > 0.0)
    mean = steps.mean(axis=0)
    standard_error = steps.std(axis=0, ddof=1) / np.sqrt(len(steps))
    return bool(np.linalg.norm(mean) > 2.0 * np.linalg.norm(standard_error))


def cycle_starts(t: np.ndarray, cycle: float, measure_from_s: float) -> list[int]:
    """The sample index (of times ``t``) at which each whole cycle after ``measure_from_s`` starts, and the index
    at which the last one ends: the span every per-cycle measure of a played schedule is taken over."""
    first = math.ceil(measure_from_s / cycle - 1e-9)
    last = math.floor((t[-1] - t[0]) / cycle + 1e-9)
    return [int(np.argmin(np.abs(t - t[0] - k * cycle))) for k in range(first, last + 1)]


def gait_metrics(t: np.ndarray, x: np.ndarray, cycle: float, measure_from_s: float) -> dict:
    """Distance per cycle, speed, headings, yaw rate and heave over the whole cycles after ``measure_from_s``.

    ``x`` is the state (n, 12) at times ``t``; headings are of the displacement over those
    cycles, in our convention (counter-clockwise from forward) and the robot's compass
    (clockwise from forward), the robot starting at zero yaw; ``heading_defined`` says whether
    the cycles agree on it (:func:`heading_defined`).
    """
    bounds = cycle_starts(t, cycle, measure_from_s)
    i0, i1 = bounds[0], bounds[-1]
    cycles = len(bounds) - 1
    span = t[i1] - t[i0]
    d = x[i1, 3:5] - x[i0, 3:5]
    heading = float(np.degrees(np.arctan2(d[1], d[0])))
    yaw = np.unwrap(x[:, 2])
    return {
        "cycles": int(cycles),
        "heading_defined": heading_defined(x[bounds, 3:5]),
        "distance_per_cycle_mm": float(np.linalg.norm(d) / cycles * 1e3),
        "speed_mm_s": float(np.linalg.norm(d) / span * 1e3),
        "heading_deg": heading,  # ours: counter-clockwise from forward
        "compass_deg": float((-heading) % 360.0),  # the robot's: clockwise from forward
        "yaw_rate_deg_s": float(np.degrees(yaw[i1] - yaw[i0]) / span),
        "heave_mm": float(np.ptp(x[i0 : i1 + 1, 5]) * 1e3),
        "height_mm": float(np.mean(x[i0 : i1 + 1, 5]) * 1e3),
    }


def foot_strokes(
    t: np.ndarray, reach: np.ndarray, cycle: float, measure_from_s: float, leg_yaw: np.ndarray, heading_deg: float
) -> dict:
    """Each foot's stroke along its leg over the whole cycles after ``measure_from_s`` (the peak-to-peak of its
    reach ``reach`` (n, 4), m, within each cycle, averaged), the stroke ceiling (how far per cycle the body would
    go along ``heading_deg`` if every stroke were gripped whole, :func:`slotexp.locomotion.openloop.stroke_ceiling`)
    and the grip efficiency (distance over ceiling): which of the two limits a gait meets on the model."""
    i0 = cycle_starts(t, cycle, measure_from_s)[0]
    steps = max(1, int(round(cycle / float(np.median(np.diff(t))))))
    stroke = strokes(reach, i0, steps)
    ceiling = stroke_ceiling(stroke, leg_yaw, heading_deg, 1.0) * 1e3  # per cycle: a frequency of one
    return {
        **{f"stroke_{i}_mm": float(v * 1e3) for i, v in enumerate(stroke)},
        "stroke_max_mm": float(np.max(stroke) * 1e3),
        "stroke_ceiling_mm": float(ceiling),
    }


def foot_slides(t: np.ndarray, feet: np.ndarray, cycle: float, measure_from_s: float) -> dict:
    """How far each foot travels over the ground per cycle, over the whole cycles after ``measure_from_s``: the
    path length of its horizontal position ``feet`` (n, 4, 2), m, at times ``t``. A foot that anchors barely
    moves; one that slides moves about as far as its stroke. Which feet anchor is what decides a reach-and-pull
    gait on Coulomb friction (docs/results/gaits.md), and the stroke columns cannot show it."""
    bounds = cycle_starts(t, cycle, measure_from_s)
    path = np.linalg.norm(np.diff(feet[bounds[0] : bounds[-1] + 1], axis=0), axis=2).sum(axis=0)
    path /= max(1, len(bounds) - 1)
    return {
        **{f"slide_{i}_mm": float(v * 1e3) for i, v in enumerate(path)},
        "slide_min_mm": float(path.min() * 1e3),  # the foot that holds best
        "slide_max_mm": float(path.max() * 1e3),
    }


def wrap_deg(angle: float) -> float:
    """An angle in (-180, 180]."""
    return -((-angle + 180.0) % 360.0 - 180.0)
