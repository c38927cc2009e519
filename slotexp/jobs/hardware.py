"""Experiment ``hardware``: a run of `slot hardware` on the robot (or against the simulator, HIL).

It is run by ``slot hardware``, not ``slot run``; registering it here lets
``slot figures`` rebuild a hardware run's metrics and figures like any other.
"""

from __future__ import annotations

from pathlib import Path

from ..config import SlotConfig
from ..errors import ConfigError
from ..hardware.config import HardwareExperiment, HardwareSlotConfig
from . import EXPERIMENTS, Experiment


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    raise ConfigError("the hardware experiment runs on the robot: use `slot hardware`")


def report(run_dir: Path, cfg: SlotConfig) -> dict:
    from ..hardware.report import report as hardware_report

    return hardware_report(run_dir, list(cfg.gait.velocity), list(cfg.robot.leg.names))


EXPERIMENTS.add(
    "hardware", Experiment(HardwareExperiment, run, report, root_schema=HardwareSlotConfig, command="slot hardware")
)
