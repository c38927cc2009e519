"""Experiment ``calibrate``: the affine force-to-tendon map of paper eq. (11), from our leg.

The root is held at the stance height (gait.height minus half the torso height)
and the tendon angle is swept up quasi-statically; at each angle the leg is
settled and the ground's total normal force on it recorded. The fit
f_z = a theta + b uses the loaded part of the sweep (f_z >= fit_min_force); the
controller inverts it as theta = (f_z - b) / a.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import write_csv, write_json, write_text
from ..config import SlotConfig, num_field
from ..errors import ConfigError
from ..record import Recorder, read_log
from ..robot import leg_root_z
from ..soft.statics import clamped_leg, set_tendon, settle
from . import EXPERIMENTS, Experiment
from ._logged import git_commit
from .leg import check_leg_load

PAPER = (0.107, -6.91)


@dataclass
class CalibrateExperiment:
    """Quasi-static sweep of tendon angle against ground normal force: theta = (f_z - b) / a."""

    name: str = "calibrate"
    angles: int = num_field(25, lo=3, hi=1000, unit="points")
    # None: robot.leg.tendon_max_deg; at most that (the tendon winds no further)
    max_deg: float | None = num_field(None, lo=0.0, lo_open=True, unit="deg")
    fit_min_force: float = num_field(0.5, lo=0.0, unit="N")  # fit only where the foot is loaded

    def check(self, cfg: SlotConfig) -> None:
        check_leg_load(cfg)
        top = cfg.robot.leg.tendon_max_deg
        if self.max_deg is not None and self.max_deg > top:
            raise ConfigError(
                f"experiment.max_deg = {self.max_deg:g} deg is out of range: must be > 0 and <= "
                f"robot.leg.tendon_max_deg = {top:g} deg"
            )


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    from rich.console import Console
    from rich.progress import Progress

    exp = cfg.experiment
    root_height = cfg.gait.height + leg_root_z(cfg.robot)
    sim = clamped_leg(cfg, root_height=root_height)
    top = exp.max_deg if exp.max_deg is not None else cfg.robot.leg.tendon_max_deg
    angles = np.linspace(0.0, top, exp.angles)
    (out_dir / "logs").mkdir(parents=True, exist_ok=True)
    meta = {
        "config": {"yaml": resolved_yaml},
        "run": {"experiment": "calibrate", "git_commit": git_commit(), "root_height_m": repr(root_height)},
    }
    settle(sim, cfg, 1.0)  # under its own weight first
    with (
        Recorder(out_dir / "logs" / "calibrate.mcap", metadata=meta) as rec,
        Progress(console=Console(stderr=True), transient=False) as bar,
    ):
        task = bar.add_task("sweep     ", total=len(angles))
        for angle in angles:
            set_tendon(sim, float(angle), cfg.robot.leg.pulley_radius)
            state = settle(sim, cfg, cfg.leg_load.settle_time / 3)
            rec.write("/calibrate/point", sim.time, {"angle_deg": float(angle), **state, "shape": sim.pos})
            bar.advance(task)
    report(out_dir, cfg)


def fit(angle: np.ndarray, fz: np.ndarray, min_force: float) -> dict:
    used = fz >= min_force
    if used.sum() < 2:
        raise ConfigError(
            f"only {int(used.sum())} sweep points load the foot above {min_force} N: "
            "raise experiment.max_deg or lower experiment.fit_min_force"
        )
    slope, offset = np.polyfit(angle[used], fz[used], 1)
    pred = slope * angle[used] + offset
    ss_res = float(np.sum((fz[used] - pred) ** 2))
    ss_tot = float(np.sum((fz[used] - fz[used].mean()) ** 2))
    return {
        "slope_n_per_deg": float(slope),
        "offset_n": float(offset),
        "r2": 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan"),
        "points_fitted": int(used.sum()),
        "angle_range_deg": [float(angle[used].min()), float(angle[used].max())],
        "used": used,
    }


def report(out_dir: Path, cfg: SlotConfig) -> dict:
    """The fit, its table, figure and ``actuation_calibrated.yaml``, from the sweep's log."""
    from ..figures.leg import plot_calibration

    min_force = cfg.experiment.fit_min_force
    df = read_log(out_dir / "logs" / "calibrate.mcap")["/calibrate/point"]
    angle = df["angle_deg"].to_numpy(float)
    fz = df["normal_force_n"].to_numpy(float)
    result = fit(angle, fz, min_force)
    used = result.pop("used")
    result["paper"] = {"slope_n_per_deg": PAPER[0], "offset_n": PAPER[1]}
    write_csv(
        df[["angle_deg", "normal_force_n", "tension_n", "tip_x", "tip_z"]],
        out_dir / "calibration.csv",
        index=False,
        float_format="%.6g",
    )
    write_json(out_dir / "calibrate.json", result)
    write_text(
        out_dir / "actuation_calibrated.yaml",
        "# @package robot.actuation\n"
        f"# Fitted by `slot run experiment=calibrate` (R^2 = {result['r2']:.4f}, "
        f"{result['angle_range_deg'][0]:.1f}-{result['angle_range_deg'][1]:.1f} deg)\n"
        f"slope_n_per_deg: {result['slope_n_per_deg']:.6g}\noffset_n: {result['offset_n']:.6g}\n",
    )
    plot_calibration(
        angle, fz, used, result["slope_n_per_deg"], result["offset_n"], PAPER, out_dir / "fig_calibrate.png"
    )
    return result


EXPERIMENTS.add("calibrate", Experiment(CalibrateExperiment, run, report))
