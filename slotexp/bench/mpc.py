"""``slot bench mpc``: per-step update time of every QP backend on the same closed-loop walk.

One closed-loop run of the ``combined`` scenario (perturbed start and a push at
5 s, walk gait, ideal plant, 10 s = 300 MPC steps) is recorded with the reference
backend (Clarabel); the same sequence of MPC problems (state, reference, lever arms, contact
plan) is then replayed to each backend in this one process, a fresh instance per
pass, so every backend sees identical inputs and keeps its own warm start. Each
step is timed around the whole ``solve`` call (build or update + solve + plan
extraction). The first solve of an instance (CVXPY's compilation, numba's JIT or
cache load, OSQP/DAQP setup) and the constructor are reported separately in
``extra`` and excluded from the per-step numbers. BLAS is pinned to one thread
(the targets are for one core).
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from ..atomic import write_text
from ..backends import BACKENDS, make_mpc
from ..backends._base import single_threaded_blas
from ..composition import schema_of
from ..config import SlotConfig, SolverConfig
from ..configtree import CONF_DIR
from ..controllers.paper import PaperController
from ..figures.style import new_figure, save
from ..plants import ForceCommand, nominal_state
from ..plants.ideal import IdealPlant
from ..robot import build_robot
from ..scenarios import advance, perturbations
from ..simulation import scenario_seed
from . import BenchRow, register

SCENARIO = "combined"
DURATION_S = 10.0
PASSES = 2
BASELINE = "scs"  # the paper's stack: CVXPY + SCS
REFERENCE = "clarabel"  # objective agreement is reported against it
CONF_SOLVER = CONF_DIR / "solver"


def record_problems(cfg: SlotConfig, scenario: str = SCENARIO, duration: float = DURATION_S) -> list[tuple]:
    """The MPC problems of one closed-loop run on the ideal plant: (x, x_ref, lever_arms, plan) per step."""
    robot = build_robot(cfg.robot)
    sc = cfg.scenarios[scenario]
    plant = IdealPlant(robot, nominal_state(robot) + np.asarray(sc.offset.as_array()), cfg.sim.gravity, cfg.sim.dt)
    ctrl = PaperController(cfg, robot)
    acting = perturbations(sc)  # pushes at their own times within a period, as a run applies them
    rng = np.random.default_rng(scenario_seed(cfg.sim.seed, sc.name))
    problems = []
    for k in range(int(round(duration * cfg.mpc.rate_hz))):
        t = k * ctrl.period
        x, feet = plant.state(), plant.feet()
        step = ctrl.step(t, x, feet)
        problems.append((x, step.x_ref, feet - x[3:6], step.plan))
        advance(plant, ForceCommand(step.forces), t, ctrl.period, acting, rng)
    return problems


def solver_settings(name: str, cfg: SlotConfig) -> SolverConfig:
    """Backend ``name`` with its own conf/solver/<name>.yaml settings (or the run's, for its own backend)."""
    if name == cfg.solver.name:
        return cfg.solver
    raw = OmegaConf.to_container(OmegaConf.load(CONF_SOLVER / f"{name}.yaml"))
    raw.pop("defaults", None)  # a backend with settings of its own composes its schema
    return dataclasses.replace(schema_of("solver", name)(), **raw)


def time_backend(name: str, cfg: SlotConfig, problems: list[tuple]) -> dict:
    """Construct, solve once (setup, excluded), then time every remaining step."""

    robot = build_robot(cfg.robot)
    solver = solver_settings(name, cfg)
    t0 = time.perf_counter()
    mpc = make_mpc(cfg.mpc, solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
    t1 = time.perf_counter()
    first = mpc.solve(*problems[0])
    t2 = time.perf_counter()
    times, iters, objective, failures = [], [], [first.objective], int(not first.success)
    for problem in problems[1:]:
        start = time.perf_counter()
        sol = mpc.solve(*problem)
        times.append(time.perf_counter() - start)
        iters.append(sol.iterations)
        objective.append(sol.objective)
        failures += int(not sol.success)
    return {
        "times": np.asarray(times),
        "iterations": np.asarray(iters),
        "objective": np.asarray(objective),
        "failures": failures,
        "construct_s": t1 - t0,
        "first_solve_s": t2 - t1,
    }


@register()
def bench_mpc(cfg: SlotConfig, out_dir: Path) -> list[BenchRow]:
    """Median / p99 / max update time, iterations and setup of every backend (see the module docstring)."""
    single_threaded_blas()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    # recorded with the reference backend, so no backend under test is warmed up by the recording
    problems = record_problems(dataclasses.replace(cfg, solver=solver_settings(REFERENCE, cfg)))
    runs: dict[str, list[dict]] = {name: [] for name in BACKENDS.names()}
    for _ in range(PASSES):  # passes interleave the backends, so slow drifts of the machine hit all alike
        for name in BACKENDS.names():
            runs[name].append(time_backend(name, cfg, problems))
    merged = {name: _merge(r) for name, r in runs.items()}
    base = float(np.median(merged[BASELINE]["times"]))
    ref_obj = merged[REFERENCE]["objective"]
    rows = []
    for name, m in merged.items():
        t = m["times"] * 1e6
        med = float(np.median(t))
        rel = np.abs(m["objective"] - ref_obj) / np.abs(ref_obj)
        rows.append(
            BenchRow(
                component="mpc",
                variant=name,
                median_us=med,
                p99_us=float(np.percentile(t, 99)),
                ratio_vs_baseline=base * 1e6 / med,
                extra={
                    "max_us": float(t.max()),
                    "mean_us": float(t.mean()),
                    "iterations_median": float(np.median(m["iterations"])),
                    "iterations_max": int(m["iterations"].max()),
                    "failed_steps": int(m["failures"]),
                    "steps_timed": int(t.size),
                    "construct_s": m["construct_s"],
                    "first_solve_s": m["first_solve_s"],
                    "max_rel_objective_vs_clarabel": float(np.nanmax(rel)),
                    "scenario": SCENARIO,
                    "duration_s": DURATION_S,
                    "passes": PASSES,
                    "horizon": cfg.mpc.horizon,
                    "load_average_1min_at_start": load,
                },
            )
        )
    _plot(merged, out_dir / "mpc_update_times.png", cfg.mpc.horizon)
    _write_table(rows, out_dir / "bench_mpc.md")
    _write_csv(rows, out_dir / "bench_mpc.csv")  # `make results` copies these three into results/bench_mpc/
    return rows


def _merge(passes: list[dict]) -> dict:
    return {
        "times": np.concatenate([p["times"] for p in passes]),
        "iterations": np.concatenate([p["iterations"] for p in passes]),
        "objective": np.concatenate([p["objective"] for p in passes]),
        "failures": sum(p["failures"] for p in passes),
        "construct_s": float(np.median([p["construct_s"] for p in passes])),
        "first_solve_s": float(max(p["first_solve_s"] for p in passes)),
    }


def _plot(merged: dict, path: Path, horizon: int) -> None:
    """Empirical distribution of each backend's per-step update time (log scale)."""
    fig = new_figure(7.0, 4.0)
    ax = fig.add_subplot()
    for name, m in merged.items():
        t = np.sort(m["times"] * 1e3)
        ax.step(t, np.arange(1, t.size + 1) / t.size, where="post", label=f"{name} (median {np.median(t):.3g} ms)")
    ax.set_xscale("log")
    ax.set_xlabel("MPC update time per step (ms, build or update + solve)")
    ax.set_ylabel("fraction of steps")
    ax.set_title(f"{SCENARIO} walk, {DURATION_S:g} s closed loop, horizon {horizon}, one BLAS thread")
    ax.axvline(1000.0 / 30.0, color="grey", lw=0.8, ls="--")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    save(fig, path)


def _write_table(rows: list[BenchRow], path: Path) -> None:
    lines = [
        "| backend | median (ms) | p99 (ms) | max (ms) | x faster than SCS | iterations median / max | "
        "failed steps | first solve (s) | max rel. objective vs Clarabel |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        e = r.extra
        lines.append(
            f"| {r.variant} | {r.median_us / 1e3:.3f} | {r.p99_us / 1e3:.3f} | {e['max_us'] / 1e3:.3f} | "
            f"{r.ratio_vs_baseline:.1f} | {e['iterations_median']:g} / {e['iterations_max']} | "
            f"{e['failed_steps']} | {e['first_solve_s']:.3f} | {e['max_rel_objective_vs_clarabel']:.1e} |"
        )
    load = rows[0].extra["load_average_1min_at_start"]
    note = (
        f"`slot bench mpc`: {SCENARIO} scenario, {DURATION_S:g} s closed loop on the ideal plant, "
        f"{rows[0].extra['steps_timed']} timed steps per backend ({PASSES} passes, first solve of each pass "
        f"excluded), one process, BLAS pinned to one thread; 1-min load average at start {load:.2f}.\n\n"
    )
    write_text(path, note + "\n".join(lines) + "\n")


def _write_csv(rows: list[BenchRow], path: Path) -> None:
    cols = [
        "variant",
        "median_us",
        "p99_us",
        "max_us",
        "ratio_vs_baseline",
        "iterations_median",
        "iterations_max",
        "failed_steps",
        "first_solve_s",
        "max_rel_objective_vs_clarabel",
    ]
    out = [",".join(cols)]
    for r in rows:
        vals = {
            "variant": r.variant,
            "median_us": r.median_us,
            "p99_us": r.p99_us,
            "ratio_vs_baseline": r.ratio_vs_baseline,
            **r.extra,
        }
        out.append(",".join(str(vals[c]) if isinstance(vals[c], str) else f"{vals[c]:.6g}" for c in cols))
    write_text(path, "\n".join(out) + "\n")
