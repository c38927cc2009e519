"""Paper Fig. 7 (cost trajectories) and Fig. 8 (Dynamic Constraint Map), from logs."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.patches import Patch

from ..mpc import CONSTRAINT_GROUPS
from ..runlog import RunData
from .style import new_figure, save

FEASIBLE, VIOLATED, FALLBACK = 0, 1, 2
DCM_COLOURS = ["#4caf50", "#e53935", "#ffb300"]
VIOLATION_TOL_N = 1e-3  # a group counts as violated above this (N), well above solver tolerances


def constraint_status(run: RunData, tol: float = VIOLATION_TOL_N) -> np.ndarray:
    """(groups, steps) codes: feasible, violated, or fallback (last feasible input applied)."""
    viol = run.violations[list(CONSTRAINT_GROUPS)].to_numpy(float).T
    status = np.where(viol > tol, VIOLATED, FEASIBLE)
    status[:, run.stats["fallback"].to_numpy(bool)] = FALLBACK
    return status


def plot_costs(
    runs: Sequence[RunData], path: str | Path, floor: float = 1e-8, ylabel: str = r"stage cost $10^3\,e^\top Q e$"
) -> Path:
    fig = new_figure(8, 4.5)
    ax = fig.add_subplot()
    for run in runs:
        ax.semilogy(run.t, np.maximum(run.cost, floor), label=run.name, lw=1.2, ls="--" if run.name == "roll" else "-")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title("MPC cost under perturbations, walk gait (cf. paper Fig. 7)")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(ncol=4, fontsize=8)
    ax.set_ylim(bottom=floor)
    return save(fig, path)


def plot_dcm(runs: Sequence[RunData], path: str | Path, title: str = "Dynamic Constraint Map, walk gait") -> Path:
    fig = new_figure(9, 0.9 + 0.75 * len(runs))
    axes = fig.subplots(len(runs), 1, sharex=True, squeeze=False)[:, 0]
    cmap = ListedColormap(DCM_COLOURS)
    for ax, run in zip(axes, runs):
        status = constraint_status(run)
        t0, t1 = run.t[0], run.t[-1] + (run.t[1] - run.t[0] if len(run.t) > 1 else 0)
        ax.imshow(
            status,
            aspect="auto",
            cmap=cmap,
            vmin=0,
            vmax=2,
            interpolation="nearest",
            extent=(t0, t1, len(CONSTRAINT_GROUPS) - 0.5, -0.5),
        )
        ax.set_yticks(range(len(CONSTRAINT_GROUPS)), CONSTRAINT_GROUPS, fontsize=7)
        n_bad = int((status != FEASIBLE).any(axis=0).sum())
        ax.set_ylabel(run.name, rotation=0, ha="right", va="center", fontsize=9)
        ax.text(1.005, 0.5, f"{n_bad} bad", transform=ax.transAxes, fontsize=7, va="center")
    axes[-1].set_xlabel("time [s]")
    handles = [Patch(color=c, label=name) for c, name in zip(DCM_COLOURS, ["feasible", "violated", "fallback"])]
    fig.legend(handles=handles, loc="outside lower center", ncol=3, fontsize=8)
    fig.suptitle(f"{title} (cf. paper Fig. 8)", fontsize=10)
    return save(fig, path)
