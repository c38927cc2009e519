"""Experiment ``identify``: fit uncertain model parameters to what the robot did with its own gaits.

The paper's stated next step. Chosen numeric settings (``experiment.parameters``: a
config path and a range each, e.g. the floor's friction, the horn zero, E, damping)
are fitted by CMA-ES (``cma``, seeded, the start evaluated first) so that the soft
plant, playing the schedules ``experiment.schedules`` open loop
(:func:`slotexp.locomotion.schedules.play`, one :class:`CosseratBatch` per candidate),
matches the observations:

- a table of per-gait displacements (``experiment.observations``: ``robot``, the
  schedules' own evidence in ``conf/schedule/`` (the robot's compass heading, distance
  per cycle where given), or a CSV ``gait,compass_deg,distance_per_cycle_mm`` with
  blanks where a gait has no figure, and optionally ``height_mm``);
- the torso's mean height while it walks (``experiment.height_mm``, every gait; or the
  CSV's ``height_mm``): a fit that matches the distances on stilts is not the robot;
- marker tracks (``experiment.tracks``: gait -> a marker CSV or ``.mcap`` in the formats
  of ``experiment=validate``): the ``com`` marker's track, cycle by cycle (its displacement
  over each whole gait cycle and its mean height, :func:`cycle_features`).

Each observation's residual is (model - observed) / sigma, and the cost is their sum of
squares. With ``experiment.synthetic.truth`` the observations are made by the model
itself at known values, with Gaussian noise, and written as files (``synthetic/``) that
go through the same loaders: the check that the fit recovers what it should.

Candidates run through :func:`slotexp.parallel.pool` (``experiment.parallel``: local
processes, every core, by default; a Dask cluster as a setting). Writes ``fit.yaml``
(the best values, as overrides), ``residuals.csv``, ``candidates.csv``, ``spread.csv``
(the range of each parameter over the candidates within the 68 % Delta-chi^2 of the best),
``metrics.json`` and ``fig_identify.png``, all rebuilt by ``slot figures`` from
``logs/identify.mcap``. After the search, each parameter is scanned over its whole range
with the others at the best (``experiment.slice_points`` each): a search that converges
visits little of a weakly constrained parameter's range, so without the scan the region
would describe where the search went, not where the cost allows. With ``experiment.restarts`` the
searches are several, each from the next best design point, sharing ``max_evals``. The best is the lowest
cost of every candidate, the scans' included. With ``experiment.robust.parameters`` the
fit is robust: each candidate also runs with each of those settings moved by
+-``experiment.robust.fraction`` of its value, and its cost is the worst of those runs'
and its own (:class:`RobustConfig`); ``candidates.csv`` keeps every run's cost.
"""

from __future__ import annotations

import json
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from ..atomic import write_csv, write_json, write_text
from ..config import SlotConfig, check_fields, choice_field, num_field, setting_unit, with_setting
from ..config import setting as config_setting
from ..errors import ConfigError, UserError
from ..locomotion.schedules import cycle_s, gait_metrics, play, with_profile_velocity, wrap_deg
from ..parallel import ParallelConfig, pool
from ..record import Log, Recorder, read_log
from . import EXPERIMENTS, Experiment
from ._logged import git_commit
from .replay import VISIBLE, check_played_schedules

COM = "com"
AXES = ("x", "y", "z")


@dataclass
class ParameterSpec:
    """One fitted setting: a numeric config path (a list setting gets the value in every entry) and its range."""

    path: str = "robot.contact.friction"
    lo: float = 0.05
    hi: float = 1.0
    log: bool = False  # search the logarithm (a scale: friction, stiffness, damping)


@dataclass
class SyntheticConfig:
    """Observations made by the model at known values (``truth``, one per parameter), with noise."""

    truth: list[float] | None = None
    noise_mm: float = num_field(0.5, lo=0.0, unit="mm")  # on distances per cycle and every track sample
    noise_deg: float = num_field(2.0, lo=0.0, unit="deg")  # on headings
    seed: int = num_field(0, lo=0, unit="")


@dataclass
class RobustConfig:
    """A robust fit: each candidate is also run with each of ``parameters`` moved by +-``fraction`` of its value
    (the others as the candidate has them), and its cost is the worst (or the mean) of those runs' and its own.

    Why: the robot walks its gaits on whatever floor it is on and with whatever batch of TPU its legs were
    printed from, so a model that matches them only at one friction or one stiffness is missing what makes
    them work (a fit that walked the forward gait 31.7 mm per cycle walked it 4.9 mm at E x 1.1). The worst
    case, not the mean, is the default: a mean can be carried by one lucky neighbour."""

    parameters: list[str] = field(default_factory=list)  # config paths; [] : no robust cost
    fraction: float = num_field(0.1, lo=0.0, lo_open=True, hi=0.9, unit="of the value")
    aggregate: str = choice_field("worst", "worst", "mean")


def _default_parameters() -> list[ParameterSpec]:
    return [
        ParameterSpec("robot.contact.friction", 0.05, 1.0, True),
        ParameterSpec("robot.servo.horn_zero_deg", 80.0, 140.0, False),
    ]


