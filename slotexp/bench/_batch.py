"""Batch throughput of the soft plant: robot-seconds simulated per wall second.

Kept apart from :mod:`.leg` (whose accuracy cases need the controllers, the signal
handling and the QP solvers) so that it imports only the numerical core: numpy,
numba and the soft plant. It then runs on a machine that has only those, e.g. a
many-core node, from the package's source and a pickled config
(``scripts/batch_throughput.py``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np

from ..config import SlotConfig
from ..plants import TendonCommand, nominal_state
from ..plants.cosserat import CosseratBatch, CosseratPlant
from ..robot import build_robot

BATCH_SIZES = (1, 8, 64)
BATCH_S = 2.0  # s simulated per robot
ALONE_AT_MOST = 8  # robots stepped one after another for comparison (the cost is linear in their number)


@dataclass(frozen=True)
class BatchThroughput:
    """One batch size: the per-step wall times and robot-seconds per wall second, batched and one after another."""

    robots: int
    step_wall_s: np.ndarray  # wall time of each control period's batch step
    robot_seconds_per_wall_second: float
    one_after_another_robot_seconds_per_wall_second: float
    threads: int
    simulated_s_per_robot: float


def batch_throughput(
    cfg: SlotConfig, sizes: tuple[int, ...] = BATCH_SIZES, seconds: float = BATCH_S
) -> list[BatchThroughput]:
    """Step B robots of ``cfg`` together for ``seconds`` each, every robot walking the library's fastest
    primitive of the configured style at its own phase (b / B of a cycle), for each B in ``sizes``.

    The kernel is compiled (or loaded from numba's cache) before anything is timed.
    """
    from ..locomotion.primitives import GaitStyle, Primitive, mix

    robot = build_robot(cfg.robot)
    style_cfg = cfg.controller.library[cfg.gait.style]
    style = GaitStyle(style_cfg.frequency_hz, style_cfg.duty, style_cfg.sharpness)
    walk = max((Primitive.from_config(p) for p in style_cfg.primitives), key=lambda p: p.speed_mps)
    top = cfg.robot.leg.tendon_max_deg
    period = 1.0 / cfg.mpc.rate_hz
    steps = int(round(seconds / period))

    def schedules(n: int, k: int) -> np.ndarray:  # (n, 4): robot b runs the gait shifted by b / n of a cycle
        return np.array([mix(style, [(1.0, walk)], k * period * style.frequency_hz + b / n, top) for b in range(n)])

    def plants(n: int) -> list[CosseratPlant]:
        return [CosseratPlant(cfg, robot, nominal_state(robot)) for _ in range(n)]

    CosseratBatch(plants(2)).step(schedules(2, 0), period)  # compile or load the batch kernel first
    results = []
    for n in sizes:
        batch = CosseratBatch(plants(n))
        per_step = np.empty(steps)
        for k in range(steps):
            start = time.perf_counter()
            batch.step(schedules(n, k), period)
            per_step[k] = time.perf_counter() - start
        alone = plants(min(n, ALONE_AT_MOST))
        start = time.perf_counter()
        for k in range(steps):
            for plant, command in zip(alone, schedules(len(alone), k)):
                plant.step(TendonCommand(command), period)
        alone_rate = len(alone) * seconds / (time.perf_counter() - start)
        results.append(
            BatchThroughput(n, per_step, n * seconds / per_step.sum(), alone_rate, numba.get_num_threads(), seconds)
        )
    return results
