"""Open-loop gait runs on the soft plant: what a gait does, measured (the gait search's evaluation).

The robot is set down standing (:class:`slotexp.plants.cosserat.CosseratPlant`), then
its tendons follow the gait's angles, sampled at the controller's rate (30 Hz) and
driven by the servo model (speed-torque line, Profile Velocity). After ``settle``
seconds the motion is measured over whole gait cycles up to the end of the run.

Beside the motion, each foot's stroke: how far it moves along its leg (from the root,
in the leg's plane) within a gait cycle, peak to peak, averaged over the measured
cycles. A foot moves the body only along its leg, by at most its stroke while it
grips, so ``f * sum_i stroke_i |cos(alpha_i - h)|`` (legs pointing out at alpha_i,
travel along h, each leg's stroke used once a cycle) is the speed the strokes would
give if every one were gripped whole: the stroke ceiling. Speed over ceiling is the
grip efficiency. It is an estimate, not a bound: feet that slide with unequal
friction can move the body too.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from ..config import SlotConfig
from ..plants import TendonCommand, nominal_state
from ..plants.cosserat import CosseratPlant
from ..robot import build_robot


@dataclass
class GaitMetrics:
    """Mean motion over the measured window: velocities in mm/s and the world frame (the start's body frame)."""

    vx: float
    vy: float
    speed: float
    heading_deg: float
    yaw_rate_dps: float
    yaw_total_deg: float
    dz_mean_mm: float  # mean height over the window, against the standing height
    dz_range_mm: float  # peak-to-peak height after settling
    roll_max_deg: float
    pitch_max_deg: float
    window_s: float
    stroke_mm: float = math.nan  # the feet's mean stroke along their legs per gait cycle (peak to peak)
    stroke_ceiling_mm_s: float = math.nan  # the speed every stroke would give, gripped whole (module docstring)

    @property
    def grip_efficiency(self) -> float:
        """Speed over the stroke ceiling (NaN where no ceiling was measured)."""
        return self.speed / self.stroke_ceiling_mm_s if self.stroke_ceiling_mm_s > 0 else math.nan

    def along(self, heading_deg: float) -> tuple[float, float]:
        """(speed along, speed across) ``heading_deg``, mm/s."""
        h = math.radians(heading_deg)
        return (self.vx * math.cos(h) + self.vy * math.sin(h), -self.vx * math.sin(h) + self.vy * math.cos(h))

    def as_dict(self) -> dict:
        return asdict(self)


def run_gait(
    cfg: SlotConfig, angles: Callable[[float], np.ndarray], frequency_hz: float, duration: float, settle: float
) -> GaitMetrics:
    """Drive the soft plant with tendon angles ``angles(t)`` (deg, (4,)) and measure it."""
    robot = build_robot(cfg.robot)
    plant = CosseratPlant.from_config(cfg, robot, nominal_state(robot))
    period = 1.0 / cfg.mpc.rate_hz
    n = int(round(duration / period))
    xs = np.empty((n + 1, 12))
    reach = np.empty((n + 1, 4))
    xs[0], reach[0] = plant.state(), plant.foot_reach()
    for k in range(n):
        plant.step(TendonCommand(angles(k * period)), period)
        xs[k + 1], reach[k + 1] = plant.state(), plant.foot_reach()
    return measure(xs, period, frequency_hz, settle, reach, np.radians(cfg.robot.leg.yaw_deg))


def strokes(reach: np.ndarray, start: int, cycle_steps: int) -> np.ndarray:
    """Each foot's stroke (4,), m: the peak-to-peak of its reach within each whole cycle from ``start``, averaged."""
    n_cycles = (reach.shape[0] - 1 - start) // cycle_steps
    if n_cycles < 1:
        return np.full(reach.shape[1], np.nan)
    cycles = reach[start : start + n_cycles * cycle_steps].reshape(n_cycles, cycle_steps, -1)
    return np.ptp(cycles, axis=1).mean(axis=0)


def stroke_ceiling(stroke: np.ndarray, leg_yaw: np.ndarray, heading_deg: float, frequency_hz: float) -> float:
    """The speed (same length unit per s as ``stroke``) along ``heading_deg`` if every stroke were gripped whole."""
    return float(frequency_hz * np.sum(stroke * np.abs(np.cos(leg_yaw - math.radians(heading_deg)))))


def measure(
    xs: np.ndarray,
    period: float,
    frequency_hz: float,
    settle: float,
    reach: np.ndarray | None = None,
    leg_yaw: np.ndarray | None = None,
) -> GaitMetrics:
    """Metrics of a state trajectory ``xs`` (n + 1, 12) sampled every ``period`` (and of the feet's ``reach``
    (n + 1, 4) along legs pointing out at ``leg_yaw`` (rad), when given)."""
    n = xs.shape[0] - 1
    total = n * period
    cycles = max(1, int(math.floor((total - settle) * frequency_hz + 1e-9)))
    window = min(cycles / frequency_hz, total - settle)
    start = n - int(round(window / period))
    span = (n - start) * period
    v = (xs[n, 3:5] - xs[start, 3:5]) / span * 1e3
    yaw = np.unwrap(xs[:, 2])
    after = xs[int(round(settle / period)) :]
    heading = float(np.degrees(np.arctan2(v[1], v[0])))
    stroke_mm, ceiling = math.nan, math.nan
    if reach is not None and leg_yaw is not None:
        stroke = strokes(reach, start, max(1, int(round(1.0 / (frequency_hz * period))))) * 1e3
        stroke_mm, ceiling = float(np.mean(stroke)), stroke_ceiling(stroke, leg_yaw, heading, frequency_hz)
    return GaitMetrics(
        vx=float(v[0]),
        vy=float(v[1]),
        speed=float(np.hypot(*v)),
        heading_deg=heading,
        yaw_rate_dps=float(np.degrees(yaw[n] - yaw[start]) / span),
        yaw_total_deg=float(np.degrees(yaw[n] - yaw[0])),
        dz_mean_mm=float((xs[start:, 5].mean() - xs[0, 5]) * 1e3),
        dz_range_mm=float(np.ptp(after[:, 5]) * 1e3),
        roll_max_deg=float(np.degrees(np.abs(after[:, 0]).max())),
        pitch_max_deg=float(np.degrees(np.abs(after[:, 1]).max())),
        window_s=float(span),
        stroke_mm=stroke_mm,
        stroke_ceiling_mm_s=ceiling,
    )
