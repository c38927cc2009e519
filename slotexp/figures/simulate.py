"""Paper Fig. 4 (CoM x, y, z against time) and Fig. 6 (path against desired, with the gait sequence)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..runlog import RunData
from .style import LEG_COLOURS, new_figure, save


def plot_com(run: RunData, path: str | Path) -> Path:
    fig = new_figure(8, 6)
    axes = fig.subplots(3, 1, sharex=True)
    for ax, i, name in zip(axes, (3, 4, 5), "xyz"):
        ax.plot(run.t, run.x_ref[:, i], "k--", lw=1.2, label="reference")
        ax.plot(run.t, run.x[:, i], color="#1f77b4", lw=1.4, label="simulated")
        ax.set_ylabel(f"CoM {name} [m]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("time [s]")
    gait = run.run.get("gait", "?")
    fig.suptitle(f"CoM trajectory, {gait} gait, {run.run.get('plant', '?')} plant (cf. paper Fig. 4)", fontsize=10)
    return save(fig, path)


def path_error_mm(x_ref: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The CoM's planar error (mm, simulated minus desired) along and across the desired path's direction
    (its overall displacement; the world x and y axes for a path that does not travel)."""
    d = x_ref[-1, 3:5] - x_ref[0, 3:5]
    norm = float(np.hypot(*d))
    u = d / norm if norm > 1e-9 else np.array([1.0, 0.0])
    e = 1000.0 * (x[:, 3:5] - x_ref[:, 3:5])
    return e @ u, e @ np.array([-u[1], u[0]])


def plot_path(run: RunData, legs: list[str], path: str | Path, snapshots: int = 6) -> Path:
    """The path in plan view (desired dashed, simulated solid, the robot drawn at ``snapshots`` instants with
    its legs in their colours: filled feet in stance, hollow in swing), the error along and across the
    desired path against time (what the plan view is too coarse to show), and the gait sequence."""
    fig = new_figure(8, 9)
    top, err, bottom = fig.subplots(3, 1, height_ratios=[3.2, 1.1, 1])
    picks = np.unique(np.linspace(0, len(run.t) - 1, snapshots).round().astype(int)) if len(run.t) else []
    labelled: list[np.ndarray] = []  # where a time is written: one label per place (a robot turning in place)
    for k in picks:
        com = run.x[k, 3:5]
        for i, leg in enumerate(legs):
            cols = [f"{leg}_foot.0", f"{leg}_foot.1"]
            if cols[0] not in run.markers:
                continue
            foot = run.markers.loc[k, cols].to_numpy(float)
            colour = LEG_COLOURS.get(leg, "m")
            top.plot([com[0], foot[0]], [com[1], foot[1]], color=colour, lw=0.8, alpha=0.45)
            top.plot(*foot, "o", ms=5, mec=colour, mfc="none" if not run.stance[k, i] else colour, alpha=0.8)
        if all(np.hypot(*(com - p)) > 0.01 for p in labelled):
            top.annotate(f"{run.t[k]:.0f} s", com, textcoords="offset points", xytext=(4, -10), fontsize=7, color="0.3")
            labelled.append(com)
    top.plot(run.x_ref[:, 3], run.x_ref[:, 4], "k--", lw=1.4, label="desired", zorder=3)
    top.plot(run.x[:, 3], run.x[:, 4], color="#9467bd", lw=1.8, label="simulated", zorder=4)
    for leg in legs:  # the legs' colours, for the plan view and the gait sequence below
        top.plot([], [], color=LEG_COLOURS.get(leg, "m"), lw=2, label=f"{leg} leg")
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel("x [m]")
    top.set_ylabel("y [m]")
    top.grid(alpha=0.3)
    top.legend(fontsize=8, loc="best", ncols=2)
    top.set_title("path, with the robot at six instants (feet: filled in stance, hollow in swing)", fontsize=9)
    along, across = path_error_mm(run.x_ref, run.x)
    err.plot(run.t, along, color="#8c564b", lw=1.2, label="along the path (+ ahead)")
    err.plot(run.t, across, color="#17becf", lw=1.2, label="across it (+ to the left)")
    err.axhline(0.0, color="k", lw=0.6)
    err.set_ylabel("CoM error [mm]")
    err.set_xlabel("time [s]")
    err.grid(alpha=0.3)
    err.legend(fontsize=8, loc="best")
    err.set_title("simulated minus desired position", fontsize=9)
    dt = run.t[1] - run.t[0] if len(run.t) > 1 else 1.0
    for i, leg in enumerate(legs):
        swing = ~run.stance[:, i]
        starts = np.flatnonzero(np.diff(np.concatenate([[0], swing.astype(int)])) == 1)
        ends = np.flatnonzero(np.diff(np.concatenate([swing.astype(int), [0]])) == -1)
        bottom.broken_barh(
            [(run.t[a], run.t[b] - run.t[a] + dt) for a, b in zip(starts, ends)],
            (i - 0.4, 0.8),
            color=LEG_COLOURS.get(leg, "m"),
        )
    bottom.set_yticks(range(len(legs)), legs)
    bottom.set_xlabel("time [s]")
    bottom.set_title("gait sequence the MPC plans with (bars: swing, the low-friction phase)", fontsize=9)
    for ax in (err, bottom):
        ax.set_xlim(run.t[0], run.t[-1] + dt)
    fig.suptitle(f"{run.run.get('gait', '?')} gait: desired vs simulated path (cf. paper Fig. 6)", fontsize=10)
    return save(fig, path)
