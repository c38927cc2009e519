"""Deadline scheduling and loop-timing statistics.

Cycle k is due at ``t0 + k * period``. The loop sleeps to the next deadline (not
for a fixed time), so the work's duration does not accumulate into drift. A cycle
that ends after the next deadline is an overrun: the next cycle starts at once to
catch up; if it is a whole period or more behind, the missed deadlines are skipped
(and counted) rather than run back to back.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Deadlines:
    period: float
    clock: Callable[[], float] = time.monotonic
    sleep: Callable[[float], None] = time.sleep
    t0: float = 0.0
    k: int = 0
    overruns: int = 0
    skipped: int = 0

    def start(self) -> None:
        self.t0 = self.clock()
        self.k = 0

    @property
    def due(self) -> float:
        """When the current cycle was due."""
        return self.t0 + self.k * self.period

    @property
    def next_due(self) -> float:
        return self.t0 + (self.k + 1) * self.period

    def wait_next(self) -> tuple[bool, int]:
        """Sleep to the next deadline; return (this cycle overran, deadlines skipped)."""
        now = self.clock()
        target = self.next_due
        self.k += 1
        if now <= target:
            self.sleep(target - now)
            return False, 0
        self.overruns += 1
        behind = int(math.floor((now - target) / self.period))
        if behind >= 1:
            self.k += behind
            self.skipped += behind
            self.sleep(max(0.0, self.due - self.clock()))
        return True, behind


@dataclass
class LoopStats:
    """Per-cycle timings, summarised for the log's ``loop`` metadata record."""

    period: float
    starts: list[float] = field(default_factory=list)
    cycle_times: list[float] = field(default_factory=list)
    lateness: list[float] = field(default_factory=list)
    odometry_ages: list[float] = field(default_factory=list)
    overruns: int = 0
    skipped: int = 0

    def add(self, start: float, cycle_time: float, lateness: float, odometry_age: float) -> None:
        self.starts.append(start)
        self.cycle_times.append(cycle_time)
        self.lateness.append(lateness)
        self.odometry_ages.append(odometry_age)

    def summary(self) -> dict[str, float]:
        n = len(self.starts)
        out: dict[str, float] = {
            "cycles": float(n),
            "target_rate_hz": 1.0 / self.period,
            "overruns": float(self.overruns),
            "skipped_deadlines": float(self.skipped),
        }
        span = self.starts[-1] - self.starts[0] if n > 1 else 0.0
        out["achieved_rate_hz"] = (n - 1) / span if span > 0 else float("nan")
        for name, values in (
            ("cycle_ms", self.cycle_times),
            ("lateness_ms", self.lateness),
            ("odometry_age_ms", self.odometry_ages),
        ):
            arr = np.asarray(values, dtype=float) * 1e3
            out[f"{name}_median"] = float(np.median(arr)) if n else float("nan")
            out[f"{name}_p99"] = float(np.percentile(arr, 99)) if n else float("nan")
            out[f"{name}_max"] = float(np.max(arr)) if n else float("nan")
        if n > 1:
            dt = np.diff(np.asarray(self.starts)) * 1e3
            out["period_ms_median"] = float(np.median(dt))
            out["period_ms_p99"] = float(np.percentile(dt, 99))
        return out

    def one_line(self) -> str:
        s = self.summary()
        return (
            f"{int(s['cycles'])} cycles at {s['achieved_rate_hz']:.2f} Hz (target {s['target_rate_hz']:g}), "
            f"{int(s['overruns'])} overruns, cycle time median {s['cycle_ms_median']:.1f} ms, "
            f"p99 {s['cycle_ms_p99']:.1f} ms"
        )