@dataclass
class IdentifyExperiment:
    """Fit model parameters to per-gait displacements and marker tracks (CMA-ES over the batched plant)."""

    name: str = "identify"
    schedules: list[str] = field(default_factory=lambda: list(VISIBLE))
    observations: str = "robot"  # robot: the schedules' evidence (conf/schedule/); or a CSV path
    tracks: dict[str, str] = field(default_factory=dict)  # gait -> marker CSV / .mcap (validate's formats)
    parameters: list[ParameterSpec] = field(default_factory=_default_parameters)
    duration: float = num_field(8.0, lo=0.0, lo_open=True, hi=600.0, unit="s")  # simulated per gait
    measure_from_s: float = num_field(2.0, lo=0.0, unit="s")  # displacements: whole cycles from here
    rate_hz: float = num_field(50.0, lo=1.0, hi=1000.0, unit="Hz")
    profile_velocity_rpm: float = num_field(0.0, lo=0.0, hi=61.0, unit="rpm")  # the robot's gait code: none
    heading_sigma_deg: float = num_field(15.0, lo=0.0, lo_open=True, unit="deg")
    # a model's cycle displacement known to +-this (mm) in any direction: its heading then to +-atan(this / its
    # distance per cycle), in quadrature with heading_sigma_deg (0: the heading's sigma alone). Why: a gait the
    # model barely moves creeps in a direction its stick-slip picks (the step, a parameter's last digit), so a
    # fixed sigma charges it a cost that jumps with that direction (docs/results/gaits.md)
    heading_displacement_sigma_mm: float = num_field(0.0, lo=0.0, unit="mm")
    # the torso's mean height over the measured cycles, observed for every gait (e.g. 40: the paper's walking
    # height p_z* = 0.04 m); None: not observed (a CSV's height_mm column gives it per gait instead)
    height_mm: float | None = None
    height_sigma_mm: float = num_field(10.0, lo=0.0, lo_open=True, unit="mm")
    distance_sigma: float = num_field(0.2, lo=0.0, unit="")  # relative, on distances per cycle ...
    distance_sigma_mm: float = num_field(1.0, lo=0.0, unit="mm")  # ... in quadrature with this floor
    track_sigma_mm: float = num_field(2.0, lo=0.0, lo_open=True, unit="mm")  # on a track's per-cycle RMS per axis
    max_evals: int = num_field(120, lo=2, hi=100000, unit="candidates")
    popsize: int = num_field(8, lo=2, hi=1000, unit="")
    sigma0: float = num_field(0.25, lo=0.0, lo_open=True, hi=1.0, unit="of each range")
    # Latin-hypercube points over the ranges evaluated first; the search starts from the best of them and the
    # config's own values (a fit from the config alone can settle in a local minimum: docs/results/gaits.md)
    initial_design: int = num_field(16, lo=0, hi=10000, unit="candidates")
    # CMA-ES runs, each from the next best of the design's points (and the config's), max_evals shared between them:
    # one search's end depends on its path by more than the region it reports (docs/results/gaits.md)
    restarts: int = num_field(1, lo=1, hi=100, unit="searches")
    # after the search: each parameter scanned over its range at this many points, the others at the best
    slice_points: int = num_field(8, lo=0, hi=1000, unit="candidates per parameter")
    seed: int = num_field(1, lo=0, unit="")
    parallel: ParallelConfig = field(default_factory=ParallelConfig)
    synthetic: SyntheticConfig = field(default_factory=SyntheticConfig)
    robust: RobustConfig = field(default_factory=RobustConfig)

    def check(self, cfg: SlotConfig) -> None:
        if cfg.plant.name != "cosserat":
            raise ConfigError(
                f"experiment=identify fits the soft legs' model: use plant=cosserat, not {cfg.plant.name}"
            )
        check_played_schedules(cfg, self.schedules, self.rate_hz, self.duration, self.measure_from_s)
        for name in self.schedules:
            if cfg.schedules[name].heldout:
                raise ConfigError(
                    f"experiment.schedules names {name!r}, a held-out gait (the model's test, never fitted): "
                    f"fit on the gaits in shared/data ({', '.join(VISIBLE)})"
                )
        for gait in self.tracks:
            if gait not in self.schedules:
                raise ConfigError(
                    f"experiment.tracks has a track for {gait!r}, which is not in experiment.schedules: add it there"
                )
        if self.restarts > 1 and self.restarts > self.initial_design + 1:
            raise ConfigError(
                f"experiment.restarts = {self.restarts} searches start from the design's best points and the config's: "
                f"give experiment.initial_design >= {self.restarts - 1}"
            )
        if self.restarts > 1 and self.max_evals // self.restarts < self.popsize:
            raise ConfigError(
                f"experiment.max_evals = {self.max_evals} shared by {self.restarts} searches leaves each less than a "
                f"generation of experiment.popsize = {self.popsize}: give max_evals >= {self.restarts * self.popsize}"
            )
        if not self.parameters:
            raise ConfigError("experiment.parameters is empty: name at least one setting to fit")
        paths = [p.path for p in self.parameters]
        if len(set(paths)) != len(paths):
            raise ConfigError(f"experiment.parameters names a setting twice: {', '.join(paths)}")
        for p in self.parameters:
            current = setting(cfg, p.path)
            entries = current if isinstance(current, list) else [current]
            if not entries or any(not isinstance(v, (int, float)) or isinstance(v, bool) for v in entries):
                raise ConfigError(f"experiment.parameters: {p.path} is not a numeric setting: fit a number")
            if not p.lo < p.hi:
                raise ConfigError(f"experiment.parameters: {p.path} has lo = {p.lo:g} >= hi = {p.hi:g}: give lo < hi")
            if p.log and p.lo <= 0:
                raise ConfigError(f"experiment.parameters: {p.path} is searched in log space: give lo > 0")
            # the range inside the setting's own valid values (a fit there would be refused by the tool itself);
            # a robust fit also runs each robust setting 10 % beyond the candidates
            spread = self.robust.fraction if p.path in self.robust.parameters else 0.0
            for end, value in (("lo", p.lo * (1.0 - spread)), ("hi", p.hi * (1.0 + spread))):
                try:
                    check_fields(with_setting(cfg, p.path, value))
                except ConfigError as exc:
                    raise ConfigError(
                        f"experiment.parameters: {p.path} from {p.lo:g} to {p.hi:g} leaves its valid values at {end} "
                        f"({str(exc).splitlines()[0]}): narrow the range"
                    ) from None
        truth = self.synthetic.truth
        if truth is not None:
            if len(truth) != len(self.parameters):
                raise ConfigError(
                    f"experiment.synthetic.truth has {len(truth)} values for {len(self.parameters)} parameters: "
                    "give one per parameter, in order"
                )
            for p, v in zip(self.parameters, truth, strict=True):
                if not p.lo <= v <= p.hi:
                    raise ConfigError(
                        f"experiment.synthetic.truth: {p.path} = {v:g} is outside its range [{p.lo:g}, {p.hi:g}]"
                    )
        for path in self.robust.parameters:
            current = setting(cfg, path)
            entries = current if isinstance(current, list) else [current]
            if not entries or any(not isinstance(v, (int, float)) or isinstance(v, bool) for v in entries):
                raise ConfigError(f"experiment.robust.parameters: {path} is not a numeric setting: name a number")
        if self.height_mm is not None and not 0.0 < self.height_mm < 1000.0:
            raise ConfigError(
                f"experiment.height_mm = {self.height_mm:g} is not a torso height: give mm above the floor"
            )
        if truth is None and self.observations != "robot" and not Path(self.observations).expanduser().is_file():
            raise ConfigError(
                f"experiment.observations = {self.observations!r} is neither 'robot' nor a CSV file: "
                "give the path of gait,compass_deg,distance_per_cycle_mm"
            )
        self.parallel.check()


