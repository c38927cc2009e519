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


def plot_path(run: RunData, legs: list[str], path: str | Path, snapshot_s: float = 1.5) -> Path:
    fig = new_figure(8, 7.5)
    top, bottom = fig.subplots(2, 1, height_ratios=[3, 1])
    top.plot(run.x_ref[:, 3], run.x_ref[:, 4], "k--", lw=1.2, label="desired")
    top.plot(run.x[:, 3], run.x[:, 4], color="#1f77b4", lw=1.6, label="simulated")
    step = max(1, int(round(snapshot_s / (run.t[1] - run.t[0])))) if len(run.t) > 1 else 1
    for k in range(0, len(run.t), step):
        com = run.x[k, 3:5]
        for i, leg in enumerate(legs):
            cols = [f"{leg}_foot.0", f"{leg}_foot.1"]
            if cols[0] not in run.markers:
                continue
            foot = run.markers.loc[k, cols].to_numpy(float)
            top.plot([com[0], foot[0]], [com[1], foot[1]], color="0.6", lw=0.7)
            if not run.stance[k, i]:
                top.plot(*foot, "o", ms=6, mfc="none", mec=LEG_COLOURS.get(leg, "m"), mew=1.5)
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel("x [m]")
    top.set_ylabel("y [m]")
    top.grid(alpha=0.3)
    top.legend(fontsize=8, loc="best")
    top.set_title(f"path (grey: legs, circles: legs in swing; every {snapshot_s:g} s)", fontsize=9)
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
    bottom.set_xlim(run.t[0], run.t[-1] + dt)
    fig.suptitle(f"{run.run.get('gait', '?')} gait: desired vs simulated path (cf. paper Fig. 6)", fontsize=10)
    return save(fig, path)
