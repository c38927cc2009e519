"""``slot summarize <multirun dir>``: one table and one figure for a whole sweep.

Each job directory of a Hydra multirun (``<n>_<overrides>/`` holding
``.hydra/overrides.yaml``, ``logs/*.mcap`` and ``table1.csv`` or ``metrics.json``)
becomes one row: the solver, every setting the sweep varied, the Table I metrics
aggregated over the job's scenarios, the MPC update time (median, p99, max of
``/mpc/stats`` ``wall_time_s`` over every logged step but each log's first, which
also pays the backend's one-off setup) and the infeasible steps
(total, and in deterministic scenarios). Written as ``summary.csv``,
``summary.md`` and ``summary.png`` in the multirun directory. A sweep over commanded
velocities (``gait.velocity``) of runs that measure their speed also gets ``summary_polar.png``:
the speed made per heading beside the command and, where the controller logs it, the
library's envelope (``envelope_mps``; ``speed_of_envelope`` is the fraction made). A replay's metrics (one
object per gait) become ``<gait>.<metric>`` columns, and a sweep over one numeric setting also gets
``summary_gaits.png``: each gait's distance per cycle, and its feet's slides, against that setting.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from . import telemetry as T
from .atomic import write_csv, write_text
from .config import SlotConfig, setting_unit
from .errors import UserError
from .figures.style import new_figure, save
from .record import LogReadError, read_log
from .tables import to_markdown

OVERRIDES = Path(".hydra") / "overrides.yaml"
CONFIG = Path(".hydra") / "config.yaml"


def find_jobs(multirun_dir: Path) -> list[Path]:
    """Job directories in sweep order (Hydra's job number prefix)."""
    if not multirun_dir.is_dir():
        raise UserError(f"{multirun_dir}: not a directory: give a multirun directory (experiments/multirun/<time>)")
    jobs = [p for p in multirun_dir.iterdir() if p.is_dir() and (p / OVERRIDES).is_file()]
    if not jobs:
        raise UserError(
            f"{multirun_dir}: no job directories (<job>/.hydra/overrides.yaml): is this the output "
            f"directory of `slot run -m ...`?"
        )

    def number(p: Path) -> tuple[int, str]:
        head = p.name.split("_", 1)[0]
        return (int(head) if head.isdigit() else 1 << 30, p.name)

    return sorted(jobs, key=number)


def _overrides(job: Path) -> dict[str, str]:
    try:
        items = yaml.safe_load((job / OVERRIDES).read_text()) or []
    except (OSError, yaml.YAMLError) as exc:
        raise UserError(f"{job / OVERRIDES}: cannot read the job's overrides ({exc.__class__.__name__})") from exc
    if not isinstance(items, list):
        raise UserError(
            f"{job / OVERRIDES}: expected Hydra's list of overrides (- key=value), found a {type(items).__name__}"
        )
    out = {}
    for item in items:
        key, _, value = str(item).partition("=")
        if not key.lstrip("+~").startswith("hydra"):
            out[key.lstrip("+~")] = value
    return out


def _deterministic(job: Path) -> dict[str, bool]:
    """Scenario name -> deterministic, from the job's composed config (all deterministic if unknown)."""
    try:
        cfg = yaml.safe_load((job / CONFIG).read_text()) or {}
    except (OSError, yaml.YAMLError):
        return {}
    return {name: bool(sc.get("deterministic", True)) for name, sc in (cfg.get("scenarios") or {}).items()}


def _metrics(job: Path) -> dict[str, float]:
    """Table I aggregated over the job's scenarios, or the flat numbers of metrics.json."""
    table = job / "table1.csv"
    if table.is_file():
        try:
            t = pd.read_csv(table)
            settle = pd.to_numeric(t["settle_s"], errors="coerce")
            costs = t[["max_cost", "mean_cost", "final_cost"]].apply(pd.to_numeric, errors="raise")
        except (pd.errors.ParserError, pd.errors.EmptyDataError, KeyError, ValueError, TypeError) as exc:
            raise UserError(
                f"{table}: not a Table I written by slot ({exc.__class__.__name__}); rerun the job"
            ) from exc
        return {
            "scenarios": len(t),
            "max_cost": float(costs["max_cost"].max()),
            "mean_cost": float(costs["mean_cost"].mean()),
            "final_cost_max": float(costs["final_cost"].max()),
            "settle_s_max": float(settle.max()) if settle.notna().any() else math.nan,
            "unsettled": int(settle.isna().sum()),
        }
    path = job / "metrics.json"
    if path.is_file():
        try:
            data = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise UserError(f"{path}: not readable JSON ({exc.__class__.__name__}); rerun the job") from exc
        if not isinstance(data, dict):
            raise UserError(f"{path}: expected a JSON object of metrics, found a {type(data).__name__}")
        return _numbers(data)
    return {}


def _numbers(data: dict, prefix: str = "") -> dict[str, float]:
    """The numbers of a metrics object, a nested object's as ``outer.inner`` (a replay's ``forward.distance...``)."""
    out: dict[str, float] = {}
    for k, v in data.items():
        if isinstance(v, dict):
            out.update(_numbers(v, f"{prefix}{k}."))
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[f"{prefix}{k}"] = float(v)
    return out


def _command(velocity: str) -> dict[str, float]:
    """A swept ``gait.velocity`` ([vx, vy] m/s, body frame) as its heading (deg, 0-360) and speed (m/s)."""
    try:
        vx, vy = (float(v) for v in yaml.safe_load(velocity))
    except (yaml.YAMLError, TypeError, ValueError):  # not a planar velocity: nothing to add
        return {}
    return {"command_heading_deg": math.degrees(math.atan2(vy, vx)) % 360.0, "command_speed_mps": math.hypot(vx, vy)}


def _plot_polar(table: pd.DataFrame, path: Path) -> None:
    """A sweep over commanded velocities: per job, the speed made at its direction of travel beside the command
    and (where logged) the library's envelope, on the robot's compass (body frame, the robot starts at zero yaw)."""
    heading = np.radians(table["command_heading_deg"].to_numpy(float))
    order = np.argsort(heading)
    travel = heading + np.radians(table.get("heading_error_deg", pd.Series(0.0, index=table.index)).fillna(0.0))

    def closed(a: np.ndarray) -> np.ndarray:  # the line around the compass, back to its first point
        a = np.asarray(a, float)[order]
        return np.append(a, a[0]) if len(a) > 2 else a

    fig = new_figure(6.5, 6.0)
    ax = fig.add_subplot(projection="polar")
    ax.plot(closed(heading), closed(1e3 * table["command_speed_mps"].to_numpy(float)), "--", color="0.6", lw=1,
            label="commanded")  # fmt: skip
    if "envelope_mps" in table:
        ax.plot(closed(heading), closed(1e3 * table["envelope_mps"].to_numpy(float)), "-", color="C1", lw=1.2,
                label="the library's envelope (open loop)")  # fmt: skip
    ax.plot(closed(travel), closed(1e3 * table["speed_mps"].to_numpy(float)), "o-", color="C0", lw=1.2,
            label="made (closed loop), at its direction of travel")  # fmt: skip
    ax.set_rlabel_position(100)
    ax.set_title("speed [mm/s] by commanded heading (body frame)", fontsize=9)
    ax.legend(loc="lower right", bbox_to_anchor=(1.15, -0.02), fontsize=7)
    save(fig, path)


def _from_logs(job: Path, deterministic: dict[str, bool]) -> tuple[dict[str, float], dict[str, float]]:
    """What the job's logs say, each log read once: the update time over every logged MPC step and the
    infeasible (fallback) steps; and, for a job of one run whose controller logs it (``/controller``
    ``max_speed``, controller=gait_mpc), the gait library's envelope in the command's direction (m/s, the
    median over the run of what the gaits measured there open loop), so that a sweep over commands sets the
    speed the closed loop made beside what its gaits promised. Table I's scenarios have no one direction."""
    walls, infeasible, infeasible_det, steps = [], 0, 0, 0
    incomplete: list[str] = []
    envelope: dict[str, float] = {}
    paths = sorted((job / "logs").glob("*.mcap"))
    for path in paths:
        try:
            log = read_log(path, topics=(T.MPC_STATS, T.CONTROLLER))
        except LogReadError as exc:
            raise UserError(f"{path}: {str(exc).splitlines()[0]}") from exc
        if log.truncated or "summary" not in log.metadata:  # killed, or stopped before its end
            incomplete.append(path.name)
        if len(paths) == 1 and T.CONTROLLER in log and "max_speed" in log[T.CONTROLLER]:
            envelope["envelope_mps"] = float(np.median(log[T.CONTROLLER]["max_speed"].to_numpy(float)))
        if T.MPC_STATS not in log:
            continue
        stats = log[T.MPC_STATS]
        walls.append(stats["wall_time_s"].to_numpy(float)[1:])  # the first step also pays one-off setup
        fallback = int(stats["fallback"].astype(bool).sum())
        infeasible += fallback
        scenario = log.metadata.get("run", {}).get("scenario", path.stem)
        infeasible_det += fallback if deterministic.get(scenario, True) else 0
        steps += len(stats)
    w = np.concatenate(walls) * 1e3 if walls else np.zeros(0)
    logs = "missing" if not paths else ("incomplete: " + " ".join(incomplete) if incomplete else "complete")
    timing: dict[str, float | str] = {"logs": logs, "steps": steps}
    if w.size:
        timing["update_median_ms"] = float(np.median(w))
        timing["update_p99_ms"] = float(np.percentile(w, 99))
        timing["update_max_ms"] = float(w.max())
    timing.update(infeasible_steps=infeasible, infeasible_deterministic=infeasible_det)
    return timing, envelope


def summarize(multirun_dir: Path) -> pd.DataFrame:
    """The summary table (one row per job); also writes summary.csv/.md/.png into ``multirun_dir``."""
    multirun_dir = Path(multirun_dir)
    jobs = find_jobs(multirun_dir)
    overrides = {job: _overrides(job) for job in jobs}
    keys = sorted({k for o in overrides.values() for k in o})
    swept = [k for k in keys if len({o.get(k) for o in overrides.values()}) > 1 and k != "solver"]
    rows = []
    for job in jobs:
        o = overrides[job]
        row = {"job": job.name, "solver": o.get("solver", _configured_solver(job))}
        row.update({k: o.get(k, "") for k in swept})
        if "gait.velocity" in swept:
            row.update(_command(o.get("gait.velocity", "")))
        timing, envelope = _from_logs(job, _deterministic(job))
        row.update(_metrics(job))
        row.update(envelope)
        if "speed_mps" in row and row.get("envelope_mps", 0.0) > 0.0:
            row["speed_of_envelope"] = row["speed_mps"] / row["envelope_mps"]
        row.update(timing)
        if row["logs"] != "complete":
            print(f"warning: {job.name}: logs {row['logs']}: its row is not a whole run", file=sys.stderr)
        rows.append(row)
    table = pd.DataFrame(rows)
    missing = missing_jobs(multirun_dir, jobs)
    gap = ""
    if missing:
        shown = ", ".join(str(n) for n in missing[:10]) + (", ..." if len(missing) > 10 else "")
        gap = f" {len(missing)} planned job(s) have no directory (numbers {shown}): the sweep was cut short."
        print(f"warning: {multirun_dir}:{gap} The summary covers the {len(jobs)} that ran", file=sys.stderr)
    write_csv(table, multirun_dir / "summary.csv", index=False, float_format="%.6g")
    write_text(
        multirun_dir / "summary.md",
        f"Sweep `{multirun_dir}`: {len(jobs)} jobs.{gap} Update time = /mpc/stats wall_time_s (build or update + "
        f"solve) over every logged MPC step but each log's first (one-off setup); infeasible = fallback steps "
        f"(deterministic: in scenarios without noise); logs: complete, incomplete (a log cut off or stopped "
        f"before its end: that row is not a whole run) or missing.\n\n" + to_markdown(table) + "\n",
    )
    _plot(table, multirun_dir / "summary.png")
    if "command_heading_deg" in table and "speed_mps" in table:
        _plot_polar(table, multirun_dir / "summary_polar.png")
    setting = _numeric_setting(table, swept)
    gaits = [c[: -len(DISTANCE)] for c in table.columns if c.endswith(DISTANCE)]
    if setting and gaits:
        _plot_gaits(table, setting, gaits, multirun_dir / "summary_gaits.png")
    return table


DISTANCE = ".distance_per_cycle_mm"  # a replay's per-gait distance column (its metrics.json, one object per gait)


def _numeric_setting(table: pd.DataFrame, swept: list[str]) -> str | None:
    """The sweep's one varied setting where it is a number (a model setting such as robot.leg.youngs_modulus);
    None for several, or a non-number."""
    if len(swept) != 1:
        return None
    values = pd.to_numeric(table[swept[0]], errors="coerce")
    return swept[0] if values.notna().all() else None


def _plot_gaits(table: pd.DataFrame, setting: str, gaits: list[str], path: Path) -> None:
    """A replay swept over one model setting: each gait's distance per cycle against it, and (where measured) how
    far its feet travel over the ground per cycle, the one that holds best and the one that slides most: where a
    gait falls off and which feet change from sliding to holding there (docs/results/gaits.md)."""
    x = pd.to_numeric(table[setting]).to_numpy(float)
    order = np.argsort(x)
    slides = [g for g in gaits if f"{g}.slide_min_mm" in table]
    fig = new_figure(6.5, 5.5 if slides else 3.5)
    axes = fig.subplots(2 if slides else 1, 1, sharex=True, squeeze=False)[:, 0]
    for i, g in enumerate(gaits):
        axes[0].plot(x[order], table[f"{g}{DISTANCE}"].to_numpy(float)[order], "o-", color=f"C{i}", label=g)
    axes[0].set_ylabel("distance per cycle (mm)")
    axes[0].legend(fontsize=7)
    for i, g in enumerate(slides):
        for key, style, which in (("slide_min_mm", "o-", "least"), ("slide_max_mm", "s--", "most")):
            axes[1].plot(
                x[order], table[f"{g}.{key}"].to_numpy(float)[order], style, color=f"C{i}", label=f"{g}: {which}"
            )
    if slides:
        axes[1].set_ylabel("foot's slide (mm per cycle)")
        axes[1].legend(fontsize=7)
    unit = setting_unit(SlotConfig(), setting)  # the schema's, where the setting is the base config's
    axes[-1].set_xlabel(setting + (f" [{unit}]" if unit else ""))
    save(fig, path)


def missing_jobs(multirun_dir: Path, jobs: list[Path]) -> list[int]:
    """The numbers of the jobs the sweep planned (``multirun.yaml``: every combination of its swept values,
    Hydra's basic sweeper) that have no directory: a sweep stopped before them. Empty where the plan is unknown."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        plan = yaml.safe_load((multirun_dir / "multirun.yaml").read_text()) or {}
        task = plan["hydra"]["overrides"]["task"]
        planned = 1
        for o in OverridesParser.create().parse_overrides(list(task)):
            if o.is_sweep_override():
                planned *= len(list(o.sweep_string_iterator()))
    except (OSError, yaml.YAMLError, KeyError, TypeError, HydraException):  # no plan to compare with: nothing to say
        return []
    found = {int(j.name.split("_", 1)[0]) for j in jobs if j.name.split("_", 1)[0].isdigit()}
    return [n for n in range(planned) if n not in found]


def _configured_solver(job: Path) -> str:
    try:
        cfg = yaml.safe_load((job / CONFIG).read_text()) or {}
        return str((cfg.get("solver") or {}).get("name", "?"))
    except (OSError, yaml.YAMLError):
        return "?"


def _plot(table: pd.DataFrame, path: Path) -> None:
    """Update time (median and p99) and infeasible steps per job."""
    fig = new_figure(max(6.0, 1.1 * len(table) + 2.0), 5.5)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[2, 1])
    labels = [
        f"{r['solver']}"
        + "".join(  # key and value on lines of their own: a sweep over vectors has long values side by side
            f"\n{c}=\n{r[c]}" for c in table.columns if c not in _FIXED and isinstance(r[c], str) and r[c]
        )
        for _, r in table.iterrows()
    ]
    x = np.arange(len(table))
    for col, offset, name in (("update_median_ms", -0.2, "median"), ("update_p99_ms", 0.2, "p99")):
        if col in table:
            top.bar(x + offset, table[col], width=0.4, label=name)
    top.set_yscale("log")
    top.set_ylabel("MPC update (ms)")
    top.axhline(1000.0 / 30.0, color="grey", lw=0.8, ls="--", label="33 ms period")
    top.legend(fontsize=8)
    top.grid(True, axis="y", which="both", alpha=0.3)
    if "infeasible_steps" in table:
        bottom.bar(x, table["infeasible_steps"], color="#d62728")
        for xi, v in zip(x, table["infeasible_steps"]):
            bottom.annotate(f"{int(v)}" if np.isfinite(v) else "—", (xi, 0), ha="center", va="bottom", fontsize=8)
        top_count = float(np.nanmax(table["infeasible_steps"])) if len(table) else 0.0
        bottom.set_ylim(0, max(1.0, 1.25 * top_count))
    bottom.set_ylabel("infeasible steps")
    bottom.set_xticks(x, labels, fontsize=7)
    save(fig, path)


_FIXED = {"job", "solver", "logs"}
