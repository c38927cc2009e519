"""Closed loop: plant <-> controller for one scenario, streaming every step to a sink.

The loop knows nothing of files: a :class:`Sink` (the MCAP recorder, in practice)
receives one set of messages per MPC step, so an interrupted run has already
handed over everything up to the interruption.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .config import ScenarioConfig, SlotConfig
from .controllers import ControlStep, make_controller
from .errors import RunFailedError
from .metrics import stage_cost
from .plants import Plant, command_for, make_plant, nominal_state
from .reference import desired_path, reference
from .robot import build_robot
from .scene import SceneFrame, SceneTrack
from .signals import interrupts_between_steps


class Sink(Protocol):
    def write(self, topic: str, t: float, message: Mapping[str, Any]) -> None: ...

    def write_pose(self, t: float, position: Any, quaternion_wxyz: Any) -> None: ...


class SceneSink(Sink, Protocol):
    """A sink that also takes the 3D scene (the MCAP recorder, the live view)."""

    def write_scene(self, frame: SceneFrame) -> None: ...


class Tee:
    """One sink that hands every message to several (the MCAP log and the live view)."""

    def __init__(self, *sinks: SceneSink) -> None:
        self.sinks = sinks

    def write(self, topic: str, t: float, message: Mapping[str, Any]) -> None:
        for s in self.sinks:
            s.write(topic, t, message)

    def write_pose(self, t: float, position: Any, quaternion_wxyz: Any) -> None:
        for s in self.sinks:
            s.write_pose(t, position, quaternion_wxyz)

    def write_scene(self, frame: SceneFrame) -> None:
        for s in self.sinks:
            s.write_scene(frame)


def scene_track(sink: Sink | None, legs: list[str], torso: Any) -> SceneTrack | None:
    """A scene builder when ``sink`` draws scenes (has ``write_scene``); None for numbers-only sinks. ``torso``:
    ``robot.torso`` (its box's size, and its mass centre's offset in the box)."""
    if sink is None or not callable(getattr(sink, "write_scene", None)):
        return None
    return SceneTrack(legs, torso.size, com_offset=torso.com_offset)


@dataclass
class RunSummary:
    scenario: str
    steps: int
    infeasible_steps: int
    sim_time_s: float
    wall_time_s: float


def scenario_seed(base: int, name: str) -> int:
    """A per-scenario seed that does not depend on which other scenarios run."""
    return (int(base) * 1_000_003 + zlib.crc32(name.encode())) % (2**32)


def _state_msg(x: np.ndarray) -> dict[str, Any]:
    return {"rpy": x[0:3], "p": x[3:6], "omega": x[6:9], "v": x[9:12]}


def run_closed_loop(
    cfg: SlotConfig,
    scenario: ScenarioConfig,
    duration: float,
    sink: Sink | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RunSummary:
    robot = build_robot(cfg.robot)
    x0 = nominal_state(robot) + np.asarray(scenario.offset.as_array())
    plant = make_plant(cfg, robot, x0)
    controller = make_controller(cfg, robot)
    period = controller.period
    n_steps = int(round(duration * cfg.mpc.rate_hz))
    rng = np.random.default_rng(scenario_seed(cfg.sim.seed, scenario.name))
    impulses = sorted(scenario.impulses, key=lambda imp: imp.t)
    q_diag = np.asarray(cfg.mpc.q_diag)
    names = list(robot.names)
    started = time.perf_counter()
    done = 0
    origin = x0[3:5].copy()  # the desired path starts where the robot does
    scene = scene_track(sink, names, cfg.robot.torso)
    with interrupts_between_steps() as check_interrupt:
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
            x_ref_now = reference(x_true, t, cfg.gait, period, 1, start=0)[0]
            x_ref_now[3:5] = desired_path(origin, cfg.gait, np.array([t]))[0]
            if sink is not None:
                position, quaternion = plant.pose()
                log_step(
                    sink,
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
                    scene,
                    plant.legs,
                )
                for topic, message in plant.telemetry().items():
                    sink.write(topic, t, message)
            _advance(plant, step, t, period, impulses, scenario, rng)
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
    )


def log_step(
    sink: Sink,
    t: float,
    x_true: np.ndarray,
    x_meas: np.ndarray,
    x_ref_now: np.ndarray,
    step: ControlStep,
    infeasible_total: int,
    markers: Mapping[str, np.ndarray],
    position: np.ndarray,
    quaternion_wxyz: np.ndarray,
    legs: list[str],
    q_diag: np.ndarray,
    scene: SceneTrack | None = None,
    leg_nodes: Callable[[], np.ndarray] | None = None,
) -> None:
    """One MPC step's messages: the log schema shared by simulation and hardware runs.

    ``x_true`` is the best available state (the plant's in simulation, the state
    estimate on hardware); the cost is evaluated on it. With a ``scene`` builder the
    step's 3D scene goes to ``sink.write_scene`` too: ``leg_nodes()`` gives the legs
    (4, N, 3), root to foot, and the applied forces (``/forces``) are drawn at each
    leg's last node, the foot.
    """
    sol = step.solution
    sink.write_pose(t, position, quaternion_wxyz)
    sink.write("/state", t, _state_msg(x_true))
    sink.write("/state_measured", t, _state_msg(x_meas))
    sink.write("/reference", t, _state_msg(x_ref_now))
    sink.write("/cost", t, {"stage": float(stage_cost(x_true, x_ref_now, q_diag))})
    sink.write("/forces", t, {"applied": step.forces, "planned": sol.forces, "legs": legs})
    sink.write(
        "/contact",
        t,
        {"stance": step.plan.stance[0].astype(float), "mu": step.plan.mu[0], "fz_max": step.plan.fz_max[0]},
    )
    sink.write("/tendon", t, {"command_deg": step.tendon_deg})
    sink.write(
        "/mpc/stats",
        t,
        {
            "status": sol.status,
            "success": sol.success,
            "fallback": step.fallback,
            "iterations": sol.iterations,
            "solve_time_s": sol.solve_time_s,
            "wall_time_s": sol.wall_time_s,
            "objective": sol.objective,
            "infeasible_total": infeasible_total,
        },
    )
    sink.write("/mpc/plan", t, {"fz": sol.plan_fz, "predicted_p": sol.predicted[:, 3:6]})
    sink.write("/constraints", t, step.violations)
    sink.write("/markers", t, dict(markers))
    if step.telemetry:
        sink.write("/controller", t, step.telemetry)
    if scene is not None and leg_nodes is not None:
        nodes = leg_nodes()
        footholds = (step.telemetry or {}).get("foothold")  # a controller that plans footholds reports them
        sink.write_scene(scene.frame(t, position, quaternion_wxyz, x_ref_now[3:6], nodes, step.forces, footholds))


def _advance(
    plant: Plant,
    step: ControlStep,
    t: float,
    period: float,
    impulses: list,
    scenario: ScenarioConfig,
    rng: np.random.Generator,
) -> None:
    """One MPC period, split exactly at any impulse that falls inside it."""
    if isinstance(step.command, plant.command_type):
        command = step.command
    else:
        command = command_for(plant.command_type, step.forces, step.tendon_deg)
    sigma = scenario.noise.process_force_sigma
    f_ext = rng.normal(0.0, sigma, 3) if sigma > 0 else None
    now = t
    end = t + period
    while impulses and impulses[0].t < end - 1e-12:
        imp = impulses.pop(0)
        if imp.t > now + 1e-12:
            plant.step(command, imp.t - now, f_ext)
            now = imp.t
        plant.apply_impulse(np.asarray(imp.linear), np.asarray(imp.angular))
    if end - now > 1e-12:
        plant.step(command, end - now, f_ext)
