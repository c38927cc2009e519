"""Tables rebuilt from logs: Table I and Markdown rendering."""

from __future__ import annotations

import math
from collections.abc import Sequence

import pandas as pd

from .metrics import settle_time
from .runlog import RunData

TABLE1_COLUMNS = ["scenario", "max_cost", "mean_cost", "final_cost", "settle_s", "infeasible_steps"]


def table1(runs: Sequence[RunData], settle_fraction: float, settle_hold_s: float) -> pd.DataFrame:
    """Paper Table I: cost statistics, settle time and infeasible (fallback) steps per scenario."""
    rows = []
    for run in runs:
        rows.append(
            {
                "scenario": run.name,
                "max_cost": float(run.cost.max()),
                "mean_cost": float(run.cost.mean()),
                "final_cost": float(run.cost[-1]),
                "settle_s": settle_time(run.t, run.cost, settle_fraction, settle_hold_s),
                "infeasible_steps": run.infeasible_steps,
            }
        )
    return pd.DataFrame(rows, columns=TABLE1_COLUMNS)


def _fmt(value) -> str:
    if isinstance(value, float):
        if math.isnan(value):
            return "—"
        return f"{value:.4g}"
    return str(value)


def to_markdown(df: pd.DataFrame, headers: Sequence[str] | None = None) -> str:
    """A GitHub-flavoured Markdown table (no extra dependency)."""
    headers = list(headers or df.columns)
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    for _, row in df.iterrows():
        lines.append("| " + " | ".join(_fmt(row[c]) for c in df.columns) + " |")
    return "\n".join(lines) + "\n"
