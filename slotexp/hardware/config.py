"""Typed schemas for ``slot hardware``: the servo bus, the odometry source, the run.

Same rules as :mod:`slotexp.config`: Hydra merges ``conf/hardware_config.yaml`` (and
the ``hardware`` and ``odometry`` groups) onto these dataclasses, so unknown keys and
wrong types fail while composing; :func:`validate_hardware` then checks the declared
ranges and the cross-field rules, so a bad value stops the run with one line before
the serial port is even opened.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ..composition import validate
from ..config import ConfigError, SlotConfig, choice_field, num_field, vec_field
from .xl430 import DEG_PER_TICK, MAX_TICK, MODEL_NUMBER, WATCHDOG_MAX_UNITS, WATCHDOG_UNIT_MS

__all__ = [
    "HardwareConfig",
    "OdometryConfig",
    "HardwareExperiment",
    "HardwareSlotConfig",
    "SUPPORTED_BAUDRATES",
    "validate_hardware",
    "load_hardware_config",
    "register_hardware_schemas",
]

# Rates both the XL430 (Baud Rate item, address 8) and dynamixel-sdk's PortHandler accept.
SUPPORTED_BAUDRATES = (9600, 57600, 115200, 1000000, 2000000, 3000000, 4000000)
ZMQ_SCHEMES = ("tcp://", "ipc://", "inproc://")


@dataclass
class HardwareConfig:
    """Four XL430-W250 servos on one Protocol 2.0 bus behind a U2D2.

    Per-servo lists are in ``robot.leg.names`` order (FL, RL, RR, FR). A tendon angle
    theta (deg, from the controller) becomes the servo position
    ``zero_offset_deg + direction * theta`` in servo-horn degrees, i.e.
    ``round((zero_offset_deg + direction * theta) * 4096 / 360)`` XL430 ticks, the
    position clamped to [min_position_deg, max_position_deg]. These four are the robot's
    horn map (``robot.servo.horn_*``, :class:`slotexp.soft.servo.HornMap`), which the
    simulation shares: they come from there, and a value that differs is refused.
    """

    name: str = "xl430"
    port: str = "/dev/ttyUSB0"
    baudrate: int = 1000000
    model_number: int = num_field(MODEL_NUMBER, lo=0, hi=65535, unit="")  # XL430-W250
    ids: list[int] = vec_field([1, 2, 3, 4], length=4, lo=0, hi=252, unit="")
    direction: list[int] = vec_field([1, 1, 1, 1], length=4, lo=-1, hi=1, unit="")
    zero_offset_deg: list[float] = vec_field([130.0] * 4, length=4, lo=0.0, hi=360.0, unit="deg")
    min_position_deg: list[float] = vec_field([130.0] * 4, length=4, lo=0.0, hi=360.0, unit="deg")
    max_position_deg: list[float] = vec_field([250.0] * 4, length=4, lo=0.0, hi=360.0, unit="deg")
    profile_velocity_rpm: float = num_field(57.0, lo=0.0, hi=61.0, unit="rpm")  # robot.servo's; 0: no profile
    watchdog_ms: int = num_field(100, lo=0, hi=WATCHDOG_MAX_UNITS * WATCHDOG_UNIT_MS, unit="ms")  # 0: off
    rate_hz: float = num_field(30.0, lo=0.0, lo_open=True, hi=1000.0, unit="Hz")
    comm_retries: int = num_field(3, lo=0, hi=20, unit="")
    error_check_every: int = num_field(15, lo=1, hi=100000, unit="cycles")
    write_position_limits: bool = True


@dataclass
class OdometryConfig:
    """Where the state estimate comes from (Algorithm 1, lines 6-14)."""

    source: str = choice_field("zmq", "zmq", "replay", "sim")
    endpoint: str = "tcp://127.0.0.1:5556"
    bind: bool = False
    max_age_s: float = num_field(0.2, lo=0.0, lo_open=True, hi=10.0, unit="s")
    startup_timeout_s: float = num_field(5.0, lo=0.0, lo_open=True, hi=600.0, unit="s")
    path: str | None = None  # replay: a run directory or .mcap log whose /state is replayed


@dataclass
class HardwareExperiment:
    """Names the run in logs and output paths; the settings live in ``hardware``/``odometry``."""

    name: str = "hardware"


@dataclass
class HardwareSlotConfig(SlotConfig):
    """A live run: the simulation config (robot, gait, solver, mpc, plant) plus the robot's I/O."""

    hardware: HardwareConfig = field(default_factory=HardwareConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    duration: float | None = num_field(None, lo=0.0, lo_open=True, unit="s")  # None: until Ctrl-C
    dry_run: bool = False
    live: bool = True  # on the robot the live view is on unless live=false (slotexp/live.py)
    experiment: Any = field(default_factory=HardwareExperiment)


def _ticks(deg: float) -> float:
    return deg / DEG_PER_TICK


def validate_hardware(cfg: HardwareSlotConfig) -> HardwareSlotConfig:
    """Ranges (via :func:`slotexp.composition.validate`) and the hardware's cross-field rules."""
    cfg = validate(cfg)
    hw, od = cfg.hardware, cfg.odometry
    servo = cfg.robot.servo
    for key, shared in (
        ("zero_offset_deg", "horn_zero_deg"),
        ("direction", "horn_direction"),
        ("min_position_deg", "horn_min_deg"),
        ("max_position_deg", "horn_max_deg"),
    ):
        if [float(v) for v in getattr(hw, key)] != [float(v) for v in getattr(servo, shared)]:
            raise ConfigError(
                f"hardware.{key} = {getattr(hw, key)} differs from robot.servo.{shared} = {getattr(servo, shared)}: "
                f"the horn map is shared with the simulation, set robot.servo.{shared} instead"
            )
    if hw.baudrate not in SUPPORTED_BAUDRATES:
        raise ConfigError(
            f"hardware.baudrate = {hw.baudrate} is not supported: choose one of "
            f"{', '.join(map(str, SUPPORTED_BAUDRATES))}"
        )
    if len(set(hw.ids)) != len(hw.ids):
        raise ConfigError(f"hardware.ids = {hw.ids} repeats an ID: each leg needs its own servo ID")
    for i, d in enumerate(hw.direction):
        if d not in (1, -1):
            raise ConfigError(f"hardware.direction[{i}] = {d} is not supported: use 1 or -1")
    for i, leg in enumerate(cfg.robot.leg.names):
        lo, hi = hw.min_position_deg[i], hw.max_position_deg[i]
        if not lo < hi:
            raise ConfigError(
                f"hardware.min_position_deg[{i}] = {lo:g} must be below max_position_deg[{i}] = {hi:g} ({leg})"
            )
        if _ticks(hi) > MAX_TICK:
            raise ConfigError(
                f"hardware.max_position_deg[{i}] = {hi:g} is beyond the XL430's position range "
                f"(<= {MAX_TICK * DEG_PER_TICK:.3f} deg = {MAX_TICK} ticks)"
            )
    period_ms = 1000.0 / hw.rate_hz
    if not math.isclose(hw.rate_hz, cfg.mpc.rate_hz, rel_tol=1e-9):
        raise ConfigError(
            f"hardware.rate_hz = {hw.rate_hz:g} differs from mpc.rate_hz = {cfg.mpc.rate_hz:g}: "
            f"the MPC model is discretised at mpc.rate_hz, set both (or only mpc.rate_hz)"
        )
    if hw.watchdog_ms:
        if hw.watchdog_ms % WATCHDOG_UNIT_MS:
            raise ConfigError(
                f"hardware.watchdog_ms = {hw.watchdog_ms} is not a multiple of {WATCHDOG_UNIT_MS} ms "
                f"(the XL430 Bus Watchdog unit)"
            )
        if hw.watchdog_ms < 2 * period_ms:
            raise ConfigError(
                f"hardware.watchdog_ms = {hw.watchdog_ms} is shorter than two loop periods "
                f"({2 * period_ms:.1f} ms): ordinary jitter would stop the servos"
            )
    if od.source == "zmq" and not od.endpoint.startswith(ZMQ_SCHEMES):
        raise ConfigError(
            f"odometry.endpoint = {od.endpoint!r} is not a ZeroMQ address: use e.g. "
            f"tcp://127.0.0.1:5556 or ipc:///tmp/odom"
        )
    if od.source == "replay" and not od.path:
        raise ConfigError("odometry.path is not set: pass odometry.path=<run dir or .mcap log> to replay")
    return cfg


def load_hardware_config(cfg: Any) -> HardwareSlotConfig:
    """Composed DictConfig -> checked dataclasses (the ``slot hardware`` counterpart of ``load_config``)."""
    from omegaconf import OmegaConf

    obj = OmegaConf.to_object(cfg)
    if not isinstance(obj, HardwareSlotConfig):  # pragma: no cover - the primary config names the schema
        raise ConfigError("the hardware config did not compose onto its schema (hardware_schema)")
    return validate_hardware(obj)


def register_hardware_schemas() -> None:
    """Store the root schema of ``conf/hardware_config.yaml`` in Hydra's ConfigStore (the CLI calls this)."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(name="hardware_schema", node=HardwareSlotConfig)
