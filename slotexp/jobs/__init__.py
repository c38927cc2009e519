"""Experiments: each wires config -> plant/controller -> MCAP logs -> tables and figures."""

from __future__ import annotations

from pathlib import Path

from ..config import (CalibrateExperiment, LegExperiment, PerturbExperiment, SimulateExperiment, SlotConfig,
                      ValidateExperiment)


def run_experiment(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    """Dispatch on the experiment's schema type."""
    from . import calibrate, leg, perturb, simulate, validate

    exp = cfg.experiment
    if isinstance(exp, PerturbExperiment):
        perturb.run(cfg, out_dir, resolved_yaml)
    elif isinstance(exp, SimulateExperiment):
        simulate.run(cfg, out_dir, resolved_yaml)
    elif isinstance(exp, ValidateExperiment):
        validate.run(cfg, out_dir, resolved_yaml)
    elif isinstance(exp, LegExperiment):
        leg.run(cfg, out_dir, resolved_yaml)
    elif isinstance(exp, CalibrateExperiment):
        calibrate.run(cfg, out_dir, resolved_yaml)
    else:  # pragma: no cover - validate() rejects this first
        raise TypeError(f"unknown experiment type {type(exp).__name__}")
