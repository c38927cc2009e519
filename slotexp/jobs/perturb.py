"""Experiment ``perturb``: paper Table I, Fig. 7 and Fig. 8 on the walk gait."""

from __future__ import annotations

import json
from pathlib import Path

from ..config import SlotConfig
from ..figures.perturb import plot_costs, plot_dcm
from ..runlog import RunData, find_logs, load_run
from ..tables import table1, to_markdown
from .logged import run_many


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    exp = cfg.experiment
    scenarios = [cfg.scenarios[name] for name in exp.scenarios]
    run_many(cfg, scenarios, exp.duration, out_dir / "logs", resolved_yaml, exp.n_jobs)
    order = {name: i for i, name in enumerate(exp.scenarios)}
    report(out_dir, exp.settle_fraction, exp.settle_hold_s, order)


def report(out_dir: Path, settle_fraction: float, settle_hold_s: float,
           order: dict[str, int] | None = None) -> list[RunData]:
    """Table I and Figs. 7-8 from the logs in ``out_dir/logs`` alone."""
    runs = [load_run(p) for p in find_logs(out_dir)]
    if order:
        runs.sort(key=lambda r: order.get(r.name, len(order)))
    table = table1(runs, settle_fraction, settle_hold_s)
    table.to_csv(out_dir / "table1.csv", index=False, float_format="%.6g")
    headers = ["Scenario", "Max cost", "Mean cost", "Final cost", "Settle (s)", "Infeasible steps"]
    note = (f"Stage cost J = 1000 e^T Q e; settled once J stays <= {settle_fraction:g} x max J "
            f"(for >= {settle_hold_s:g} s before the end). "
            f"Solver: {runs[0].run.get('solver', '?')}, plant: {runs[0].run.get('plant', '?')}.\n\n")
    (out_dir / "table1.md").write_text(note + to_markdown(table, headers))
    plot_costs(runs, out_dir / "fig7_cost.png")
    plot_dcm(runs, out_dir / "fig8_dcm.png")
    timing = {r.name: {"median_wall_ms": float(r.stats["wall_time_s"].median() * 1e3),
                       "p99_wall_ms": float(r.stats["wall_time_s"].quantile(0.99) * 1e3),
                       "median_iterations": float(r.stats["iterations"].median()),
                       "truncated_log": r.truncated} for r in runs}
    (out_dir / "metrics.json").write_text(json.dumps({"table1": table.to_dict(orient="records"),
                                                      "solver_timing": timing}, indent=2, default=float))
    return runs
