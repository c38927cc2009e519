"""Shared figure helpers: an Agg canvas per figure, no pyplot global state."""

from __future__ import annotations

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..atomic import replacing

LEG_COLOURS = {"FL": "#1f77b4", "RL": "#ff7f0e", "RR": "#2ca02c", "FR": "#d62728"}


def new_figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with replacing(path) as tmp:  # a reader never sees a half-written figure
        fig.savefig(tmp, dpi=150)
    return path
