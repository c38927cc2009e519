"""Experiment ``legmap``: the leg's quasi-static maps (eq. 11 generalised), tabulated and fitted.

See :mod:`slotexp.soft.legmap` for what is mapped. Writes ``legmap_free.csv``,
``legmap_stuck.csv``, ``legmap.json`` (each fit's coefficients, R^2, RMSE, largest
error on the grid and on held-out points between grid points) and
``fig_legmap.png``; the points go to ``logs/legmap.mcap``, from which
``slot figures`` rebuilds everything.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..atomic import write_csv, write_json
from ..config import SlotConfig, num_field, vec_field
from ..errors import ConfigError
from ..record import Recorder, read_log
from ..robot import leg_root_z
from ..soft.legmap import PolyFit, free_foot, stuck_foot
from . import EXPERIMENTS, Experiment
from ._logged import git_commit
from .leg import check_leg_load


@dataclass
class LegmapExperiment:
    """Grids and fits of the leg maps (``slotexp.soft.legmap``)."""

    name: str = "legmap"
    angles: int = num_field(13, lo=3, hi=200, unit="points")  # 0 .. robot.leg.tendon_max_deg
    root_heights: list[float] = vec_field([0.015, 0.031], length=2, lo=0.0, lo_open=True, unit="m")  # range
    heights: int = num_field(5, lo=2, hi=50, unit="points")
    radial_forces: list[float] = vec_field([-1.0, 1.0], length=2, unit="N")  # stuck foot's holding force range
    n_forces: int = num_field(5, lo=2, hi=50, unit="points")
    degrees: list[int] = vec_field([5, 3], length=2, lo=1, hi=8, unit="")  # powers of the angle, of the other
    settle_s: float = num_field(1.0, lo=0.0, lo_open=True, unit="s")
    fit_min_force: float = num_field(0.5, lo=0.0, unit="N")  # fit the normal force only where the foot is loaded
    holdout: int = num_field(12, lo=0, hi=1000, unit="points")  # random points between grid points, per map

    def check(self, cfg: SlotConfig) -> None:
        check_leg_load(cfg)
        if not self.root_heights[0] < self.root_heights[1]:
            raise ConfigError(f"experiment.root_heights = {self.root_heights}: give [lowest, highest] m")
        if not self.radial_forces[0] < 0.0 < self.radial_forces[1]:
            raise ConfigError(f"experiment.radial_forces = {self.radial_forces}: give [negative, positive] N around 0")
        # a polynomial of degree d in a direction needs d + 1 distinct points along it, or it passes through them
        # all (R^2 = 1) and says nothing between them
        du, dv = self.degrees
        for points, need, what in (
            (self.angles, du + 1, "experiment.angles"),
            (self.heights, dv + 1, "experiment.heights"),
            (self.n_forces, dv + 1, "experiment.n_forces"),
        ):
            if points < need:
                raise ConfigError(
                    f"{what} = {points} points cannot fit experiment.degrees = {list(self.degrees)} (it needs "
                    f"{need}): give more points or lower degrees"
                )


def _grids(cfg: SlotConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    exp = cfg.experiment
    angles = np.linspace(0.0, cfg.robot.leg.tendon_max_deg, exp.angles)
    heights = np.linspace(*exp.root_heights, exp.heights)
    forces = np.linspace(*exp.radial_forces, exp.n_forces)
    stance = cfg.gait.height + leg_root_z(cfg.robot)  # root height under the torso at p_z*
    return angles, heights, forces, stance


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    from rich.console import Console
    from rich.progress import Progress

    exp = cfg.experiment
    angles, heights, forces, stance = _grids(cfg)
    rng = np.random.default_rng(cfg.sim.seed)
    held_free = np.column_stack(
        [rng.uniform(angles[0], angles[-1], exp.holdout), rng.uniform(heights[0], heights[-1], exp.holdout)]
    )
    held_stuck = np.column_stack(
        [rng.uniform(angles[0], angles[-1], exp.holdout), rng.uniform(forces[0], forces[-1], exp.holdout)]
    )
    (out_dir / "logs").mkdir(parents=True, exist_ok=True)
    meta = {
        "config": {"yaml": resolved_yaml},
        "run": {"experiment": "legmap", "git_commit": git_commit(), "stance_root_height_m": repr(stance)},
    }
    total = len(angles) * (len(heights) + len(forces)) + 2 * exp.holdout
    with (
        Recorder(out_dir / "logs" / "legmap.mcap", metadata=meta) as rec,
        Progress(console=Console(stderr=True), transient=False) as bar,
    ):
        task = bar.add_task("leg maps  ", total=total)
        tick = lambda: bar.advance(task)  # noqa: E731
        for row in free_foot(cfg, angles, heights, exp.settle_s, tick):
            rec.write("/legmap/free", 0.0, row)
        for row in stuck_foot(cfg, angles, forces, stance, exp.settle_s, tick):
            rec.write("/legmap/stuck", 0.0, row)
        for theta, h in held_free:  # each held-out point from rest, as the grid's first point is
            for row in free_foot(cfg, np.array([theta]), np.array([h]), exp.settle_s, tick):
                rec.write("/legmap/free_holdout", 0.0, row)
        for theta, force in held_stuck:
            for row in stuck_foot(cfg, np.array([theta]), np.array([force]), stance, exp.settle_s, tick):
                rec.write("/legmap/stuck_holdout", 0.0, row)
    report(out_dir, cfg)


def fit_maps(free: pd.DataFrame, stuck: pd.DataFrame, degrees: tuple[int, int], min_force: float) -> dict[str, PolyFit]:
    """The four fits (see the module docstring of :mod:`slotexp.soft.legmap`)."""
    loaded = free[free["normal_n"] >= min_force]
    if len(loaded) < 3:
        raise ConfigError(
            f"only {len(loaded)} free-foot points load the foot above {min_force} N: lower "
            f"experiment.root_heights or experiment.fit_min_force"
        )
    fits = {
        "free_normal_n": PolyFit.fit(
            ("angle_deg", "root_height_m"), loaded["angle_deg"], loaded["root_height_m"], loaded["normal_n"], degrees
        ),
        "free_foot_radial_m": PolyFit.fit(
            ("angle_deg", "root_height_m"), free["angle_deg"], free["root_height_m"], free["foot_radial_m"], degrees
        ),
        "stuck_radial_force_n": PolyFit.fit(
            ("angle_deg", "offset_m"), stuck["angle_deg"], stuck["offset_m"], stuck["radial_force_n"], degrees
        ),
        "stuck_normal_n": PolyFit.fit(
            ("angle_deg", "offset_m"), stuck["angle_deg"], stuck["offset_m"], stuck["normal_n"], degrees
        ),
    }
    fits["free_normal_n"].extra["fitted_where"] = f"normal force >= {min_force} N"
    return fits


def holdout_errors(fits: dict[str, PolyFit], free: pd.DataFrame, stuck: pd.DataFrame, min_force: float) -> None:
    """Set each fit's largest error on the held-out points (model settled there, fit evaluated)."""
    loaded = free[free["normal_n"] >= min_force]
    pairs = {
        "free_normal_n": (loaded, "root_height_m", "normal_n"),
        "free_foot_radial_m": (free, "root_height_m", "foot_radial_m"),
        "stuck_radial_force_n": (stuck, "offset_m", "radial_force_n"),
        "stuck_normal_n": (stuck, "offset_m", "normal_n"),
    }
    for name, (df, second, value) in pairs.items():
        if len(df):
            err = fits[name](df["angle_deg"].to_numpy(), df[second].to_numpy()) - df[value].to_numpy()
            fits[name].holdout_max_error = float(np.max(np.abs(err)))


