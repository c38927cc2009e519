"""Figure of a replay: the robot's gaits on the model, headings against the robot's, distances per cycle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .style import new_figure, save


def plot_replay(table: pd.DataFrame, path: str | Path) -> Path:
    """Left: each gait's heading on the robot's compass (ours solid, the robot's dashed). Right: distance per
    cycle, ours against the robot's (log scale)."""
    fig = new_figure(11.0, 5.0)
    polar = fig.add_subplot(1, 2, 1, projection="polar")
    polar.set_theta_zero_location("N")  # forward up
    polar.set_theta_direction(-1)  # clockwise: the robot's compass
    colours = [f"C{i}" for i in range(len(table))]
    for (_, r), c in zip(table.iterrows(), colours):
        if r["robot_compass_deg"] == r["robot_compass_deg"]:  # not NaN
            a = np.radians(r["robot_compass_deg"])
            polar.plot([a, a], [0, 1.0], ls="--", color=c, lw=1)
        a = np.radians(r["compass_deg"])
        polar.annotate("", xy=(a, 0.85), xytext=(0, 0), arrowprops={"arrowstyle": "->", "color": c, "lw": 2})
        polar.text(a, 0.95, r["gait"], color=c, fontsize=7, ha="center")
    polar.set_yticklabels([])
    polar.set_title("heading, robot's compass: model (arrow), robot (dashed)", fontsize=9)
    bars = fig.add_subplot(1, 2, 2)
    x = np.arange(len(table))
    bars.bar(x - 0.2, table["distance_per_cycle_mm"], 0.4, label="model", color="#1f77b4")
    bars.bar(x + 0.2, table["robot_distance_per_cycle_mm"].fillna(0.0), 0.4, label="robot", color="0.6")
    bars.set_yscale("log")
    bars.set_xticks(x, table["gait"], rotation=30, ha="right", fontsize=8)
    bars.set_ylabel("distance per cycle [mm]")
    bars.legend(fontsize=8)
    bars.set_title("distance per cycle (robot: where the gait file gives it)", fontsize=9)
    return save(fig, path)
