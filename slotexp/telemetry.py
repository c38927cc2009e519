"""The run log's contract: every topic a closed-loop run writes, what it holds, and the writer of one step.

Simulation (:func:`slotexp.simulation.run_closed_loop`) and the robot
(:mod:`slotexp.hardware.loop`) write the same per-step messages through
:func:`log_step`; plants add their own (:meth:`Plant.telemetry`, the ``LEGS_*`` and
``TORSO_CONTACT`` topics), the hardware loop its servos and timing. Readers (the run
tables, figures, summaries, benchmarks) name topics by these constants, so a topic is
renamed in one place. The sink is anything with ``write``/``write_pose`` (the MCAP
recorder, the live view, :class:`Tee` of both); this module imports no MCAP code.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from .metrics import stage_cost
from .scene import SceneFrame, SceneTrack

if TYPE_CHECKING:
    from .controllers import ControlStep

# --------------------------------------------------------------------------- topics
POSE = "/torso/pose"  # foxglove.PoseInFrame: the torso's pose (the scene's and the 3D panel's)
STATE = "/state"
STATE_MEASURED = "/state_measured"
REFERENCE = "/reference"
COST = "/cost"
FORCES = "/forces"
CONTACT = "/contact"
TENDON = "/tendon"
MPC_STATS = "/mpc/stats"
MPC_PLAN = "/mpc/plan"
CONSTRAINTS = "/constraints"
MARKERS = "/markers"
CONTROLLER = "/controller"
# a plant's own (Plant.telemetry)
LEGS_SHAPE = "/legs/shape"
LEGS_TENDON = "/legs/tendon"
LEGS_CONTACT = "/legs/contact"
LEGS_ROOT = "/legs/root"
TORSO_CONTACT = "/torso/contact"
RIGID = "/rigid"
# the robot's loop (slot hardware)
SERVOS = "/servos"
LOOP = "/loop"

STATE_FIELDS = ("rpy", "p", "omega", "v")  # a 12-state's message: 3 numbers each
_STATE = "rpy, p, omega, v (3 each: roll-pitch-yaw rad, position m, body rate rad/s, velocity m/s)"
TOPICS: dict[str, str] = {
    POSE: "position (m), orientation (quaternion): the torso in the world",
    STATE: f"the true state (the state estimate on the robot): {_STATE}",
    STATE_MEASURED: f"the state the controller saw (with measurement noise): {_STATE}",
    REFERENCE: f"the reference at the same time: {_STATE}",
    COST: "stage: the MPC's stage cost of the state against the reference",
    FORCES: "applied (4, 3) N (sent; the soft plant takes tendon angles), planned (4, 3) N, legs: their names",
    CONTACT: "stance (4), mu (4), fz_max (4): the plan's first step",
    TENDON: "command_deg (4): the tendon angles commanded",
    MPC_STATS: "status, success, fallback, iterations, solve_time_s, wall_time_s, objective, infeasible_total",
    MPC_PLAN: "fz (horizon, 4) N, predicted_p (horizon, 3) m",
    CONSTRAINTS: "one number per constraint group: its largest violation (N)",
    MARKERS: "a marker's world position (3) each: com and the plant's own",
    CONTROLLER: "the controller's own telemetry (a gait's phase, footholds, ...)",
    LEGS_SHAPE: "per leg (by name): its nodes' world positions (N, 3), root to foot",
    LEGS_TENDON: "tension_n (4), servo_deg (4), command_deg (4)",
    LEGS_CONTACT: "normal_n (4), friction_n (4), lateral_m (4): each leg's ground contact",
    LEGS_ROOT: "force_n (4, 3), moment_nm (4, 3): each leg's load on the torso",
    TORSO_CONTACT: "normal_n, friction_n (2): the torso's underside on the ground",
    RIGID: "joint_torque, joint_angle: the rigid robot's joints",
    SERVOS: "goals and readings of every servo (ticks, degrees, tendon degrees), errors, retries",
    LOOP: "cycle timing: cycle_time_s, read_s, solve_s, write_s, lateness_s, overruns, odometry age",
}


def state_message(x: np.ndarray) -> dict[str, Any]:
    """A 12-state as its message (:data:`STATE`'s fields, :data:`STATE_FIELDS`)."""
    return {name: x[3 * i : 3 * i + 3] for i, name in enumerate(STATE_FIELDS)}


# --------------------------------------------------------------------------- sinks
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


# --------------------------------------------------------------------------- one step
@dataclass(frozen=True)
class StepRecord:
    """What one MPC step logs. ``x_true`` is the best available state (the plant's in simulation, the
    state estimate on the robot); the cost is evaluated on it. ``leg_nodes()`` gives the legs (4, N, 3),
    root to foot, for the 3D scene (called only when a scene is drawn)."""

    t: float
    x_true: np.ndarray
    x_meas: np.ndarray
    x_ref: np.ndarray
    step: ControlStep
    infeasible_total: int
    markers: Mapping[str, np.ndarray]
    position: np.ndarray
    quaternion_wxyz: np.ndarray
    legs: list[str]
    q_diag: np.ndarray
    leg_nodes: Callable[[], np.ndarray] | None = None


def log_step(sink: Sink, record: StepRecord, scene: SceneTrack | None = None) -> None:
    """One MPC step's messages: the log schema shared by simulation and hardware runs. With a ``scene``
    builder the step's 3D scene goes to ``sink.write_scene`` too, the applied forces (:data:`FORCES`)
    drawn at each leg's last node, the foot."""
    r = record
    t, step = r.t, r.step
    sol = step.solution
    sink.write_pose(t, r.position, r.quaternion_wxyz)
    sink.write(STATE, t, state_message(r.x_true))
    sink.write(STATE_MEASURED, t, state_message(r.x_meas))
    sink.write(REFERENCE, t, state_message(r.x_ref))
    sink.write(COST, t, {"stage": float(stage_cost(r.x_true, r.x_ref, r.q_diag))})
    sink.write(FORCES, t, {"applied": step.forces, "planned": sol.forces, "legs": r.legs})
    sink.write(
        CONTACT,
        t,
        {"stance": step.plan.stance[0].astype(float), "mu": step.plan.mu[0], "fz_max": step.plan.fz_max[0]},
    )
    sink.write(TENDON, t, {"command_deg": step.tendon_deg})
    sink.write(
        MPC_STATS,
        t,
        {
            "status": sol.status,
            "success": sol.success,
            "fallback": step.fallback,
            "iterations": sol.iterations,
            "solve_time_s": sol.solve_time_s,
            "wall_time_s": sol.wall_time_s,
            "objective": sol.objective,
            "infeasible_total": r.infeasible_total,
        },
    )
    sink.write(MPC_PLAN, t, {"fz": sol.plan_fz, "predicted_p": sol.predicted[:, 3:6]})
    sink.write(CONSTRAINTS, t, step.violations)
    sink.write(MARKERS, t, dict(r.markers))
    if step.telemetry:
        sink.write(CONTROLLER, t, step.telemetry)
    if scene is not None and r.leg_nodes is not None:
        footholds = (step.telemetry or {}).get("foothold")  # a controller that plans footholds reports them
        frame = scene.frame(t, r.position, r.quaternion_wxyz, r.x_ref[3:6], r.leg_nodes(), step.forces, footholds)
        sink.write_scene(frame)
