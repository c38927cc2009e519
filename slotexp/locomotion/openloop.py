"""Open-loop gait runs on the soft plant: what a gait does, measured (the gait search's evaluation).

The robot is set down standing (:class:`slotexp.plants.cosserat.CosseratPlant`), then
its tendons follow the gait's angles, sampled at the controller's rate (30 Hz) and
driven by the servo model (speed-torque line, Profile Velocity). After ``settle``
seconds the motion is measured over whole gait cycles up to the end of the run.
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
    xs[0] = plant.state()
    for k in range(n):
        plant.step(TendonCommand(angles(k * period)), period)
        xs[k + 1] = plant.state()
    return measure(xs, period, frequency_hz, settle)


def measure(xs: np.ndarray, period: float, frequency_hz: float, settle: float) -> GaitMetrics:
    """Metrics of a state trajectory ``xs`` (n + 1, 12) sampled every ``period``."""
    n = xs.shape[0] - 1
    total = n * period
    cycles = max(1, int(math.floor((total - settle) * frequency_hz + 1e-9)))
    window = min(cycles / frequency_hz, total - settle)
    start = n - int(round(window / period))
    span = (n - start) * period
    v = (xs[n, 3:5] - xs[start, 3:5]) / span * 1e3
    yaw = np.unwrap(xs[:, 2])
    after = xs[int(round(settle / period)) :]
    return GaitMetrics(
        vx=float(v[0]),
        vy=float(v[1]),
        speed=float(np.hypot(*v)),
        heading_deg=float(np.degrees(np.arctan2(v[1], v[0]))),
        yaw_rate_dps=float(np.degrees(yaw[n] - yaw[start]) / span),
        yaw_total_deg=float(np.degrees(yaw[n] - yaw[0])),
        dz_mean_mm=float((xs[start:, 5].mean() - xs[0, 5]) * 1e3),
        dz_range_mm=float(np.ptp(after[:, 5]) * 1e3),
        roll_max_deg=float(np.degrees(np.abs(after[:, 0]).max())),
        pitch_max_deg=float(np.degrees(np.abs(after[:, 1]).max())),
        window_s=float(span),
    )
