"""Figures of the gait search: best speed per heading (polar) and the search's progress."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .style import new_figure, save


def plot_polar(
    verified: pd.DataFrame, path: str | Path, style: str, envelope: tuple[np.ndarray, np.ndarray] | None = None
) -> Path:
    """Each verified primitive at its measured heading and speed (mm/s); turning ones listed apart; and the
    ``envelope`` (headings in deg, speeds in m/s) the gait controllers clip their command to, blends included."""
    fig = new_figure(6.5, 6.0)
    ax = fig.add_subplot(projection="polar")
    moving = verified[verified["target"] != "turn"]
    theta = np.radians(moving["heading_deg"].to_numpy(float))
    speed = moving["speed"].to_numpy(float)
    for t, r, nominal in zip(theta, speed, moving["nominal_heading_deg"].to_numpy(float), strict=True):
        ax.plot([np.radians(nominal), np.radians(nominal)], [0, r], color="0.8", lw=1)
        ax.annotate("", xy=(t, r), xytext=(0, 0), arrowprops={"arrowstyle": "->", "color": "#1f77b4", "lw": 1.5})
    ax.plot(theta, speed, "o", color="#1f77b4", label="primitives: measured (arrow), asked for (grey)")
    if envelope is not None:
        headings, top = envelope
        ax.plot(np.radians(headings), 1e3 * np.asarray(top), "-", color="C1", lw=1.2, label="envelope (blends)")
    ax.set_rlabel_position(100)
    ax.set_title(f"gait library '{style}': speed [mm/s] by heading (body frame)", fontsize=9)
    turning = verified[verified["target"] == "turn"]
    text = ", ".join(
        f"{r['name']}: {r['yaw_rate_dps']:+.1f} deg/s at {r['speed']:.1f} mm/s" for _, r in turning.iterrows()
    )
    if text:
        fig.text(0.02, 0.01, "turning: " + text, fontsize=7)
    ax.legend(loc="lower right", bbox_to_anchor=(1.15, -0.02), fontsize=7)
    return save(fig, path)


def plot_search(candidates: pd.DataFrame, path: str | Path) -> Path:
    """Best and median cost per generation, one line per searched target."""
    fig = new_figure(7, 4)
    ax = fig.add_subplot()
    for i, (target, group) in enumerate(candidates.groupby("target")):
        per_gen = group.groupby("generation")["cost"]
        best = np.minimum.accumulate(per_gen.min().to_numpy())
        ax.plot(per_gen.min().index, best, "-", color=f"C{i}", label=f"{target}: best so far")
        ax.plot(per_gen.median().index, per_gen.median().to_numpy().clip(max=50), ":", color=f"C{i}", lw=1)
    ax.set_xlabel("generation")
    ax.set_ylabel("cost (lower is better; -mm/s or -deg/s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return save(fig, path)