def report(out_dir: Path, cfg: SlotConfig) -> dict:
    """Tables, fits and figure from ``logs/legmap.mcap`` alone."""
    from ..figures.legmap import plot_legmap

    exp = cfg.experiment
    log = read_log(out_dir / "logs" / "legmap.mcap")
    free, stuck = log["/legmap/free"], log["/legmap/stuck"]
    fits = fit_maps(free, stuck, tuple(exp.degrees), exp.fit_min_force)
    if "/legmap/free_holdout" in log and "/legmap/stuck_holdout" in log:
        holdout_errors(fits, log["/legmap/free_holdout"], log["/legmap/stuck_holdout"], exp.fit_min_force)
    write_csv(free.drop(columns="t"), out_dir / "legmap_free.csv", index=False, float_format="%.6g")
    write_csv(stuck.drop(columns="t"), out_dir / "legmap_stuck.csv", index=False, float_format="%.6g")
    stance = float(log.metadata["run"]["stance_root_height_m"])
    result = {"stance_root_height_m": stance, "fits": {k: f.as_dict() for k, f in fits.items()}}
    write_json(out_dir / "legmap.json", result)
    plot_legmap(free, stuck, fits, stance, out_dir / "fig_legmap.png")
    return result


EXPERIMENTS.add("legmap", Experiment(LegmapExperiment, run, report))