# --------------------------------------------------------------------------- parameters
def setting(cfg: Any, path: str) -> Any:
    """The value at dotted ``path`` of a config; a ConfigError names a path that is not there."""
    return config_setting(cfg, path, "experiment.parameters")


def to_values(specs: list[ParameterSpec], u: np.ndarray) -> np.ndarray:
    """Parameter values for a point ``u`` of the unit cube the search moves in."""
    lo = np.array([math.log(p.lo) if p.log else p.lo for p in specs])
    hi = np.array([math.log(p.hi) if p.log else p.hi for p in specs])
    v = lo + np.clip(u, 0.0, 1.0) * (hi - lo)
    return np.array([math.exp(x) if p.log else x for p, x in zip(specs, v, strict=True)])


def to_unit(specs: list[ParameterSpec], values: np.ndarray) -> np.ndarray:
    out = []
    for p, v in zip(specs, values, strict=True):
        lo, hi, x = (math.log(p.lo), math.log(p.hi), math.log(v)) if p.log else (p.lo, p.hi, v)
        out.append((x - lo) / (hi - lo))
    return np.array(out)


def candidate_config(cfg: SlotConfig, specs: list[ParameterSpec], values: np.ndarray) -> SlotConfig:
    out = with_profile_velocity(cfg, cfg.experiment.profile_velocity_rpm)
    for p, v in zip(specs, values, strict=True):
        out = with_setting(out, p.path, float(v))
    return out


def perturbed(cfg: SlotConfig, model: SlotConfig) -> list[SlotConfig]:
    """``model`` and, for a robust fit, ``model`` with each of ``experiment.robust.parameters`` moved by
    -fraction and +fraction of its value there (a list setting: every entry alike, by its mean)."""
    robust = cfg.experiment.robust
    out = [model]
    for path in robust.parameters:
        value = setting(model, path)
        value = float(np.mean(value)) if isinstance(value, list) else float(value)
        out += [with_setting(model, path, value * (1.0 + sign * robust.fraction)) for sign in (-1.0, 1.0)]
    return out


