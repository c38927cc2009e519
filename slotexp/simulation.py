"""Closed loop: plant <-> controller for one scenario, streaming every step to a sink.

The loop knows nothing of files: a :class:`Sink` (the MCAP recorder, in practice)
receives one set of messages per MPC step, so an interrupted run has already
handed over everything up to the interruption.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .config import ScenarioConfig, SlotConfig
from .controllers import make_controller
from .errors import RunFailedError
from .plants import make_plant, nominal_state
from .reference import desired_path, reference
from .robot import build_robot
from .scenarios import advance, perturbations
from .signals import interrupts_between_steps
from .telemetry import Sink, StepRecord, log_step, scene_track


@dataclass
class RunSummary:
    scenario: str
    steps: int
    infeasible_steps: int
    sim_time_s: float
    wall_time_s: float
    plant_wall_s: float = 0.0  # of which stepping the plant (the rest: controller, MPC, reference, log)


def scenario_seed(base: int, name: str) -> int:
    """A per-scenario seed that does not depend on which other scenarios run."""
    return (int(base) * 1_000_003 + zlib.crc32(name.encode())) % (2**32)


def run_closed_loop(
    cfg: SlotConfig,
    scenario: ScenarioConfig,
    duration: float,
    sink: Sink | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RunSummary:
    with interrupts_between_steps() as check_interrupt:  # a stop signal during setup is taken before the loop
        robot = build_robot(cfg.robot)
        x0 = nominal_state(robot) + np.asarray(scenario.offset.as_array())
        plant = make_plant(cfg, robot, x0)  # compiles (or loads) the plant's kernels
        check_interrupt()
        controller = make_controller(cfg, robot)
        period = controller.period
        n_steps = int(round(duration * cfg.mpc.rate_hz))
        rng = np.random.default_rng(scenario_seed(cfg.sim.seed, scenario.name))
        acting = perturbations(scenario)
        q_diag = np.asarray(cfg.mpc.q_diag)
        names = list(robot.names)
        started = time.perf_counter()
        done = 0
        plant_wall = 0.0
        origin = x0[3:5].copy()  # the desired path starts where the robot does
        scene = scene_track(sink, names, cfg.robot.torso)
        for k in range(n_steps):
            check_interrupt()
            t = k * period
            x_true = plant.state()
            if not np.all(np.isfinite(x_true)):
                raise RunFailedError(
                    f"the state went non-finite at t = {t:.4g} s ({scenario.name}): the log up to there is readable; "
                    f"check the scenario's offsets and impulses and the plant's sim.dt"
                )
            x_meas = (
                x_true + rng.normal(0.0, scenario.noise.measurement_sigma, 12)
                if scenario.noise.measurement_sigma > 0
                else x_true
            )
            feet = plant.feet()
            step = controller.step(t, x_meas, feet)
            if sink is not None:  # the reference at this instant is only for the log
                x_ref_now = reference(x_true, t, cfg.gait, period, 1, start=0)[0]
                x_ref_now[3:5] = desired_path(origin, cfg.gait, np.array([t]))[0]
                position, quaternion = plant.pose()
                record = StepRecord(
                    t,
                    x_true,
                    x_meas,
                    x_ref_now,
                    step,
                    controller.infeasible_steps,
                    plant.markers(),
                    position,
                    quaternion,
                    names,
                    q_diag,
                    plant.legs,
                )
                log_step(sink, record, scene)
                for topic, message in plant.telemetry().items():
                    sink.write(topic, t, message)
            plant_start = time.perf_counter()
            advance(plant, step.command, t, period, acting, rng)
            plant_wall += time.perf_counter() - plant_start
            done = k + 1
            if progress is not None:
                progress(done, n_steps)
    if done > 0 and controller.infeasible_steps == done:
        raise RunFailedError(
            f"the MPC found no feasible plan in any of the {done} steps of {scenario.name} (the fallback forces were "
            f"applied throughout): check mpc.f_max, mpc.f_min_stance, the gait's stance legs and solver.time_limit_s"
        )
    return RunSummary(
        scenario=scenario.name,
        steps=done,
        infeasible_steps=controller.infeasible_steps,
        sim_time_s=done * period,
        wall_time_s=time.perf_counter() - started,
        plant_wall_s=plant_wall,
    )
