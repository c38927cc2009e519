"""The leg maps (experiment ``legmap``): model points and fits."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .style import new_figure, save


def plot_legmap(free: pd.DataFrame, stuck: pd.DataFrame, fits: dict, stance: float, path: str | Path) -> Path:
    """Four panels: free normal force and foot position against angle (one curve per root height),
    stuck radial and normal force against the foot's offset (one curve per angle). Dots: model; lines: fits."""
    fig = new_figure(11, 7.5)
    axes = fig.subplots(2, 2)
    fine = np.linspace(free["angle_deg"].min(), free["angle_deg"].max(), 100)
    for ax, value, fit, label in (
        (axes[0, 0], "normal_n", "free_normal_n", "normal force N [N]"),
        (axes[0, 1], "foot_radial_m", "free_foot_radial_m", "foot radial position [mm]"),
    ):
        scale = 1e3 if value.endswith("_m") else 1.0
        f = fits[fit]
        for i, level in enumerate(np.unique(free["root_height_m"].to_numpy())):
            sub = free[np.isclose(free["root_height_m"], level)]
            ax.plot(
                sub["angle_deg"], scale * sub[value], "o", ms=3, color=f"C{i % 10}", label=f"h = {1e3 * level:.0f} mm"
            )
            ax.plot(fine, scale * f(fine, np.full(fine.size, level)), "-", lw=1, color=f"C{i % 10}")
        _decorate(ax, f, scale, "tendon angle [deg]", label)
    angles = np.unique(stuck["angle_deg"].to_numpy())
    for ax, value, fit, label in (
        (axes[1, 0], "radial_force_n", "stuck_radial_force_n", "radial force on the foot [N]"),
        (axes[1, 1], "normal_n", "stuck_normal_n", "normal force N [N]"),
    ):
        f = fits[fit]
        for i, level in enumerate(angles[:: max(1, len(angles) // 6)]):
            sub = stuck[np.isclose(stuck["angle_deg"], level)].sort_values("offset_m")
            dr = sub["offset_m"].to_numpy()
            ax.plot(1e3 * dr, sub[value], "o", ms=3, color=f"C{i % 10}", label=f"{level:.0f} deg")
            grid = np.linspace(dr.min(), dr.max(), 50)
            ax.plot(1e3 * grid, f(np.full(grid.size, level), grid), "-", lw=1, color=f"C{i % 10}")
        _decorate(ax, f, 1.0, "radial offset of the foot from its free rest [mm]", label)
    fig.suptitle(
        f"Leg maps: free foot (frictionless ground) and stuck foot (root at the stance height {1e3 * stance:.0f} mm)",
        fontsize=10,
    )
    return save(fig, path)


def _decorate(ax, fit, scale: float, xlabel: str, ylabel: str) -> None:
    ax.set_title(
        f"R\u00b2 = {fit.r2:.4f}, largest error {scale * fit.max_error:.3g} on the grid, "
        f"{scale * fit.holdout_max_error:.3g} held out",
        fontsize=8,
    )
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, ncols=2)