def robust_cost(cfg: SlotConfig, costs: list[float]) -> float:
    """A candidate's cost from its own and its perturbed runs' (the first is its own)."""
    if len(costs) == 1:
        return costs[0]
    return float(np.max(costs)) if cfg.experiment.robust.aggregate == "worst" else float(np.mean(costs))


# --------------------------------------------------------------------------- evaluation (in workers)
def evaluate(task: tuple[SlotConfig, list[str], float, float, float, int]) -> dict:
    """Play the schedules on one candidate model: per gait its displacement metrics and its com track."""
    cfg, names, duration, rate_hz, measure_from_s, threads = task
    if threads > 0:
        import numba

        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        t, xs, retaken = play(cfg, names, duration, rate_hz)
    except Exception as exc:  # a candidate that diverges is a bad candidate, not a failed fit
        return {"error": f"{type(exc).__name__}: {exc}"}
    if not np.isfinite(xs).all():
        return {"error": "the state went non-finite"}
    gaits = {name: gait_metrics(t, xs[b], cycle_s(cfg.schedules[name]), measure_from_s) for b, name in enumerate(names)}
    com = {name: xs[b, :, 3:6] for b, name in enumerate(names)}
    return {"t": t, "gaits": gaits, "com": com, "retaken": int(retaken.sum())}


# --------------------------------------------------------------------------- observations
@dataclass
class Observations:
    """What the fit is held to: per-gait heading and distance per cycle, and com tracks (displacements)."""

    table: pd.DataFrame  # gait, compass_deg, distance_per_cycle_mm, height_mm (NaN: not observed)
    tracks: dict[str, tuple[np.ndarray, np.ndarray]]  # gait -> (t from 0, com displacement (n, 3) m)


TABLE = ("gait", "compass_deg", "distance_per_cycle_mm", "height_mm")


def _held_height(cfg: SlotConfig) -> float:
    """The torso height every gait is held to (``experiment.height_mm``; NaN: not observed)."""
    height = cfg.experiment.height_mm
    return math.nan if height is None else float(height)


def robot_table(cfg: SlotConfig, names: list[str]) -> pd.DataFrame:
    height = _held_height(cfg)
    rows = []
    for name in names:
        s = cfg.schedules[name]
        d = s.robot_distance_per_cycle_m
        rows.append(
            {
                "gait": name,
                "compass_deg": math.nan if s.heading_deg is None else float(s.heading_deg),
                "distance_per_cycle_mm": math.nan if d is None else d * 1e3,
                "height_mm": height,
            }
        )
    return pd.DataFrame(rows)


def read_table(path: Path, names: list[str], cfg_height: float = math.nan) -> pd.DataFrame:
    try:
        table = pd.read_csv(path, comment="#")
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: not a readable CSV ({exc}); give gait,compass_deg,distance_per_cycle_mm") from None
    missing = {"gait", "compass_deg", "distance_per_cycle_mm"} - set(table.columns)
    if missing:
        raise UserError(
            f"{path}: no column(s) {', '.join(sorted(missing))}; the header is gait,compass_deg,distance_per_cycle_mm"
        )
    if "height_mm" not in table.columns:  # optional: the torso's mean height while the gait walks
        table["height_mm"] = cfg_height
    try:
        table = table.astype({"gait": str, "compass_deg": float, "distance_per_cycle_mm": float, "height_mm": float})
    except ValueError as exc:
        raise UserError(
            f"{path}: a heading or distance is not a number ({exc}); leave a cell blank if unknown"
        ) from None
    unknown = sorted(set(table["gait"]) - set(names))
    if unknown:
        raise UserError(f"{path}: gait(s) {', '.join(unknown)} are not in experiment.schedules: add them or drop them")
    _check_observed(path, table)
    return table[list(TABLE)].reset_index(drop=True)


MAX_STRIDE_MM = 500.0  # mm per cycle: more than two of the robot's leg spans (its feet span about 380 mm)
MAX_HEIGHT_MM = 300.0  # mm: the torso on fully straight legs stands about 200 mm


def _check_observed(path: Path, table: pd.DataFrame) -> None:
    """An observation table observes something, in the units it says: no fit is made of an empty table (its cost
    would be 0), a negative distance (the heading carries the direction), or metres or centimetres read as mm."""
    observed = table[["compass_deg", "distance_per_cycle_mm", "height_mm"]].notna().to_numpy().any(axis=1)
    if not observed.any():
        raise UserError(
            f"{path}: observes nothing ({len(table)} rows, every heading, distance and height blank): give at least "
            "one gait's compass_deg or distance_per_cycle_mm"
        )
    for column, lo, hi, unit in (
        ("distance_per_cycle_mm", 0.0, MAX_STRIDE_MM, "mm per gait cycle, >= 0 (the heading gives the direction)"),
        ("height_mm", 0.0, MAX_HEIGHT_MM, "mm of the torso above the floor"),
        ("compass_deg", -360.0, 360.0, "deg, clockwise from forward"),
    ):
        bad = table[table[column].notna() & ~table[column].between(lo, hi)]
        if not bad.empty:
            row = bad.iloc[0]
            raise UserError(
                f"{path}: {column} = {row[column]:g} for {row['gait']} is not in {lo:g}-{hi:g}: give {unit}"
            )


