"""What the gait search optimises: a primitive as a vector, and the cost of what it did on the plant.

A translating primitive for body-frame heading h, or a turning one, is the vector

    x = [b_FL, b_RL, b_RR, b_FR, a_FL, a_RL, a_RR, a_FR, phi_RL, phi_RR, phi_FR]

(tendon base and amplitude in units of the tendon's range, phases in cycles
relative to FL's), searched by CMA-ES (``cma``) within [0, 1] for the bases and
amplitudes. The cost (mm/s, lower is better) rewards the mean speed along h and
charges what a gait must not do: move across h, yaw, sink, tip over
(:func:`cost`). Turning rewards the yaw rate (deg/s) and charges translation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import numpy as np

from .openloop import GaitMetrics
from .primitives import Primitive

N_PARAMS = 11
LOWER = np.array([0.0] * 8 + [-np.inf] * 3)
UPPER = np.array([1.0] * 8 + [np.inf] * 3)

# cost weights (mm/s per unit), and the allowances below which nothing is charged
# LATERAL < 1 and a mild HEADING keep a slope toward an oblique heading from a neighbour's gait: the
# forward gait asked for 45 deg must cost less than standing still, or CMA-ES settles on standing
LATERAL = 0.5  # per mm/s across the heading
HEADING = 0.1  # per deg of heading error beyond HEADING_FREE
HEADING_FREE = 3.0  # deg
YAW_RATE = 3.0  # per deg/s
YAW_TOTAL = 3.0  # per deg of total yaw beyond YAW_FREE
YAW_FREE = 3.0  # deg
SINK = 3.0  # per mm of mean height change beyond SINK_FREE
SINK_FREE = 3.0  # mm
HEAVE = 0.5  # per mm of peak-to-peak height beyond HEAVE_FREE
HEAVE_FREE = 10.0  # mm
TILT = 1.0  # per deg of roll or pitch beyond TILT_FREE
TILT_FREE = 8.0  # deg
TURN_DRIFT = 1.0  # per mm/s of translation while turning


def to_vector(p: Primitive, top: float) -> np.ndarray:
    return np.concatenate([p.base_deg / top, p.amplitude_deg / top, p.phase[1:] - p.phase[0]])


def from_vector(x: np.ndarray, top: float, name: str = "candidate") -> Primitive:
    x = np.asarray(x, dtype=float)
    return Primitive(
        name, np.clip(x[0:4], 0.0, 1.0) * top, np.clip(x[4:8], 0.0, 1.0) * top, np.concatenate([[0.0], x[8:11]])
    )


def cost(m: GaitMetrics, heading_deg: float | None, turn_sign: int = 1) -> float:
    """The search's cost of measured metrics ``m`` (lower is better): translation along ``heading_deg``,
    or turning in place (``heading_deg`` None) in the direction ``turn_sign`` (+1 left, -1 right)."""
    charge = SINK * max(0.0, abs(m.dz_mean_mm) - SINK_FREE) + HEAVE * max(0.0, m.dz_range_mm - HEAVE_FREE)
    charge += TILT * max(0.0, max(m.roll_max_deg, m.pitch_max_deg) - TILT_FREE)
    if heading_deg is None:
        return -turn_sign * m.yaw_rate_dps + TURN_DRIFT * m.speed + charge
    along, across = m.along(heading_deg)
    charge += LATERAL * abs(across)
    if along > 0:
        charge += HEADING * max(0.0, abs(math.degrees(math.atan2(across, along))) - HEADING_FREE)
    charge += YAW_RATE * abs(m.yaw_rate_dps) + YAW_TOTAL * max(0.0, abs(m.yaw_total_deg) - YAW_FREE)
    return -along + charge


def search(
    evaluate: Callable[[list[np.ndarray]], Iterable[float]],
    x0: np.ndarray,
    *,
    sigma0: float,
    popsize: int,
    max_evals: int,
    seed: int,
    fixed_phases: np.ndarray | None = None,
    bounds: tuple[np.ndarray, np.ndarray] = (LOWER, UPPER),
    on_generation: Callable[[int, list[np.ndarray], list[float]], None] | None = None,
) -> tuple[float, np.ndarray]:
    """CMA-ES from ``x0``: ``evaluate`` maps a generation's vectors to their costs (in parallel, if it likes).

    With ``fixed_phases`` the phases stay as given (only bases and amplitudes move).
    ``bounds`` (lower, upper) default to a gait vector's; any other search passes its own.
    The start is evaluated first (one more evaluation than ``max_evals``); ``max_evals`` caps the
    generations' evaluations (only whole generations that fit are run). Returns the
    best cost seen and its vector; ``on_generation(generation, xs, costs)`` sees every
    generation (logging, progress).
    """
    import cma

    es = cma.CMAEvolutionStrategy(
        np.asarray(x0, float),
        sigma0,
        {
            "seed": seed,
            "popsize": popsize,
            "bounds": [list(bounds[0]), list(bounds[1])],
            "maxfevals": max_evals,
            "verbose": -9,
        },
    )
    x0 = np.asarray(x0, float)
    best = (float(list(evaluate([x0]))[0]), x0)  # the start is a candidate too: the search never returns worse
    generation = 0
    while not es.stop() and es.countevals + es.popsize <= max_evals:
        xs = es.ask()
        if fixed_phases is not None:
            xs = [np.concatenate([x[:8], fixed_phases]) for x in xs]
        costs = [float(c) for c in evaluate(xs)]
        for x, c in zip(xs, costs, strict=True):
            if c < best[0]:
                best = (c, np.asarray(x, float))
        es.tell(xs, costs)
        if on_generation is not None:
            on_generation(generation, xs, costs)
        generation += 1
    return best
