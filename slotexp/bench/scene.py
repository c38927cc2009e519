"""``slot bench scene``: what logging the 3D scene costs the closed loop, per MPC step.

The same closed-loop walk (``simulate``'s baseline on the configured plant: the soft plant
``plant=cosserat`` by default, the robot the scene draws; ``slot bench scene plant=ideal`` for
the ideal plant, a loop about 20 times faster and so the worst case for any logging) is run in
turns, so that load on the machine hits every variant alike: not logged (for scale), logged with
the numbers only (the scene switched off), with numbers and scene (what every run does now), and
with numbers, scene and a live view that no client is connected to (what ``live=true`` and
``slot hardware`` add when nobody watches). Each MPC step is timed from the end of the previous
one (controller, plant, logging: the whole step); the first step of each run is left out
(one-off setup). ``extra.overhead_pct`` is a variant's extra median step time over the
numbers-only run's in the same pass, the median over the passes (``overhead_us`` the same in
microseconds; ``overhead_range_pct`` the passes' spread): a pass's runs follow one another, so
this pairing takes out most of the machine's drift, which moves single runs by about as much as
the scene costs. The scene's goal is < 10 %. ``overhead_mean_pct`` compares means instead: the
log compresses a chunk every few dozen steps, and the median step does not see that.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..config import SlotConfig
from ..record import Recorder
from ..simulation import run_closed_loop
from ..telemetry import Tee
from . import BenchRow, register

PASSES = 12
DURATION_S = {"ideal": 10.0, "cosserat": 3.0}  # s of walking per run (300 and 90 steps)
GOAL_PCT = 10.0


class _NumbersOnly(Recorder):
    """The log without the scene: :func:`slotexp.simulation.scene_track` draws for sinks with ``write_scene``."""

    write_scene = None  # type: ignore[assignment]


def _timed_run(cfg: SlotConfig, duration: float, path: Path, variant: str) -> tuple[np.ndarray, int]:
    """Per-step wall times (s) of one logged run, and the log's size in bytes."""
    stamps: list[float] = []

    def progress(done: int, total: int) -> None:
        stamps.append(time.perf_counter())

    scenario = cfg.scenarios["baseline"]
    if variant == "none":
        start = time.perf_counter()
        run_closed_loop(cfg, scenario, duration, None, progress)
        return np.diff(np.array([start, *stamps]))[1:], 0
    if variant == "numbers":
        with _NumbersOnly(path) as rec:
            start = time.perf_counter()
            run_closed_loop(cfg, scenario, duration, rec, progress)
    elif variant == "scene":
        with Recorder(path) as rec:
            start = time.perf_counter()
            run_closed_loop(cfg, scenario, duration, rec, progress)
    else:
        from ..live import LiveView

        with Recorder(path) as rec, LiveView(port=0) as view:
            start = time.perf_counter()
            run_closed_loop(cfg, scenario, duration, Tee(rec, view), progress)
    steps = np.diff(np.array([start, *stamps]))
    return steps[1:], path.stat().st_size


@register(overrides=["plant=cosserat"])
def bench_scene(cfg: SlotConfig, out_dir: Path) -> list[BenchRow]:
    out_dir.mkdir(parents=True, exist_ok=True)
    duration = DURATION_S.get(cfg.plant.name, 3.0)
    variants = {
        "none": "no log (for scale)",
        "numbers": "log: numbers only",
        "scene": "log: numbers + scene",
        "live": "log: numbers + scene + live view, no client",
    }
    times: dict[str, list[np.ndarray]] = {v: [] for v in variants}
    sizes: dict[str, int] = {}
    _timed_run(cfg, 0.2, out_dir / "scene_warmup.mcap", "live")  # JIT/cache loads and imports, not timed
    for _ in range(PASSES):
        for v in variants:
            t, size = _timed_run(cfg, duration, out_dir / f"scene_{v}.mcap", v)
            times[v].append(t)
            sizes[v] = size
    for p in out_dir.glob("scene_*.mcap"):
        p.unlink()
    base = float(np.median(np.concatenate(times["numbers"])))
    base_mean = float(np.mean(np.concatenate(times["numbers"])))
    rows = []
    for v, label in variants.items():
        t = np.concatenate(times[v])
        med = float(np.median(t))
        paired = [(np.median(a), np.median(b)) for a, b in zip(times[v], times["numbers"])]
        extra_us = [1e6 * (a - b) for a, b in paired]
        extra_pct = [100.0 * (a - b) / b for a, b in paired]
        overhead = float(np.median(extra_pct))
        rows.append(
            BenchRow(
                "scene",
                f"{cfg.plant.name}: {label}",
                med * 1e6,
                float(np.quantile(t, 0.99)) * 1e6,
                base / med,
                {
                    "overhead_pct": overhead,
                    "overhead_us": float(np.median(extra_us)),
                    "overhead_range_pct": [float(min(extra_pct)), float(max(extra_pct))],
                    "passes": PASSES,
                    "overhead_mean_pct": 100.0 * (float(np.mean(t)) - base_mean) / base_mean,
                    "goal_pct": GOAL_PCT,
                    "within_goal": bool(overhead < GOAL_PCT),
                    "mean_step_us": float(np.mean(t)) * 1e6,
                    "steps_timed": int(t.size),
                    "log_bytes": sizes[v],
                    "duration_s": duration,
                },
            )
        )
    return rows