def read_track(spec: str) -> tuple[np.ndarray, np.ndarray]:
    from ..compare import TrajectoryError
    from .validate import load_trajectory

    try:
        traj = load_trajectory(spec)
    except TrajectoryError as exc:
        raise UserError(str(exc)) from None
    if COM not in traj.markers:
        raise UserError(f"{spec}: no '{COM}' marker (columns com_x, com_y, com_z): the fit follows the torso's")
    com = np.asarray(traj.markers[COM], float)
    first = np.flatnonzero(np.isfinite(com).all(axis=1))
    if first.size == 0:
        raise UserError(f"{spec}: the '{COM}' marker is never tracked")
    return traj.t - traj.t[0], com - com[first[0]]


def write_track_csv(path: Path, t: np.ndarray, com: np.ndarray) -> None:
    lines = ["# synthetic marker track: the model's torso, with noise (experiment=identify)", "t,com_x,com_y,com_z"]
    lines += [f"{ti:.4f},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}" for ti, p in zip(t, com, strict=True)]
    write_text(path, "\n".join(lines) + "\n")


def synthetic_observations(cfg: SlotConfig, out_dir: Path) -> tuple[Path, dict[str, str]]:
    """The model's own observations at ``experiment.synthetic.truth``, with noise, written as the files a
    robot's would be (``synthetic/observations.csv`` and a track per gait)."""
    exp = cfg.experiment
    syn = exp.synthetic
    model = candidate_config(cfg, exp.parameters, np.asarray(syn.truth, float))
    result = evaluate((model, list(exp.schedules), exp.duration, exp.rate_hz, exp.measure_from_s, 0))
    if "error" in result:
        raise UserError(f"experiment.synthetic.truth: the model fails there ({result['error']}): choose other values")
    rng = np.random.default_rng(syn.seed)
    folder = out_dir / "synthetic"
    folder.mkdir(parents=True, exist_ok=True)
    rows, tracks = [], {}
    for name in exp.schedules:
        m = result["gaits"][name]
        rows.append(
            {
                "gait": name,
                "compass_deg": (m["compass_deg"] + rng.normal(0.0, syn.noise_deg)) % 360.0,
                "distance_per_cycle_mm": max(0.0, m["distance_per_cycle_mm"] + rng.normal(0.0, syn.noise_mm)),
                # observed only where the fit is told to hold the height
                "height_mm": math.nan if exp.height_mm is None else m["height_mm"] + rng.normal(0.0, syn.noise_mm),
            }
        )
        com = result["com"][name] + rng.normal(0.0, syn.noise_mm * 1e-3, result["com"][name].shape)
        write_track_csv(folder / f"{name}.csv", result["t"], com)
        tracks[name] = str(folder / f"{name}.csv")
    write_csv(pd.DataFrame(rows), folder / "observations.csv", index=False, float_format="%.4f")
    return folder / "observations.csv", tracks


def load_observations(cfg: SlotConfig, table_spec: str, track_specs: dict[str, str]) -> Observations:
    names = list(cfg.experiment.schedules)
    if table_spec == "robot":
        table = robot_table(cfg, names)
    else:
        table = read_table(Path(table_spec).expanduser(), names, _held_height(cfg))
    return Observations(table, {g: read_track(s) for g, s in track_specs.items()})


def residuals(cfg: SlotConfig, obs: Observations, result: dict) -> pd.DataFrame:
    """One row per observation: what, gait, observed, model, sigma, residual = (model - observed) / sigma."""
    exp = cfg.experiment
    rows = []
    for _, r in obs.table.iterrows():
        m = result["gaits"][r["gait"]]
        if r["compass_deg"] == r["compass_deg"]:
            err = wrap_deg(m["compass_deg"] - r["compass_deg"])
            sigma = heading_sigma(exp.heading_sigma_deg, exp.heading_displacement_sigma_mm, m["distance_per_cycle_mm"])
            rows.append(("compass_deg", r["gait"], r["compass_deg"], m["compass_deg"], sigma, err))
        d = r["distance_per_cycle_mm"]
        if d == d:
            sigma = math.hypot(exp.distance_sigma * d, exp.distance_sigma_mm)
            rows.append(
                (
                    "distance_per_cycle_mm",
                    r["gait"],
                    d,
                    m["distance_per_cycle_mm"],
                    sigma,
                    m["distance_per_cycle_mm"] - d,
                )
            )
        h = r["height_mm"]
        if h == h:
            rows.append(("height_mm", r["gait"], h, m["height_mm"], exp.height_sigma_mm, m["height_mm"] - h))
    for gait, (t_obs, com_obs) in obs.tracks.items():
        cycle = cycle_s(cfg.schedules[gait])
        com = result["com"][gait] - result["com"][gait][0]  # as the observed track: from its first sample
        model = cycle_features(result["t"], com, cycle, exp.measure_from_s)
        observed = cycle_features(t_obs, com_obs, cycle, exp.measure_from_s)
        n = min(len(model), len(observed))
        for k, axis in enumerate(AXES):
            err = (model[:n, k] - observed[:n, k]) * 1e3
            ok = np.isfinite(err)
            rms = float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else math.nan
            rows.append((f"track_cycle_rms_{axis}_mm", gait, 0.0, rms, exp.track_sigma_mm, rms))
    table = pd.DataFrame(rows, columns=["observation", "gait", "observed", "model", "sigma", "error"])
    table["residual"] = table["error"] / table["sigma"]
    return table


