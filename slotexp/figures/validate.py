"""Overlay figure for the ``validate`` experiment: reference vs candidate marker tracks.

Uses a bare :class:`matplotlib.figure.Figure` on an Agg canvas (no pyplot), so making a
figure leaks no global state and works headless. Positions are plotted in millimetres
because marker errors are millimetre-scale; the axis labels say so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..atomic import replacing

__all__ = ["plot_overlay"]

_AXES = ("x", "y", "z")
_CANDIDATE_COLOUR = "tab:orange"


def plot_overlay(
    times: np.ndarray,
    reference: dict[str, np.ndarray],
    candidate: dict[str, np.ndarray],
    path: str | Path,
    *,
    title: str = "",
) -> Path:
    """Save a marker-by-axis grid (rows: markers, columns: x, y, z) as a 150-dpi PNG.

    ``times`` is (n,) seconds and each dict maps a marker to an (n, 3) array in metres,
    as returned by :func:`slotexp.compare.align`. Markers present in both dicts are drawn
    in the reference's order: reference solid black, candidate dashed colour. NaN gaps
    (lost tracking) show as breaks in the lines. Returns the written path.
    """
    t = np.asarray(times, dtype=float)
    if t.ndim != 1:
        raise ValueError(f"times must be 1-D seconds, got shape {t.shape}")
    names = [m for m in reference if m in candidate]
    if not names:
        raise ValueError(
            f"no marker in both reference {sorted(reference)} and candidate {sorted(candidate)}; nothing to plot"
        )
    ref = {m: np.asarray(reference[m], dtype=float) for m in names}
    cand = {m: np.asarray(candidate[m], dtype=float) for m in names}
    for label, arrays in (("reference", ref), ("candidate", cand)):
        for m, a in arrays.items():
            if a.shape != (t.shape[0], 3):
                raise ValueError(f"{label} marker {m!r} has shape {a.shape}; expected ({t.shape[0]}, 3) to match times")

    nrows = len(names)
    fig = Figure(figsize=(11.0, 1.9 * nrows + 1.0), layout="constrained")
    FigureCanvasAgg(fig)
    axs = fig.subplots(nrows, 3, sharex=True, squeeze=False)
    for i, m in enumerate(names):
        for k, axis in enumerate(_AXES):
            ax = axs[i, k]
            ax.plot(t, ref[m][:, k] * 1e3, color="black", linestyle="-", linewidth=1.2, label="reference")
            ax.plot(t, cand[m][:, k] * 1e3, color=_CANDIDATE_COLOUR, linestyle="--", linewidth=1.2, label="candidate")
            ax.grid(True, alpha=0.3)
            ax.set_ylabel(f"{m}  {axis} [mm]" if k == 0 else f"{axis} [mm]")
            if i == 0:
                ax.set_title(axis)
            if i == nrows - 1:
                ax.set_xlabel("time [s]")
    handles, labels = axs[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper right", ncols=2, frameon=False)
    if title:
        fig.suptitle(title)

    out = Path(path)
    with replacing(out) as tmp:
        fig.savefig(tmp, dpi=150, format="png")
    return out
