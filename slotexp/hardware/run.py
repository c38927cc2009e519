"""One hardware run, wired: open and check the bus, wait for odometry, warm up, loop, torque off, log.

The order is chosen for safety. Everything that can fail on bad input (the port,
the pings, the model numbers, the servos' error status, the first odometry
message) fails before torque is ever enabled, as a :class:`~slotexp.errors.UserError`
(one line, exit 2). Once the loop runs, every way out (end of ``duration``,
Ctrl-C, SIGTERM, SIGHUP, stale odometry, bus failure, hardware error, a bug) passes
through the same ``finally``: torque off on every servo first (no further signal
interrupts it), then the log's summary, then the log is closed. The servos' bus
watchdog is a second line for what no ``finally`` survives (SIGKILL, a power cut of
the computer); the torque-off path does not rely on it.
"""

from __future__ import annotations

import copy
import datetime as _dt
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .. import __version__
from ..controllers import Controller, make_controller
from ..errors import BusError, SafetyStop
from ..live import open_view
from ..plants import TendonCommand
from ..record import Recorder
from ..robot import RobotModel, build_robot
from ..signals import STOP_SIGNALS, StopFlag, exit_code
from ..telemetry import Tee
from .bus import DynamixelBus, ServoBus
from .config import HardwareSlotConfig
from .loop import LoopOutcome, nominal_feet, run_loop
from .mapping import ServoMap
from .odometry import OdometrySample, OdometrySource, ReplayOdometry, SimOdometry, ZmqOdometry, wait_first
from .simbus import SimulatedBus, SimWorld
from .xl430 import DEG_PER_TICK

EXIT_OK = 0
EXIT_SAFETY_STOP = 3
LOG_NAME = "hardware.mcap"


@dataclass
class HardwareResult:
    exit_code: int
    message: str  # one line for stderr, "" if there is nothing to say
    log_path: Path | None
    outcome: LoopOutcome | None


def make_io(cfg: HardwareSlotConfig, robot: RobotModel, smap: ServoMap) -> tuple[ServoBus, OdometrySource]:
    """The bus and the odometry source the config names (``odometry=sim`` brings its own bus)."""
    od = cfg.odometry
    if od.source == "sim":
        world = SimWorld(cfg, robot, smap, cfg.hardware.profile_velocity_rpm)
        return SimulatedBus(world, ids=list(cfg.hardware.ids)), SimOdometry(world)
    bus = DynamixelBus(cfg.hardware, list(robot.names), smap)
    if od.source == "zmq":
        return bus, ZmqOdometry(od.endpoint, od.bind)
    return bus, ReplayOdometry(str(od.path))


def warm_up(controller: Controller, robot: RobotModel, sample: OdometrySample) -> None:
    """One throw-away step before torque-on, so the first timed cycle does not pay for solver set-up.

    Everything the step changes except the solver (gait phase, step count, last
    feasible input, counters) is put back, so the run starts as if it had not happened.
    """
    keep = ("mpc", "cfg", "robot")
    saved = {k: copy.deepcopy(v) for k, v in vars(controller).items() if k not in keep}
    controller.step(0.0, sample.state, nominal_feet(robot, sample.position, sample.quaternion))
    vars(controller).update(saved)


