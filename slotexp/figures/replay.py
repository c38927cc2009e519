"""Figure of a replay: the robot's gaits on the model, headings against the robot's, distances per cycle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.ticker import ScalarFormatter

from .style import new_figure, save


def plot_replay(table: pd.DataFrame, path: str | Path) -> Path:
    """Left: each gait's heading on the robot's compass (ours an arrow, the robot's a dashed line drawn over it;
    direction only, a legend instead of labels that overlap). Right: distance per cycle, ours against the
    robot's (log scale)."""
    fig = new_figure(12.0, 5.0)
    polar = fig.add_subplot(1, 2, 1, projection="polar")
    polar.set_theta_zero_location("N")  # forward up
    polar.set_theta_direction(-1)  # clockwise: the robot's compass
    # one colour per gait: the ten default colours, or tab20's twenty where there are more gaits (held out: 13)
    colours = (
        [f"C{i}" for i in range(len(table))]
        if len(table) <= 10
        else [colormaps["tab20"](i % 20) for i in range(len(table))]
    )
    for (_, r), c in zip(table.iterrows(), colours):
        a = np.radians(r["compass_deg"])
        polar.annotate("", xy=(a, 0.8), xytext=(0, 0), arrowprops={"arrowstyle": "-|>", "color": c, "lw": 2})
        polar.plot([], [], color=c, lw=2, label=r["gait"])
    seen: dict[float, int] = {}  # gaits the robot calls the same heading: their dots step inward, one each
    for (_, r), c in zip(table.iterrows(), colours):  # on top of every arrow, out to the rim, so none hides it
        if r["robot_compass_deg"] == r["robot_compass_deg"]:  # not NaN
            a = np.radians(r["robot_compass_deg"])
            rim = 1.0 - 0.07 * seen.get(r["robot_compass_deg"], 0)
            seen[r["robot_compass_deg"]] = seen.get(r["robot_compass_deg"], 0) + 1
            polar.plot([a, a], [0.0, rim], ls=(0, (3, 2)), color=c, lw=1.3, zorder=5)
            polar.plot([a], [rim], "o", ms=6, mfc="white", mec=c, mew=1.5, zorder=6, clip_on=False)
    polar.plot([], [], ls=(0, (3, 2)), color="0.3", marker="o", mfc="white", label="robot (dashed, rim dot)")
    polar.set_ylim(0.0, 1.0)
    polar.set_yticks([])
    polar.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.12, 1.05), frameon=False)
    polar.set_title(
        "heading on the robot's compass: model (arrow) and robot\n(directions only; distances right)", fontsize=9
    )
    bars = fig.add_subplot(1, 2, 2)
    x = np.arange(len(table))
    bars.bar(x - 0.2, table["distance_per_cycle_mm"], 0.4, label="model", color="#1f77b4")
    bars.bar(x + 0.2, table["robot_distance_per_cycle_mm"].fillna(0.0), 0.4, label="robot", color="0.6")
    bars.set_yscale("log")
    bars.yaxis.set_major_formatter(ScalarFormatter())  # 1, 10, 100, not 10^0
    bars.set_xticks(x, table["gait"], rotation=30, ha="right", fontsize=8)
    bars.set_ylabel("distance per cycle [mm]")
    bars.legend(fontsize=8)
    bars.set_title("distance per cycle (robot: the authors' planner's estimate)", fontsize=9)
    return save(fig, path)
