"""Experiment ``perturb``: paper Table I, Fig. 7 and Fig. 8 on the walk gait."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import write_csv, write_json, write_text
from ..config import SlotConfig, check_run_length, check_scenario, choice_field, num_field
from ..errors import ConfigError
from ..metrics import cycle_mean_cost, cycle_mean_cost_parts
from ..plants import STATE_NAMES
from ..runlog import RunData, find_logs, load_run
from ..tables import table1, to_markdown
from . import EXPERIMENTS, Experiment
from ._logged import run_many


@dataclass
class PerturbExperiment:
    """Paper Table I: every listed scenario on the walk gait."""

    name: str = "perturb"
    duration: float = num_field(25.0, lo=0.0, lo_open=True, hi=3600.0, unit="s")
    scenarios: list[str] = field(
        default_factory=lambda: ["baseline", "roll", "pitch", "height", "velocity", "combined", "noise"]
    )
    n_jobs: int = num_field(0, lo=0, unit="processes")  # 0 = one per core
    settle_fraction: float = num_field(0.01, lo=0.0, lo_open=True, hi=1.0, unit="")
    settle_hold_s: float = num_field(1.0, lo=0.0, unit="s")
    # step: the stage cost of every MPC step (the paper's); gait_cycle: the cost of the error averaged
    # over the last gait cycle (walking soft legs or a trotting rigid robot, whose state swings within each cycle)
    cost_average: str = choice_field("step", "step", "gait_cycle")

    def check(self, cfg: SlotConfig) -> None:
        check_run_length(cfg, self.duration)
        if self.cost_average == "gait_cycle":
            gait_period_steps(cfg)
        if not self.scenarios:
            raise ConfigError("experiment.scenarios is empty: list at least one scenario")
        for name in self.scenarios:
            check_scenario(cfg, name, "experiment.scenarios names")


def gait_period_steps(cfg: SlotConfig) -> int:
    """MPC steps in one cycle of the gait the controller walks, as the controller declares it
    (:meth:`MpcController.gait_cycle_steps`)."""
    from ..controllers import CONTROLLERS
    from ..controllers._base import MpcController

    steps = CONTROLLERS.get(cfg.controller.name).gait_cycle_steps(cfg)
    if steps is None:
        cycled = [
            name
            for name, cls in CONTROLLERS.load_all().items()
            if cls.gait_cycle_steps.__func__ is not MpcController.gait_cycle_steps.__func__
        ]
        raise ConfigError(
            f"experiment.cost_average=gait_cycle needs a controller that walks a gait cycle: "
            f"controller={cfg.controller.name} has none (use cost_average=step, or controller="
            f"{', '.join(cycled)})"
        )
    return steps


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    exp = cfg.experiment
    scenarios = [cfg.scenarios[name] for name in exp.scenarios]
    run_many(cfg, scenarios, exp.duration, out_dir / "logs", resolved_yaml, exp.n_jobs)
    report(out_dir, cfg)


def final_cost_parts(runs: Sequence[RunData], q: np.ndarray, window: int) -> dict:
    """Each scenario's final cost split by state (as Table I weighs it, ``q`` over ``window`` steps) and its
    largest term with its share: what keeps a run that does not settle from settling."""
    parts, largest = {}, {}
    for run in runs:
        final = cycle_mean_cost_parts(run.x, run.x_ref, q, window)[-1]
        parts[run.name] = {name: float(c) for name, c in zip(STATE_NAMES, final, strict=True)}
        k = int(np.argmax(final))
        largest[run.name] = f"{STATE_NAMES[k]} ({final[k] / max(final.sum(), 1e-300):.0%})"
    return {"final_cost_parts": parts, "final_cost_largest": largest}


def report(out_dir: Path, cfg: SlotConfig) -> list[RunData]:
    """Table I and Figs. 7-8 from the logs in ``out_dir/logs`` alone."""
    from ..figures.perturb import plot_costs, plot_dcm

    exp = cfg.experiment
    settle_fraction, settle_hold_s = exp.settle_fraction, exp.settle_hold_s
    order = {name: i for i, name in enumerate(exp.scenarios)}
    runs = [load_run(p) for p in find_logs(out_dir)]
    runs.sort(key=lambda r: order.get(r.name, len(order)))
    step_table = table1(runs, settle_fraction, settle_hold_s)
    q = np.asarray(cfg.mpc.q_diag, dtype=float)
    window = gait_period_steps(cfg) if exp.cost_average == "gait_cycle" else 1  # 1: each step's own cost
    if exp.cost_average == "gait_cycle":
        for run in runs:
            run.cost = cycle_mean_cost(run.x, run.x_ref, q, window)
    table = table1(runs, settle_fraction, settle_hold_s)
    write_csv(table, out_dir / "table1.csv", index=False, float_format="%.6g")
    headers = ["Scenario", "Max cost", "Mean cost", "Final cost", "Settle (s)", "Infeasible steps"]
    what = (
        "J of the error averaged over the last gait cycle"
        if exp.cost_average == "gait_cycle"
        else "Stage cost J = 1000 e^T Q e"
    )
    note = (
        f"{what}; settled once J stays <= {settle_fraction:g} x max J "
        f"(for >= {settle_hold_s:g} s before the end). "
        f"Solver: {runs[0].run.get('solver', '?')}, plant: {runs[0].run.get('plant', '?')}.\n\n"
    )
    write_text(out_dir / "table1.md", note + to_markdown(table, headers))
    if exp.cost_average == "gait_cycle":
        plot_costs(runs, out_dir / "fig7_cost.png", ylabel=r"cost of the cycle-mean error $10^3\,\bar e^\top Q \bar e$")
    else:
        plot_costs(runs, out_dir / "fig7_cost.png")
    plot_dcm(runs, out_dir / "fig8_dcm.png")
    timing = {
        r.name: {
            "median_wall_ms": float(r.stats["wall_time_s"].median() * 1e3),
            "p99_wall_ms": float(r.stats["wall_time_s"].quantile(0.99) * 1e3),
            "median_iterations": float(r.stats["iterations"].median()),
            "truncated_log": r.truncated,
        }
        for r in runs
    }
    result = {
        "table1": table.to_dict(orient="records"),
        "cost_average": exp.cost_average,
        **final_cost_parts(runs, q, window),
        "solver_timing": timing,
    }
    if exp.cost_average != "step":
        result["table1_step_cost"] = step_table.to_dict(orient="records")
    write_json(out_dir / "metrics.json", result)
    return runs


EXPERIMENTS.add("perturb", Experiment(PerturbExperiment, run, report, walks_gait=True, summary="table1.md"))
