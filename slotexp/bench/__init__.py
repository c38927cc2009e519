"""Benchmarks (`slot bench`): each component measures variants side by side in one process.

A component is a module here, named after it, whose function
``(cfg, out_dir) -> list[BenchRow]`` is registered in :data:`COMPONENTS` with
``@register(overrides=...)``: the Hydra overrides its config needs (e.g.
``plant=cosserat``); the CLI composes each component's config from those, then the
user's overrides. ``slot bench`` runs the selected components and writes
``bench.csv`` (columns ``component,variant,median_us,p99_us,ratio_vs_baseline``)
plus ``bench.json`` with each row's extra fields, into its output directory.
Speed goals are checked here and reported with numbers, never in timed tests.
"""

from __future__ import annotations

import csv
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ..atomic import write_json
from ..config import SlotConfig
from ..registry import Registry

CSV_COLUMNS = ["component", "variant", "median_us", "p99_us", "ratio_vs_baseline"]


@dataclass
class BenchRow:
    component: str
    variant: str
    median_us: float
    p99_us: float
    ratio_vs_baseline: float  # baseline time / this time (> 1 means faster than the baseline)
    extra: dict[str, Any] = field(default_factory=dict)


Component = Callable[[SlotConfig, Path], list[BenchRow]]


@dataclass(frozen=True)
class BenchComponent:
    measure: Component
    overrides: tuple[str, ...] = ()  # Hydra overrides its config needs


COMPONENTS: Registry[BenchComponent] = Registry(__name__, "bench component")


def register(overrides: list[str] | None = None) -> Callable[[Component], Component]:
    """Register the decorated function as the component named after its module."""

    def wrap(fn: Component) -> Component:
        COMPONENTS.add(fn.__module__.rsplit(".", 1)[-1], BenchComponent(fn, tuple(overrides or ())))
        return fn

    return wrap


def write(rows: list[BenchRow], out_dir: Path) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "bench.csv"
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(CSV_COLUMNS)
        for r in rows:
            writer.writerow(
                [r.component, r.variant, f"{r.median_us:.4g}", f"{r.p99_us:.4g}", f"{r.ratio_vs_baseline:.4g}"]
            )
    write_json(out_dir / "bench.json", [asdict(r) for r in rows])
    return path