def heading_sigma(sigma_deg: float, displacement_sigma_mm: float, distance_mm: float) -> float:
    """A model heading's sigma (deg): the observation's ``sigma_deg`` in quadrature with the direction's own
    uncertainty, atan(``displacement_sigma_mm`` / ``distance_mm``), for a cycle displacement of ``distance_mm``
    known to +-``displacement_sigma_mm`` across it. It grows to 90 deg as the model stops moving, so a gait
    that barely creeps is charged at most (180 / hypot(sigma_deg, 90))^2 whichever way it creeps."""
    if displacement_sigma_mm <= 0.0:
        return sigma_deg
    spread = math.degrees(math.atan2(displacement_sigma_mm, max(distance_mm, 0.0)))
    return math.hypot(sigma_deg, spread)


def cycle_features(t: np.ndarray, com: np.ndarray, cycle: float, measure_from_s: float) -> np.ndarray:
    """A track cycle by cycle (whole cycles after ``measure_from_s``): the displacement over each cycle in x
    and y and the mean height over it (m), (cycles, 3). Compared cycle by cycle, not sample by sample: a
    stick-slip gait's position drifts from any model's a little more every cycle, so whole tracks would
    weigh how long the run was, not how well the model walks."""
    first = math.ceil(measure_from_s / cycle - 1e-9)
    last = math.floor((t[-1] - t[0]) / cycle + 1e-9)
    out = []
    for k in range(first, last):
        t0, t1 = t[0] + k * cycle, t[0] + (k + 1) * cycle
        ends = [np.interp([t0, t1], t, com[:, j]) for j in range(2)]
        inside = (t >= t0) & (t <= t1)
        out.append([ends[0][1] - ends[0][0], ends[1][1] - ends[1][0], float(np.nanmean(com[inside, 2]))])
    return np.array(out).reshape(-1, 3)


def cost_of(cfg: SlotConfig, obs: Observations, result: dict) -> float:
    if "error" in result:
        return 1e9
    r = residuals(cfg, obs, result)["residual"].to_numpy(float)
    return float(np.sum(np.where(np.isfinite(r), r, 1e3) ** 2))


