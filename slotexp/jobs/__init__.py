"""Experiments: each wires config -> plant/controller -> MCAP logs -> tables and figures.

One registry (``experiment=<name>``): an experiment is one module here, named after
it, that defines its schema (a dataclass, with an optional ``check(cfg)`` for rules
that span the whole config) and registers an :class:`Experiment` with ``run`` and
``report``, plus its ``conf/experiment/<name>.yaml``. ``slot run`` dispatches to
``run``; ``slot figures`` rebuilds a run's outputs with ``report`` from the config
stored in its log.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..config import SlotConfig
from ..registry import Registry


@dataclass(frozen=True)
class Experiment:
    schema: type  # dataclass of the ``experiment`` config node
    run: Callable[[SlotConfig, Path, str], None]  # (checked config, output dir, resolved YAML)
    report: Callable[[Path, SlotConfig], object]  # rebuild tables and figures from the run's logs
    root_schema: type = SlotConfig  # the whole config's schema (hardware runs differ)
    command: str = "slot run"  # the command that runs it
    walks_gait: bool = False  # it drives the robot with the gait command (gait.velocity, gait.yaw_rate)
    summary: str | None = None  # an output printed when the run ends (a markdown table), before its directory


EXPERIMENTS: Registry[Experiment] = Registry(__name__, "experiment")


def run_names() -> tuple[str, ...]:
    """Experiments that ``slot run experiment=<name>`` runs."""
    return tuple(name for name, e in EXPERIMENTS.load_all().items() if e.command == "slot run")


def run_experiment(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    """Run the experiment ``cfg.experiment`` names."""
    EXPERIMENTS.get(cfg.experiment.name).run(cfg, out_dir, resolved_yaml)
