"""``slot bench rigid``: a 10 s trot on the rigid quadruped, the MPC and the MuJoCo step timed apart.

The closed loop runs in this process without logging (the controller and the
plant called directly), BLAS pinned to one thread. Per MPC period it times:

- ``controller``: the whole controller step (gait, footstep planner, MPC update
  and solve, swing bookkeeping);
- ``mpc``: the MPC update and solve alone (the backend's own wall time);
- ``plant``: the whole plant period (MuJoCo steps plus the leg torques of every step);
- ``mujoco_step``: one MuJoCo step alone (``mj_step1`` + ``mj_step2``), per physics step;
- ``period_total``: controller plus plant, one MPC period.

``ratio_vs_baseline`` is the MPC period (the real-time budget) over the median,
so ``period_total``'s is the real-time factor; ``extra.real_time_factor`` is
simulated time over the loop's whole wall time.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..backends._base import single_threaded_blas
from ..config import SlotConfig
from ..controllers import make_controller
from ..plants import nominal_state
from ..plants.rigid import RigidPlant
from ..robot import build_robot
from . import BenchRow, register

DURATION_S = 10.0


@register(overrides=["plant=rigid", "experiment=simulate"])
def bench_rigid(cfg: SlotConfig, out_dir: Path) -> list[BenchRow]:
    single_threaded_blas()
    robot = build_robot(cfg.robot)
    plant = RigidPlant(cfg, robot, nominal_state(robot))
    controller = make_controller(cfg, robot)
    period = controller.period
    n = int(round(DURATION_S / period))
    substeps = max(1, int(round(period / plant.dt)))
    times = {k: np.empty(n) for k in ("controller", "mpc", "plant", "mujoco_step", "period_total")}
    started = time.perf_counter()
    for k in range(n):
        t0 = time.perf_counter()
        step = controller.step(k * period, plant.state(), plant.feet())
        t1 = time.perf_counter()
        mujoco_before = plant.mujoco_time_s
        plant.step(step.command, period)
        t2 = time.perf_counter()
        times["controller"][k] = t1 - t0
        times["mpc"][k] = step.solution.wall_time_s
        times["plant"][k] = t2 - t1
        times["mujoco_step"][k] = (plant.mujoco_time_s - mujoco_before) / substeps
        times["period_total"][k] = t2 - t0
    wall = time.perf_counter() - started
    x = plant.state()
    extra = {
        "robot": cfg.robot.name,
        "gait": cfg.gait.name,
        "solver": cfg.solver.name,
        "sim_dt_s": plant.dt,
        "mpc_period_s": period,
        "sim_time_s": DURATION_S,
        "wall_time_s": wall,
        "real_time_factor": DURATION_S / wall,
        "mpc_share_of_wall": float(times["mpc"].sum() / wall),
        "mujoco_share_of_wall": float(times["mujoco_step"].sum() * substeps / wall),
        "infeasible_steps": controller.infeasible_steps,
        "distance_m": float(np.hypot(*x[3:5])),
        "first_step_excluded": True,
    }
    rows = []
    for name, samples in times.items():
        s = samples[1:] * 1e6  # the first step (JIT cache load, solver setup) is excluded
        budget = period * 1e6 / (substeps if name == "mujoco_step" else 1)
        median = float(np.median(s))
        rows.append(BenchRow("rigid", name, median, float(np.percentile(s, 99)), budget / median, dict(extra)))
    return rows