# --------------------------------------------------------------------------- run
def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from ..locomotion.search import search

    exp = cfg.experiment
    specs = list(exp.parameters)
    # absolute, as they are recorded in the log: slot figures reads them again from wherever it is run
    table_spec = exp.observations
    track_specs = {g: str(Path(spec).expanduser().resolve()) for g, spec in exp.tracks.items()}
    if exp.synthetic.truth is not None:
        path, track_specs = synthetic_observations(cfg, out_dir)
        table_spec = str(path)
    obs = load_observations(cfg, table_spec, track_specs)
    names = list(exp.schedules)
    k = len(specs)
    # pycma searches two dimensions at least: one parameter gets an inert second coordinate
    x0 = np.concatenate([to_unit(specs, np.array([_start_value(cfg, p) for p in specs])), [0.5] * (k == 1)])
    (out_dir / "logs").mkdir(parents=True, exist_ok=True)
    meta = {
        "config": {"yaml": resolved_yaml},
        "run": {"experiment": "identify", "git_commit": git_commit()},
        "observations": {"table": json.dumps(obs.table.to_dict(orient="records")), "tracks": json.dumps(track_specs)},
    }
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with (
        pool(exp.parallel, exp.popsize) as engine,
        Recorder(out_dir / "logs" / "identify.mcap", metadata=meta) as rec,
        Progress(*columns, console=Console(stderr=True), transient=False) as bar,
    ):
        # every core: the engine's processes, each batch's robots on the cores left to it
        local = exp.parallel.engine == "processes" or exp.parallel.address is None
        threads = max(1, (os.cpu_count() or 1) // engine.workers) if local else 0
        # every evaluation: the start and the design, the search's start and its whole generations within
        # max_evals, the scan, the best run again (CMA-ES may stop sooner: the bar is closed at the count done)
        design = exp.initial_design + 1 if exp.initial_design > 0 else 0
        budget = exp.max_evals // exp.restarts  # each search's (check(): restarts > 1 has the design to start from)
        generations = exp.restarts * (budget // exp.popsize * exp.popsize + 1)
        task = bar.add_task("identify", total=design + generations + k * exp.slice_points + 1)
        written = 0
        generation = 0

        def run_candidates(us: list[np.ndarray]) -> list[tuple[np.ndarray, dict, float, list[float]]]:
            """Each candidate's values, its own run, its (robust) cost and every run's cost (its own first)."""
            values = [to_values(specs, u[:k]) for u in us]
            models = [perturbed(cfg, candidate_config(cfg, specs, v)) for v in values]
            tasks = [
                (m, names, exp.duration, exp.rate_hz, exp.measure_from_s, threads) for group in models for m in group
            ]
            results = iter(engine.map(evaluate, tasks))
            out = []
            for v, group in zip(values, models, strict=True):
                runs = [next(results) for _ in group]
                costs = [cost_of(cfg, obs, r) for r in runs]
                out.append((v, runs[0], robust_cost(cfg, costs), costs))
            return out

        def evaluate_generation(us: list[np.ndarray]) -> list[float]:
            nonlocal written, generation
            costs = []
            for v, r, c, each in run_candidates(us):
                written += 1
                costs.append(c)
                rec.write(
                    "/identify/candidate",
                    float(written),
                    {
                        "generation": generation,
                        "cost": c,
                        "cost_own": each[0],
                        "cost_perturbed": np.asarray(each[1:] or [c]),
                        "values": v,
                        "failed": "error" in r,
                        "retaken": r.get("retaken", 0),  # periods retaken by backward Euler (plant.retakes)
                        **_flat(r),
                    },
                )
            generation += 1
            bar.advance(task, len(us))
            return costs

        firsts = [x0]
        if exp.initial_design > 0:  # the start and a space-filling design, one batch; the best are the starts
            from scipy.stats import qmc

            design = qmc.LatinHypercube(d=k, seed=exp.seed).random(exp.initial_design)
            points = [x0] + [np.concatenate([u, x0[k:]]) for u in design]
            order = np.argsort(evaluate_generation(points), kind="stable")
            firsts = [points[i] for i in order[: exp.restarts]]
        best_cost, best_u = math.inf, firsts[0]
        for n, first in enumerate(firsts):  # a search from each start, with its own seed
            cost, u = search(
                evaluate_generation,
                first,
                sigma0=exp.sigma0,
                popsize=exp.popsize,
                max_evals=budget,
                seed=exp.seed + n,
                bounds=(np.zeros(len(first)), np.ones(len(first))),
            )
            if cost < best_cost:
                best_cost, best_u = cost, u
        if exp.slice_points > 0:  # each parameter across its range, the others at the best: one batch
            grid = np.linspace(0.0, 1.0, exp.slice_points)
            points = [np.concatenate([best_u[:i], [g], best_u[i + 1 :]]) for i in range(k) for g in grid]
            for u, c in zip(points, evaluate_generation(points), strict=True):
                if c < best_cost:
                    best_cost, best_u = c, u
        ((v, r, c, _),) = run_candidates([best_u])
        bar.advance(task)
        bar.update(task, total=written + 1)  # what was done: CMA-ES may have stopped before the cap
        if "error" in r:
            raise UserError(f"the best candidate fails when run again ({r['error']}): check the parameter ranges")
        rec.write("/identify/best", 0.0, {"cost": c, "values": v, **_flat(r)})
        for gait in names:  # the best candidate's com tracks, one record per tick (log time: the track's)
            for ti, p in zip(r["t"], r["com"][gait], strict=True):
                rec.write("/identify/best_com", float(ti), {"gait": gait, "x": p[0], "y": p[1], "z": p[2]})
    report(out_dir, cfg)


def _start_value(cfg: SlotConfig, p: ParameterSpec) -> float:
    """The search starts from the config's own value (a list setting: its mean), held inside the range."""
    v = setting(cfg, p.path)
    v = float(np.mean(v)) if isinstance(v, list) else float(v)
    return min(max(v, p.lo), p.hi)


def _flat(result: dict) -> dict:
    """A candidate's per-gait numbers as one flat record (gait.metric)."""
    if "error" in result:
        return {}
    return {f"{g}.{k}": float(v) for g, m in result["gaits"].items() for k, v in m.items()}


# --------------------------------------------------------------------------- report
def _result_from_log(log: Log, names: list[str]) -> dict:
    """The best candidate's per-gait metrics and com tracks, as :func:`evaluate` returned them."""
    best = log["/identify/best"].iloc[0]
    gaits = {g: {c.split(".", 1)[1]: float(best[c]) for c in best.index if c.startswith(g + ".")} for g in names}
    frame = log["/identify/best_com"]
    by_gait = {g: frame[frame["gait"] == g] for g in names}
    t = by_gait[names[0]]["t"].to_numpy(float)
    return {"t": t, "gaits": gaits, "com": {g: f[list(AXES)].to_numpy(float) for g, f in by_gait.items()}}


def report(out_dir: Path, cfg: SlotConfig) -> dict:
    """Fit, residuals, spread, candidates, metrics and the figure from ``logs/identify.mcap`` alone."""
    from scipy.stats import chi2

    from ..figures.identify import plot_identify

    exp = cfg.experiment
    specs = list(exp.parameters)
    path = out_dir / "logs" / "identify.mcap"
    log = read_log(path)
    meta = log.metadata.get("observations", {})
    table = pd.DataFrame(json.loads(meta.get("table", "[]")), columns=list(TABLE))
    table = table.astype({"compass_deg": float, "distance_per_cycle_mm": float, "height_mm": float})
    track_specs = json.loads(meta.get("tracks", "{}"))
    obs = Observations(table, {g: read_track(s) for g, s in track_specs.items()})
    names = list(exp.schedules)
    result = _result_from_log(log, names)
    res = residuals(cfg, obs, result)
    write_csv(res, out_dir / "residuals.csv", index=False, float_format="%.6g")

    candidates = log["/identify/candidate"].reset_index(drop=True)
    value_cols = [f"values.{i}" for i in range(len(specs))]
    candidates = candidates.rename(columns=dict(zip(value_cols, [p.path for p in specs], strict=True)))
    write_csv(candidates.drop(columns="t"), out_dir / "candidates.csv", index=False, float_format="%.6g")

    best = log["/identify/best"].iloc[0]
    best_values = [float(best[f"values.{i}"]) for i in range(len(specs))]
    best_cost = float(best["cost"])
    # Delta-chi^2 region: the candidates whose cost is within the 68 % quantile of chi^2 with k degrees of
    # freedom of the best (a joint confidence region when the sigmas are the observations' standard errors)
    delta = float(chi2.ppf(0.683, len(specs)))
    near = candidates[candidates["cost"] <= min(best_cost, candidates["cost"].min()) + delta]
    truth = exp.synthetic.truth
    spread = []
    for i, p in enumerate(specs):
        vals = near[p.path].to_numpy(float) if len(near) else np.array([best_values[i]])
        row = {
            "parameter": p.path,
            "best": best_values[i],
            "lo_68": float(min(vals.min(), best_values[i])),
            "hi_68": float(max(vals.max(), best_values[i])),
            "range_lo": p.lo,
            "range_hi": p.hi,
            "candidates_in_region": int(len(near)),
        }
        row["at_edge"] = _at_edge(p, best_values[i])
        if truth is not None:
            row["truth"] = float(truth[i])
            row["error_rel"] = (best_values[i] - truth[i]) / truth[i] if truth[i] else math.nan
            row["truth_in_region"] = bool(row["lo_68"] <= truth[i] <= row["hi_68"])
        spread.append(row)
    spread_table = pd.DataFrame(spread)
    write_csv(spread_table, out_dir / "spread.csv", index=False, float_format="%.6g")
    overrides = {p.path: _as_setting(setting(cfg, p.path), v) for p, v in zip(specs, best_values, strict=True)}
    edges = [
        f"{r['parameter']} = {r['best']:.4g} at its range's {r['at_edge']} end ({r['range_lo']:g}-{r['range_hi']:g})"
        for r in spread
        if r["at_edge"]
    ]
    for edge in edges:  # the best may lie beyond: the range, not the data, stopped the fit
        print(f"warning: {edge}: the best may lie beyond it; widen the range", file=sys.stderr)
    write_text(
        out_dir / "fit.yaml",
        "# Written by `slot run experiment=identify`: the best values, as overrides (key=value on the command line)\n"
        + "".join(f"# at the edge: {edge}: the best may lie beyond it\n" for edge in edges)
        + yaml.safe_dump({"cost": best_cost, "overrides": overrides}, sort_keys=False, width=120),
    )
    metrics = {
        "cost": best_cost,
        "evaluations": int(len(candidates)),
        "failed": int(candidates["failed"].sum()) if "failed" in candidates else 0,
        # candidates with a period retaken after diverging (plant.retakes): scored by what they do all the same
        "retaken": int((candidates["retaken"] > 0).sum()) if "retaken" in candidates else 0,
        "delta_chi2_68": delta,
        "parameters": spread,
        "residuals": res.to_dict(orient="records"),
    }
    write_json(out_dir / "metrics.json", metrics)
    plot_identify(
        candidates,
        [p.path for p in specs],
        spread_table,
        res,
        out_dir / "fig_identify.png",
        log=[p.log for p in specs],
        units=[setting_unit(cfg, p.path) for p in specs],
    )
    return metrics


EDGE = 0.01  # of a range's width (in the space it is searched in): a best value this close to an end is at it


def _at_edge(spec: ParameterSpec, value: float) -> str:
    """ "lo" or "hi" where ``value`` sits within :data:`EDGE` of that end of ``spec``'s range, else ""."""
    lo, hi, v = (math.log(x) for x in (spec.lo, spec.hi, value)) if spec.log else (spec.lo, spec.hi, value)
    if v - lo <= EDGE * (hi - lo):
        return "lo"
    if hi - v <= EDGE * (hi - lo):
        return "hi"
    return ""


def _as_setting(current: Any, value: float) -> Any:
    return [round(value, 6)] * len(current) if isinstance(current, list) else round(value, 6)


EXPERIMENTS.add("identify", Experiment(IdentifyExperiment, run, report))
