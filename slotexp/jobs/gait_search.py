"""Experiment ``gait_search``: CMA-ES over periodic tendon schedules, on the soft plant itself.

For each body-frame heading in ``experiment.headings`` (and turning in place with
``experiment.turn``) it searches a primitive of the style ``experiment.style``
(:mod:`slotexp.locomotion.search`), every candidate simulated on the two-way coupled
soft plant at ``sim.dt`` (:mod:`slotexp.locomotion.openloop`), candidates evaluated
in parallel through :func:`slotexp.parallel.pool` (``experiment.parallel``: local
processes on every core by default, or a Dask cluster), seeded. The
best primitive of each heading and its mirror images (the torso is symmetric about
its x and y axes) are then run again for ``experiment.verify_duration`` seconds and
what they measured (heading, speed, yaw rate) goes into the library.

Writes ``library.yaml`` (the style's primitives: the current library's, with the
searched headings and their mirrors replaced; ``make results`` installs it as
``conf/library/default.yaml``), ``search.csv`` (every candidate), ``metrics.json``
and the figures ``fig_gait_polar.png`` (best speed per heading) and
``fig_search.png`` (cost per generation), all rebuilt by ``slot figures`` from
``logs/gait_search.mcap``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from ..atomic import write_csv, write_json, write_text
from ..config import GaitStyleConfig, PrimitiveConfig, SlotConfig, check_library, check_schedule_reach, num_field
from ..errors import ConfigError
from ..locomotion.heading import lean_pattern
from ..locomotion.openloop import GaitMetrics, run_gait
from ..locomotion.primitives import GaitStyle, Primitive, from_steps
from ..locomotion.schedules import schedule_tendon_deg
from ..locomotion.search import cost, from_vector, search, to_vector
from ..parallel import ParallelConfig, pool
from ..record import Recorder, read_log
from ..soft.servo import HornMap
from . import EXPERIMENTS, Experiment
from ._logged import git_commit

TURN = "turn"


@dataclass
class GaitSearchExperiment:
    """Search gait primitives for headings (and turning) of one style of the gait library."""

    name: str = "gait_search"
    style: str = "walk"  # the library style searched (controller.library)
    # deg, body frame, searched in this order: each starts from the nearest gait found so far
    headings: list[float] = field(default_factory=lambda: [0.0, 90.0, 45.0, 60.0])
    turn: bool = True  # also search turning in place (left; right by mirror)
    free_phases: bool = True  # false: keep the starting primitive's phases
    # a library primitive, or one of the robot's schedules (conf/schedule/, shaped as a primitive), every heading
    # starts from (default: the nearest primitive)
    start_from: str | None = None
    max_evals: int = num_field(300, lo=2, hi=100000, unit="candidates per heading")
    popsize: int = num_field(12, lo=2, hi=1000, unit="")
    sigma0: float = num_field(0.15, lo=0.0, lo_open=True, hi=1.0, unit="of the tendon range")  # a new heading
    sigma_refine: float = num_field(0.04, lo=0.0, lo_open=True, hi=1.0, unit="of the tendon range")  # a known one
    duration: float = num_field(5.0, lo=0.5, hi=600.0, unit="s")  # simulated per candidate
    settle: float = num_field(1.0, lo=0.0, hi=600.0, unit="s")  # before the measured window
    verify_duration: float = num_field(8.0, lo=0.5, hi=600.0, unit="s")  # the library's measurements
    # a translating gait slower than this when verified stays out of the library (a failed heading)
    min_speed: float = num_field(5.0, lo=0.0, unit="mm/s")
    # false: search nothing; measure the library's primitives as they stand (a changed model, the report's
    # columns) and write the library with what they measured
    search: bool = True
    # every gait along a body axis (forward, backward, sideways) made its own mirror image half a cycle later before
    # it is measured (Primitive.glide_symmetric): it then turns and drifts the body neither way on any symmetric
    # model. Off by default: across 32 sampled models the lateral walk met 10 more targets and omni60 7 fewer
    # (its blend with the asymmetric 45-deg gait), and the forward walk lost its turn back from 20 deg off
    # (results/controller_sweep_sampled_glide)
    glide_symmetric: bool = False
    seed: int = num_field(1, lo=0, unit="")
    parallel: ParallelConfig = field(default_factory=ParallelConfig)

    def check(self, cfg: SlotConfig) -> None:
        if cfg.plant.name != "cosserat":
            raise ConfigError("experiment=gait_search needs the soft legs: add plant=cosserat")
        if self.style not in cfg.controller.library:
            raise ConfigError(
                f"experiment.style = {self.style!r} is not in the gait library: choose one of "
                f"{', '.join(cfg.controller.library) or '(none)'} (conf/library/)"
            )
        check_library(cfg, [self.style])  # its candidates are played at mpc.rate_hz
        if self.search and not self.headings and not self.turn:
            raise ConfigError(
                "nothing to search: give experiment.headings or experiment.turn=true "
                "(or experiment.search=false to measure the library as it stands)"
            )
        names = [p.name for p in cfg.controller.library[self.style].primitives]
        if self.start_from is not None and self.start_from not in names and self.start_from not in cfg.schedules:
            raise ConfigError(
                f"experiment.start_from = {self.start_from!r} is neither a {self.style} primitive nor a schedule: "
                f"choose one of {', '.join(names)}, or a schedule ({', '.join(cfg.schedules)})"
            )
        if self.start_from is not None and self.start_from not in names:
            check_schedule_reach(cfg, self.start_from)
        if self.settle >= self.duration:
            raise ConfigError(
                f"experiment.settle = {self.settle:g} s leaves nothing of experiment.duration = "
                f"{self.duration:g} s to measure: lower it"
            )
        if self.settle >= self.verify_duration:
            raise ConfigError(
                f"experiment.settle = {self.settle:g} s leaves nothing of experiment.verify_duration = "
                f"{self.verify_duration:g} s to measure the library's gaits over: raise verify_duration"
            )
        self.parallel.check()


# --------------------------------------------------------------------------- evaluation (in workers)
def _evaluate(task: tuple) -> dict:
    """Run one primitive open loop. It is passed whole, not as the search's vector: the vector keeps the legs'
    phases relative to the first leg's, and a schedule shifted in time is sampled at other 30 Hz ticks, so on
    the plant it is another gait (measured: the forward gait's front/back mirror image walks 31.7 mm/s as it
    stands and 15.7 mm/s shifted by 0.11 cycle to put its first leg's phase at zero). An optional sixth item
    adds constant tendon offsets (4,), deg (the heading loop's lean, :func:`_lean_probes`)."""
    cfg, style, prim, duration, settle, *rest = task
    offsets = np.asarray(rest[0], float) if rest else np.zeros(4)
    top = cfg.robot.leg.tendon_max_deg
    try:
        return run_gait(
            cfg,
            lambda t: np.clip(prim.angles(style, style.frequency_hz * t, top) + offsets, 0.0, top),
            style.frequency_hz,
            duration,
            settle,
        ).as_dict()
    except Exception as exc:  # a candidate that diverges is a bad candidate, not a failed search
        return {"error": f"{type(exc).__name__}: {exc}"}


def _style_of(cfg: SlotConfig, name: str) -> GaitStyle:
    s = cfg.controller.library[name]
    return GaitStyle(s.frequency_hz, s.duty, s.sharpness)


def _primitives(cfg: GaitStyleConfig) -> list[Primitive]:
    return [Primitive.from_config(p) for p in cfg.primitives]


def _start(prims: list[Primitive], target: float | str) -> Primitive:
    """The search's starting point: the library's primitive nearest the target, or a quarter-turn
    rotation of one (the legs' layout is nearly square-symmetric), whichever is nearer."""
    if target == TURN:
        turns = [p for p in prims if p.heading_deg is None and p.yaw_rate_dps > 0]
        if turns:
            return max(turns, key=lambda p: p.yaw_rate_dps)
        # a wave running round the body (FL, RL, RR, FR a quarter cycle apart) turns it (DESIGN.md)
        return Primitive("rotary", np.full(4, 60.0), np.full(4, 50.0), np.array([0.0, 0.25, 0.5, 0.75]))
    candidates = _with_rotations(prims)
    if candidates:
        return min(candidates, key=lambda p: _distance(p, float(target)))
    return Primitive("default", np.full(4, 60.0), np.full(4, 50.0), np.array([0.0, 0.25, 0.75, 0.5]))


def _with_rotations(prims: list[Primitive]) -> list[Primitive]:
    out = []
    for p in (p for p in prims if p.heading_deg is not None):
        for _ in range(4):
            out.append(p)
            p = p.rotated_left()
    return out


def _distance(p: Primitive, heading: float) -> float:
    return abs((p.heading_deg - heading + 180.0) % 360.0 - 180.0)


def _near(p: Primitive, target: float | str) -> bool:
    """Whether ``p`` is already a gait for ``target`` (within 10 deg, or a left turn)."""
    if target == TURN:
        return p.heading_deg is None and p.yaw_rate_dps > 0
    return p.heading_deg is not None and _distance(p, float(target)) < 10.0


def _mirrors(prim: Primitive, target: float | str) -> list[Primitive]:
    if target == TURN:
        return [prim, prim.mirrored("x")]
    images = [prim, prim.mirrored("x"), prim.mirrored("y"), prim.mirrored("x").mirrored("y")]
    out: list[Primitive] = []
    for image, heading in zip(images, _mirror_headings(float(target)), strict=True):
        if all(abs((heading - h + 180.0) % 360.0 - 180.0) > 1.0 for h in (_nominal(o) for o in out)):
            out.append(Primitive(image.name, image.base_deg, image.amplitude_deg, image.phase, heading))
    return out


def _mirror_headings(h: float) -> list[float]:
    return [h, -h, 180.0 - h, h - 180.0]


def _nominal(p: Primitive) -> float:
    return float(p.heading_deg) if p.heading_deg is not None else float("nan")


def _label(target: float | str) -> str:
    return TURN if target == TURN else f"h{float(target):+06.1f}"


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    exp = cfg.experiment
    style = _style_of(cfg, exp.style)
    top = cfg.robot.leg.tendon_max_deg
    current = _primitives(cfg.controller.library[exp.style])
    # experiment.start_from, taken from the library as it was (a searched heading may replace it in `current`)
    fixed_start = next((p for p in current if p.name == exp.start_from), None)
    if exp.start_from in cfg.schedules and fixed_start is None:  # the robot's own gait, shaped as a primitive
        horn = HornMap.from_config(cfg.robot.servo)
        steps = schedule_tendon_deg(cfg.schedules[exp.start_from], list(cfg.robot.leg.names), horn)
        fixed_start = from_steps(exp.start_from, steps, top)
    # in the order given, each heading starting from the nearest gait found so far (or a quarter turn of one)
    targets: list[float | str] = [float(h) for h in exp.headings] + ([TURN] if exp.turn else [])
    (out_dir / "logs").mkdir(parents=True, exist_ok=True)
    meta = {"config": {"yaml": resolved_yaml}, "run": {"experiment": "gait_search", "git_commit": git_commit()}}
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with (
        Recorder(out_dir / "logs" / "gait_search.mcap", metadata=meta) as rec,
        pool(exp.parallel, exp.popsize) as engine,
        Progress(*columns, console=Console(stderr=True), transient=False) as bar,
    ):
        written = 0  # candidates logged so far: the log's clock
        if not exp.search:
            targets = []
            task_all = bar.add_task("verify", total=len(current))
        for i, target in enumerate(targets):
            task = bar.add_task(f"{_label(target):<8}", total=exp.max_evals // exp.popsize * exp.popsize + 1)
            start = fixed_start if fixed_start is not None and target != TURN else _start(current, target)
            x0 = to_vector(start, top)
            sigma = exp.sigma_refine if _near(start, target) else exp.sigma0
            generation = 0

            def evaluate(xs: list[np.ndarray], target: float | str = target, task=task) -> list[float]:
                nonlocal written, generation
                costs = []
                tasks = [(cfg, style, from_vector(x, top), exp.duration, exp.settle) for x in xs]
                for x, r in zip(xs, engine.map(_evaluate, tasks), strict=True):
                    costs.append(_cost(r, target))
                    written += 1
                    rec.write(
                        "/search/candidate",
                        float(written),
                        {"target": _label(target), "generation": generation, "cost": costs[-1], "x": x, **_numeric(r)},
                    )
                generation += 1
                bar.advance(task, len(xs))
                return costs

            best = search(
                evaluate,
                x0,
                sigma0=sigma,
                popsize=exp.popsize,
                max_evals=exp.max_evals,
                seed=exp.seed + 1000 * i,
                fixed_phases=None if exp.free_phases else x0[8:].copy(),
            )
            prim = from_vector(best[1], top, f"{exp.style}_{_label(target)}")
            found = Primitive(
                prim.name,
                prim.base_deg,
                prim.amplitude_deg,
                prim.phase,
                None if target == TURN else float(target),
                1.0,
                1.0 if target == TURN else 0.0,
            )
            current = [p for p in current if not _near(p, target)] + [found]  # the next target starts from it
            _verify(cfg, style, [_glide(exp, p) for p in _mirrors(prim, target)], _label(target), engine, rec, float(i))
        if not exp.search:  # the library as it stands, measured again (each primitive with its own heading)
            for i, prim in enumerate(current):
                label = TURN if prim.heading_deg is None else _label(prim.heading_deg)
                _verify(cfg, style, [_glide(exp, prim)], label, engine, rec, float(i))
                bar.advance(task_all, 1)
    report(out_dir, cfg)


def _glide(exp: GaitSearchExperiment, prim: Primitive) -> Primitive:
    """``prim`` made glide-symmetric if it travels along a body axis and ``experiment.glide_symmetric`` asks."""
    axis = prim.along_axis() if exp.glide_symmetric else None
    return prim if axis is None else prim.glide_symmetric(axis)


LEAN_PROBE_DEG = 10.0  # the lean (deg of tendon) each translating primitive is measured with, either way


def _lean_probes(prim: Primitive, leg_yaw: np.ndarray) -> list[np.ndarray]:
    """Tendon offsets for a lean of +-LEAN_PROBE_DEG towards the left of the primitive's nominal heading."""
    pattern = lean_pattern(leg_yaw, np.radians(prim.heading_deg))
    return [LEAN_PROBE_DEG * pattern, -LEAN_PROBE_DEG * pattern]


def _verify(
    cfg: SlotConfig, style: GaitStyle, images: list[Primitive], label: str, engine, rec: Recorder, clock: float
) -> None:
    """Measure each primitive as it stands over ``experiment.verify_duration`` and log it as ``/search/verified``;
    a translating one also with the heading loop's lean either way (its turning authority while walking)."""
    exp = cfg.experiment
    leg_yaw = np.radians(cfg.robot.leg.yaw_deg)
    tasks = [(cfg, style, p, exp.verify_duration, exp.settle) for p in images]
    probed = [p for p in images if p.heading_deg is not None]
    tasks += [(cfg, style, p, exp.verify_duration, exp.settle, o) for p in probed for o in _lean_probes(p, leg_yaw)]
    results = engine.map(_evaluate, tasks)
    checks, leans = results[: len(images)], iter(results[len(images) :])
    for image, check in zip(images, checks, strict=True):
        authority = {}
        if image.heading_deg is not None:
            left, right = next(leans), next(leans)
            if "error" not in left and "error" not in right and "error" not in check:
                authority = {
                    "lean_yaw_left_dps": left["yaw_rate_dps"] - check["yaw_rate_dps"],
                    "lean_yaw_right_dps": right["yaw_rate_dps"] - check["yaw_rate_dps"],
                    "lean_speed_mm_s": 0.5 * (left["speed"] + right["speed"]),
                }
        rec.write(
            "/search/verified",
            clock,
            {
                "target": label,
                "name": image.name,
                "nominal_heading_deg": _nominal(image),
                "base_deg": image.base_deg,
                "amplitude_deg": image.amplitude_deg,
                "phase": image.phase,
                **_numeric(check),
                **authority,
            },
        )


def _cost(result: dict, target: float | str) -> float:
    if "error" in result:
        return 1e6
    return cost(GaitMetrics(**result), None if target == TURN else float(target))


def _numeric(result: dict) -> dict:
    return {k: v for k, v in result.items() if isinstance(v, (int, float))} | {"failed": "error" in result}


# --------------------------------------------------------------------------- report
def library_from_log(cfg: SlotConfig, verified: pd.DataFrame) -> GaitStyleConfig:
    """The style's library: the current primitives, with every verified one replacing those near its heading."""
    exp = cfg.experiment
    style = cfg.controller.library[exp.style]
    new: list[PrimitiveConfig] = []
    for _, row in verified.iterrows():
        if row.get("failed", False):
            continue
        if str(row["target"]) != TURN and float(row["speed"]) < exp.min_speed:
            continue  # a heading the search did not find a gait for: the library blends its neighbours
        prim = Primitive(
            str(row["name"]),
            *(np.array([row[f"{key}.{k}"] for k in range(4)]) for key in ("base_deg", "amplitude_deg", "phase")),
        )
        m = GaitMetrics(**{k: float(row[k]) for k in GaitMetrics.__dataclass_fields__ if k in row})
        turning = str(row["target"]) == TURN
        new.append(
            PrimitiveConfig(
                name=prim.name,
                heading_deg=None if turning else round(m.heading_deg, 2),
                speed_mps=round(m.speed * 1e-3, 5) if not turning else 0.0,
                yaw_rate_dps=round(m.yaw_rate_dps, 3),
                base_deg=[round(float(v), 3) for v in prim.base_deg],
                amplitude_deg=[round(float(v), 3) for v in prim.amplitude_deg],
                phase=[round(float(v), 4) for v in prim.phase],
            )
        )
    kept = []
    for p in style.primitives:
        replaced = any(
            p.name == q.name  # the same target searched again
            or (p.heading_deg is None) == (q.heading_deg is None)
            and (
                p.heading_deg is None
                and np.sign(p.yaw_rate_dps) == np.sign(q.yaw_rate_dps)
                or p.heading_deg is not None
                and abs((p.heading_deg - q.heading_deg + 180.0) % 360.0 - 180.0) < 10.0
            )
            for q in new
        )
        if not replaced:
            kept.append(p)
    return GaitStyleConfig(style.frequency_hz, style.duty, style.sharpness, kept + new)


def report(out_dir: Path, cfg: SlotConfig) -> dict:
    """Library, table of candidates, metrics and figures from ``logs/gait_search.mcap`` alone."""
    from omegaconf import OmegaConf

    from ..figures.gait_search import plot_polar, plot_search

    exp = cfg.experiment
    log = read_log(out_dir / "logs" / "gait_search.mcap")
    candidates = log["/search/candidate"] if "/search/candidate" in log else pd.DataFrame()
    verified = log["/search/verified"] if "/search/verified" in log else pd.DataFrame()
    if len(candidates):
        write_csv(candidates.drop(columns="t"), out_dir / "search.csv", index=False, float_format="%.6g")
    library = library_from_log(cfg, verified)
    text = yaml.safe_dump(
        {exp.style: OmegaConf.to_container(OmegaConf.structured(library))},
        default_flow_style=None,
        sort_keys=False,
        width=120,
    )
    write_text(
        out_dir / "library.yaml",
        "# @package controller.library\n# Written by `slot run experiment=gait_search` (style "
        f"{exp.style}); measured at sim.dt = {cfg.sim.dt:g} s.\n" + text,
    )
    best = {}
    for target, group in candidates.groupby("target") if len(candidates) else ():
        row = group.loc[group["cost"].idxmin()]
        best[str(target)] = {
            "cost": float(row["cost"]),
            "evaluations": int(len(group)),
            "vx_mm_s": float(row["vx"]),
            "vy_mm_s": float(row["vy"]),
            "yaw_rate_dps": float(row["yaw_rate_dps"]),
        }
    result = {
        "style": exp.style,
        "sim_dt_s": cfg.sim.dt,
        "best": best,
        "verified": verified.drop(columns=[c for c in verified.columns if "." in c or c == "t"]).to_dict(
            orient="records"
        )
        if len(verified)
        else [],
    }
    write_json(out_dir / "metrics.json", result)
    if len(candidates):
        plot_search(candidates, out_dir / "fig_search.png")
    if len(verified):
        plot_polar(verified, out_dir / "fig_gait_polar.png", exp.style, envelope(library, cfg.robot.leg.tendon_max_deg))
        write_text(out_dir / "library.md", library_table(verified, exp.style, cfg.sim.dt))
    return result


def envelope(library: GaitStyleConfig, top_deg: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The speed (m/s) the gait controllers ask of ``library`` at most in each body-frame heading (deg, 0-360 in
    2-deg steps): a primitive's own speed along its heading, a blend's between them
    (:meth:`slotexp.locomotion.library.GaitLibrary.max_speed`); None for a library that cannot steer (fewer
    than two translating primitives)."""
    from ..locomotion.library import GaitLibrary

    try:
        lib = GaitLibrary.from_config(library, 0.0, top_deg)
    except ConfigError:
        return None
    headings = np.arange(0.0, 361.0, 2.0)
    return headings, np.array([lib.max_speed(h) for h in headings])


def library_table(verified: pd.DataFrame, style: str, dt: float) -> str:
    """Markdown: what each verified primitive does (speed, heading, yaw rate), its feet's stroke and the stroke
    ceiling with the grip efficiency (:mod:`slotexp.locomotion.openloop`), and its turning authority: the yaw
    rate a lean of +-LEAN_PROBE_DEG adds while walking (:mod:`slotexp.locomotion.heading`), or its own while
    turning in place."""

    def num(row: pd.Series, key: str, fmt: str) -> str:
        value = row.get(key, np.nan)
        return format(float(value), fmt) if pd.notna(value) else "—"

    lines = [
        f"Gait library '{style}', each primitive measured open loop at sim.dt = {dt:g} s. Stroke: each foot's travel "
        "along its leg per cycle (mean of the four); ceiling: the speed every stroke would give gripped whole; "
        f"turning authority: the yaw rate a lean of {LEAN_PROBE_DEG:g} deg of tendon adds, to the left / right, "
        "while walking (turning primitives: their own yaw rate in place).",
        "",
        "| primitive | heading (deg) | speed (mm/s) | yaw rate (deg/s) | stroke (mm) | ceiling (mm/s) "
        "| grip efficiency | turning authority (deg/s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for _, row in verified.iterrows():
        turning = str(row["target"]) == TURN
        ceiling = float(row.get("stroke_ceiling_mm_s", np.nan))
        efficiency = float(row["speed"]) / ceiling if ceiling > 0 else np.nan
        authority = (
            f"{float(row['yaw_rate_dps']):+.2f} in place"
            if turning
            else f"{num(row, 'lean_yaw_left_dps', '+.2f')} / {num(row, 'lean_yaw_right_dps', '+.2f')}"
        )
        lines.append(
            f"| {row['name']} | {'—' if turning else num(row, 'heading_deg', '.1f')} | {num(row, 'speed', '.2f')} "
            f"| {num(row, 'yaw_rate_dps', '+.3f')} | {num(row, 'stroke_mm', '.1f')} "
            f"| {num(row, 'stroke_ceiling_mm_s', '.1f')} "
            f"| {'—' if np.isnan(efficiency) or turning else f'{efficiency:.2f}'} | {authority} |"
        )
    return "\n".join(lines) + "\n"


EXPERIMENTS.add("gait_search", Experiment(GaitSearchExperiment, run, report))
