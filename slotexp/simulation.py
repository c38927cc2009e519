"""Closed loop: plant <-> controller for one scenario, streaming every step to a sink.

The loop knows nothing of files: a :class:`Sink` (the MCAP recorder, in practice)
receives one set of messages per MPC step, so an interrupted run has already
handed over everything up to the interruption.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Protocol

import numpy as np

from .config import ScenarioConfig, SlotConfig
from .controller import Controller, ControlStep
from .metrics import stage_cost
from .plant import IdealPlant, Plant, nominal_state
from .reference import reference
from .robot import RobotModel, build_robot


class Sink(Protocol):
    def write(self, topic: str, t: float, message: Mapping[str, Any]) -> None: ...

    def write_pose(self, t: float, position: Any, quaternion_wxyz: Any) -> None: ...


@dataclass
class RunSummary:
    scenario: str
    steps: int
    infeasible_steps: int
    sim_time_s: float
    wall_time_s: float


def make_plant(cfg: SlotConfig, robot: RobotModel, x0: np.ndarray) -> Plant:
    if cfg.plant.name == "ideal":
        return IdealPlant(robot, x0, cfg.sim.gravity, cfg.sim.dt)
    if cfg.plant.name == "cosserat":
        from .cosserat import CosseratPlant

        return CosseratPlant(cfg, robot, x0)
    raise ValueError(f"unknown plant {cfg.plant.name!r}")


def scenario_seed(base: int, name: str) -> int:
    """A per-scenario seed that does not depend on which other scenarios run."""
    return (int(base) * 1_000_003 + zlib.crc32(name.encode())) % (2**32)


def _state_msg(x: np.ndarray) -> dict[str, Any]:
    return {"rpy": x[0:3], "p": x[3:6], "omega": x[6:9], "v": x[9:12]}


def run_closed_loop(cfg: SlotConfig, scenario: ScenarioConfig, duration: float, sink: Sink | None = None,
                    progress: Callable[[int, int], None] | None = None) -> RunSummary:
    robot = build_robot(cfg.robot)
    x0 = nominal_state(robot) + np.asarray(scenario.offset.as_array())
    plant = make_plant(cfg, robot, x0)
    controller = Controller(cfg, robot)
    period = controller.period
    n_steps = int(round(duration * cfg.mpc.rate_hz))
    rng = np.random.default_rng(scenario_seed(cfg.sim.seed, scenario.name))
    impulses = sorted(scenario.impulses, key=lambda imp: imp.t)
    q_diag = np.asarray(cfg.mpc.q_diag)
    names = list(robot.names)
    started = time.perf_counter()
    done = 0
    p_des = x0[3:5].copy()  # desired path in the plane: the reference velocity integrated from the start
    for k in range(n_steps):
        t = k * period
        x_true = plant.state()
        x_meas = x_true + rng.normal(0.0, scenario.noise.measurement_sigma, 12) \
            if scenario.noise.measurement_sigma > 0 else x_true
        feet = plant.feet()
        step = controller.step(t, x_meas, feet)
        x_ref_now = reference(x_true, t, cfg.gait, period, 1, start=0)[0]
        x_ref_now[3:5] = p_des
        p_des = p_des + period * x_ref_now[9:11]
        if sink is not None:
            position, quaternion = plant.pose()
            log_step(sink, t, x_true, x_meas, x_ref_now, step, controller.infeasible_steps, plant.markers(),
                     position, quaternion, names, q_diag)
            for topic, message in plant.telemetry().items():
                sink.write(topic, t, message)
        _advance(plant, step, t, period, impulses, scenario, rng)
        done = k + 1
        if progress is not None:
            progress(done, n_steps)
    return RunSummary(scenario=scenario.name, steps=done, infeasible_steps=controller.infeasible_steps,
                      sim_time_s=done * period, wall_time_s=time.perf_counter() - started)


def log_step(sink: Sink, t: float, x_true: np.ndarray, x_meas: np.ndarray, x_ref_now: np.ndarray,
             step: ControlStep, infeasible_total: int, markers: Mapping[str, np.ndarray], position: np.ndarray,
             quaternion_wxyz: np.ndarray, legs: list[str], q_diag: np.ndarray) -> None:
    """One MPC step's messages: the log schema shared by simulation and hardware runs.

    ``x_true`` is the best available state (the plant's in simulation, the state
    estimate on hardware); the cost is evaluated on it.
    """
    sol = step.solution
    sink.write_pose(t, position, quaternion_wxyz)
    sink.write("/state", t, _state_msg(x_true))
    sink.write("/state_measured", t, _state_msg(x_meas))
    sink.write("/reference", t, _state_msg(x_ref_now))
    sink.write("/cost", t, {"stage": float(stage_cost(x_true, x_ref_now, q_diag))})
    sink.write("/forces", t, {"applied": step.forces, "planned": sol.forces, "legs": legs})
    sink.write("/contact", t, {"stance": step.plan.stance[0].astype(float), "mu": step.plan.mu[0],
                               "fz_max": step.plan.fz_max[0]})
    sink.write("/tendon", t, {"command_deg": step.tendon_deg})
    sink.write("/mpc/stats", t, {
        "status": sol.status, "success": sol.success, "fallback": step.fallback,
        "iterations": sol.iterations, "solve_time_s": sol.solve_time_s,
        "wall_time_s": sol.wall_time_s, "objective": sol.objective,
        "infeasible_total": infeasible_total})
    sink.write("/mpc/plan", t, {"fz": sol.plan_fz, "predicted_p": sol.predicted[:, 3:6]})
    sink.write("/constraints", t, step.violations)
    sink.write("/markers", t, dict(markers))


def _advance(plant: Plant, step: ControlStep, t: float, period: float, impulses: list,
             scenario: ScenarioConfig, rng: np.random.Generator) -> None:
    """One MPC period, split exactly at any impulse that falls inside it."""
    forces, tendon = step.forces, step.tendon_deg
    sigma = scenario.noise.process_force_sigma
    f_ext = rng.normal(0.0, sigma, 3) if sigma > 0 else None
    now = t
    end = t + period
    while impulses and impulses[0].t < end - 1e-12:
        imp = impulses.pop(0)
        if imp.t > now + 1e-12:
            plant.step(forces, imp.t - now, f_ext, tendon)
            now = imp.t
        plant.apply_impulse(np.asarray(imp.linear), np.asarray(imp.angular))
    if end - now > 1e-12:
        plant.step(forces, end - now, f_ext, tendon)