def _run_metadata(cfg: HardwareSlotConfig, commit: str) -> dict[str, str]:
    sim = cfg.odometry.source == "sim"
    return {
        "experiment": "hardware",
        "scenario": "hardware",
        "gait": cfg.gait.name,
        "plant": cfg.plant.name if sim else "hardware",
        "solver": cfg.solver.name,
        "bus": "simulated" if sim else "dynamixel",
        "port": "" if sim else cfg.hardware.port,
        "odometry": cfg.odometry.source,
        "dry_run": str(cfg.dry_run).lower(),
        "rate_hz": repr(cfg.hardware.rate_hz),
        "duration_s": repr(cfg.duration),
        "git_commit": commit,
        "slotexp_version": __version__,
        "started_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }


_SIGNAL_NAMES = {s.name for s in STOP_SIGNALS}


def _best_effort(notify: Callable[[str], None]) -> Callable[[str], None]:
    """``notify`` that never raises for a closed stream: after SIGHUP the terminal is gone, and writing to it
    (EIO, a broken pipe) must not stand between a stop signal and the torque-off path or the log's summary."""

    def tell(message: str) -> None:
        try:
            notify(message)
        except OSError:
            pass

    return tell


def _fmt(value: float) -> str:
    return f"{value:.6g}"


def run_hardware(
    cfg: HardwareSlotConfig,
    out_dir: Path,
    resolved_yaml: str,
    notify: Callable[[str], None] = lambda _m: None,
    commit: str = "unknown",
) -> HardwareResult:
    """Run the loop on the configured bus and odometry; write ``out_dir/logs/hardware.mcap``."""
    hw, od = cfg.hardware, cfg.odometry
    notify = _best_effort(notify)
    robot = build_robot(cfg.robot)
    smap = ServoMap.from_config(hw, cfg.robot.leg.tendon_max_deg)
    lo, hi = smap.tendon_range_deg()
    for k, leg in enumerate(robot.names):
        if lo[k] > DEG_PER_TICK or hi[k] < smap.tendon_max_deg - DEG_PER_TICK:
            notify(
                f"note: {leg}: the servo limits allow tendon angles {lo[k]:.1f}-{hi[k]:.1f} deg only "
                f"(tendon range 0-{smap.tendon_max_deg:g}): commands outside are clamped"
            )
    bus, odometry = make_io(cfg, robot, smap)
    stop = StopFlag()
    outcome = LoopOutcome.empty(hw.rate_hz)
    log_path = out_dir / "logs" / LOG_NAME
    with stop.installed():
        try:
            notes = bus.open()  # read-only checks first: nothing is written until everything answers
            odometry.start()
            first = wait_first(odometry, od.startup_timeout_s, lambda: stop.requested)
            if first is None:
                return HardwareResult(
                    exit_code(stop.signum or signal.SIGINT),
                    f"interrupted ({stop.name}) before the loop started: torque was never on",
                    None,
                    None,
                )
            for note in notes + bus.configure(cfg.dry_run):
                notify(f"note: {note}")
            controller = make_controller(cfg, robot, TendonCommand)  # the servos take tendon angles
            warm_up(controller, robot, first)
            log_path.parent.mkdir(parents=True, exist_ok=True)
            meta = {"config": {"yaml": resolved_yaml}, "run": _run_metadata(cfg, commit)}
            # the live view is on by default: a busy port costs the robot's run nothing but the view
            with (
                Recorder(log_path, metadata=meta) as rec,
                open_view(cfg.live, cfg.live_port, notify, keep_going=True) as live,
            ):
                started = time.perf_counter()
                try:
                    if not cfg.dry_run and not stop.requested:
                        bus.enable()
                    run_loop(
                        cfg,
                        robot,
                        controller,
                        bus,
                        odometry,
                        smap,
                        rec if live is None else Tee(rec, live),
                        stop,
                        rate_hz=hw.rate_hz,
                        max_age_s=od.max_age_s,
                        error_check_every=hw.error_check_every,
                        duration=cfg.duration,
                        dry_run=cfg.dry_run,
                        outcome=outcome,
                        notify=notify,
                    )
                except SafetyStop as exc:
                    outcome.stop_reason, outcome.error = exc.reason, str(exc)
                except BusError as exc:
                    outcome.stop_reason, outcome.error = "bus", f"{exc}: stopped, torque off"
                except KeyboardInterrupt:
                    outcome.stop_reason = stop.name or "SIGINT"
                finally:
                    stop.shutting_down()  # a further signal must not cut the torque-off writes short
                    problems = bus.disable()  # first, before any bookkeeping
                    if problems:
                        outcome.error = (
                            ((outcome.error + "; ") if outcome.error else "")
                            + "TORQUE MAY STILL BE ON: "
                            + "; ".join(problems)
                        )
                    _write_summary(rec, outcome, controller, bus, odometry, time.perf_counter() - started)
        finally:
            stop.shutting_down()
            bus.disable()
            bus.close()
            odometry.close()
    notify(f"hardware: {outcome.stats.one_line()}; stopped: {outcome.stop_reason}")
    if outcome.error:
        return HardwareResult(EXIT_SAFETY_STOP, outcome.error, log_path, outcome)
    if outcome.stop_reason in _SIGNAL_NAMES:
        return HardwareResult(
            exit_code(signal.Signals[outcome.stop_reason]),
            f"interrupted ({outcome.stop_reason}): torque off, the log is closed and readable",
            log_path,
            outcome,
        )
    return HardwareResult(EXIT_OK, "", log_path, outcome)


def _write_summary(
    rec: Recorder, outcome: LoopOutcome, controller: Controller, bus: ServoBus, odometry: OdometrySource, wall: float
) -> None:
    rec.add_metadata("loop", {k: _fmt(v) for k, v in outcome.stats.summary().items()})
    rec.add_metadata(
        "summary",
        {
            "steps": str(outcome.steps),
            "infeasible_steps": str(controller.infeasible_steps),
            "wall_time_s": f"{wall:.3f}",
            "stop_reason": outcome.stop_reason,
            "error": outcome.error or "",
            "clamped_cycles": ",".join(str(int(c)) for c in outcome.clamped),
            "comm_retries": str(outcome.comm_retries),
            "comm_errors": str(getattr(bus, "comm_errors", 0)),
            "odometry_bad_messages": str(odometry.bad_messages),
        },
    )
