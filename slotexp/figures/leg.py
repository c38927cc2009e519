"""The deformed leg (experiment ``leg``) and the force-to-tendon calibration curve."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .style import new_figure, save


def plot_leg(rest: np.ndarray, shape: np.ndarray, path: str | Path, title: str, ground: bool = True) -> Path:
    """Rest and deformed centrelines in the leg's plane, millimetres from the root."""
    fig = new_figure(7, 4)
    ax = fig.add_subplot()
    root = shape[0]
    ax.plot(1e3 * (rest[:, 0] - root[0]), 1e3 * (rest[:, 1] - root[1]), "k--", lw=1, label="rest")
    ax.plot(
        1e3 * (shape[:, 0] - root[0]),
        1e3 * (shape[:, 1] - root[1]),
        "o-",
        ms=3,
        lw=1.6,
        color="#1f77b4",
        label="equilibrium",
    )
    if ground:
        ax.axhline(-1e3 * root[1], color="0.4", lw=2, label="ground")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("along the leg [mm]")
    ax.set_ylabel("height from root [mm]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=9)
    return save(fig, path)


def plot_calibration(
    angle: np.ndarray,
    fz: np.ndarray,
    fitted: np.ndarray,
    slope: float,
    offset: float,
    paper: tuple[float, float],
    path: str | Path,
) -> Path:
    fig = new_figure(7, 4.5)
    ax = fig.add_subplot()
    ax.plot(angle, fz, "o", color="#1f77b4", label="Cosserat leg, quasi-static")
    ax.plot(
        angle[fitted],
        slope * angle[fitted] + offset,
        "-",
        color="#1f77b4",
        label=f"fit: f_z = {slope:.3f} θ {offset:+.2f}",
    )
    a, b = paper
    ax.plot(angle, a * angle + b, "k--", label=f"paper eq. 11: f_z = {a:.3f} θ {b:+.2f}")
    ax.set_xlabel("tendon angle θ [deg]")
    ax.set_ylabel("ground normal force f_z [N]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_ylim(bottom=min(-0.5, float(np.nanmin(fz)) - 0.5))
    ax.set_title("force-to-tendon map, root held at the stance height", fontsize=9)
    return save(fig, path)
