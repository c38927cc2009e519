"""Figure of an identification: the search's cost, each parameter's path to its fit, and the fit's residuals."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.ticker import MaxNLocator

from .style import new_figure, save


def plot_identify(
    candidates: pd.DataFrame,
    parameters: list[str],
    spread: pd.DataFrame,
    residuals: pd.DataFrame,
    path: str | Path,
    log: Sequence[bool] = (),
    units: Sequence[str] = (),
) -> Path:
    """Top left: cost per candidate (log) and the running best. Top right: each parameter's value per candidate,
    the fit and its 68 % Delta-chi^2 range (the truth, dashed, on synthetic data), on a log axis where the
    parameter was searched in log space (``log``), labelled with its unit (``units``). Bottom: residual per
    observation of the fit, in sigmas."""
    per_row = 4
    param_rows = -(-len(parameters) // per_row)
    fig = new_figure(12.0, 3.6 * (1 + param_rows))
    grid = fig.add_gridspec(1 + param_rows, per_row)
    cost = fig.add_subplot(grid[0, 0])
    c = candidates["cost"].to_numpy(float)
    n = np.arange(1, len(c) + 1)
    failed = candidates["failed"].to_numpy(bool) if "failed" in candidates else np.zeros(len(c), bool)
    cost.semilogy(n[~failed], c[~failed], ".", color="0.6", ms=3, label="candidate")
    cost.semilogy(n, np.minimum.accumulate(c), color="#1f77b4", label="best so far")
    if failed.any():  # diverged: no cost to draw, marked along the top
        top = c[~failed].max() if (~failed).any() else 1.0
        cost.semilogy(n[failed], np.full(failed.sum(), top), "x", color="#d62728", ms=4, label="failed")
    cost.set_xlabel("candidate")
    cost.xaxis.set_major_locator(MaxNLocator(nbins=5, integer=True))
    cost.set_ylabel("cost (sum of squared residuals)")
    cost.legend(fontsize=7)
    for i, name in enumerate(parameters):
        ax = fig.add_subplot(grid[1 + i // per_row, i % per_row])
        row = spread.iloc[i]
        ax.plot(n, candidates[name].to_numpy(float), ".", color="0.6", ms=3, label="candidate")
        ax.axhspan(row["lo_68"], row["hi_68"], color="#1f77b4", alpha=0.2, label="68 % region")
        ax.axhline(row["best"], color="#1f77b4", label="fit")
        if "truth" in spread and np.isfinite(row["truth"]):
            ax.axhline(row["truth"], color="k", ls="--", lw=1, label="truth")
        if i < len(log) and log[i]:  # searched in log space: drawn so
            ax.set_yscale("log")
        ax.set_ylim(row["range_lo"], row["range_hi"])
        ax.set_xlabel("candidate")
        ax.xaxis.set_major_locator(MaxNLocator(nbins=5, integer=True))
        unit = units[i] if i < len(units) and units[i] else ""
        ax.set_ylabel(name.rsplit(".", 1)[-1] + (f" [{unit}]" if unit else ""), fontsize=8)
        ax.set_title(f"{name}\nfit {row['best']:.4g} (68 %: {row['lo_68']:.3g} to {row['hi_68']:.3g})", fontsize=8)
        if i == 0:
            ax.legend(fontsize=7, loc="best")
    bars = fig.add_subplot(grid[0, 1:])
    labels = [f"{r['gait']}: {r['observation']}" for _, r in residuals.iterrows()]
    values = residuals["residual"].to_numpy(float)
    bars.bar(np.arange(len(values)), values, color=np.where(np.abs(values) > 2, "#d62728", "#1f77b4"))
    bars.axhline(0.0, color="k", lw=0.8)
    for s in (-2, 2):
        bars.axhline(s, color="0.5", lw=0.8, ls=":")
    bars.set_xticks(np.arange(len(values)), labels, rotation=35, ha="right", fontsize=6)
    bars.set_ylabel("residual of the fit [sigma]")
    bars.set_title("each observation's residual at the fit (red: beyond 2 sigma)", fontsize=8)
    return save(fig, path)
