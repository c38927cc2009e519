"""Which steps carry the soft robot through its gaits, across the models the identification searches.

A step that is stable on the default model may not be on a softer or grippier one, and a search over models
must not mistake the step blowing up for a bad model. Each row plays the robot's seven visible gaits open loop
(:func:`slotexp.locomotion.schedules.play`, one batch, :data:`DURATION_S` each) on one model at one plant
setting and reports whether all ran to the end, where the first failure came, and how many periods
``plant.retakes`` took again. The models: the default and the corners of the identification's range (friction
0.05 and 1.5, E 4e6 and 2.5e7 Pa) at its lowest damping (5 /s), where a step is hardest pressed, and, where the
searches at 1 ms failed, a grippy, stiff model inside it at a low horn zero and a soft one at a high horn zero.
The settings: the default (the feet's friction solved at the step's end at 5e-4 s, the tendons wound in over the
first settling move) with and without retakes, set down at once, and at 1 and 2 ms; with the Jacobians refreshed
by turn (``plant.jacobian_turn``) at each of those steps, and so with every settling move's change wound in
(``plant.wind_in_every_move``); the secant friction at 2e-4 s with the tendons taken at once (the default
before), without retakes, wound in, and at 5e-4 s; and backward Euler (``plant.newton``) at 1, 5 and 10 ms.
Speed columns: robot-seconds simulated per wall second (the kernels compiled or loaded first, by a short run
that is not timed).
"""

from __future__ import annotations

import re
import time
from pathlib import Path

from ..config import SlotConfig, with_settings
from ..errors import DivergenceError
from ..locomotion.schedules import play
from ..plants.cosserat import SETTLE_ITERATIONS, SETTLE_S
from . import BenchRow, register
from ._accuracy import PREVIOUS_DEFAULT

DURATION_S = 8.0  # per gait, as the identification plays them
RATE_HZ = 50.0
WIND_IN_S = SETTLE_S / SETTLE_ITERATIONS  # s: plant.wind_in_s for the "wound in" row, the whole first settling move
GAITS = ["forward", "backward", "right_walk", "left_walk", "walk_45", "crawl_forward", "crawl_backward"]
# (label, the model's settings by config path): the identification's range's corners
MODELS = (
    (("default", {}),)
    + tuple(
        (label, {"robot.contact.friction": mu, "robot.leg.youngs_modulus": youngs, "robot.leg.damping_per_s": 5.0})
        for label, mu, youngs in (
            ("mu 0.05, E 4e6, c 5", 0.05, 4.0e6),
            ("mu 1.5, E 4e6, c 5", 1.5, 4.0e6),
            ("mu 0.05, E 2.5e7, c 5", 0.05, 2.5e7),
            ("mu 1.5, E 2.5e7, c 5", 1.5, 2.5e7),
        )
    )
    + (
        # inside the range, where the searches at 1 ms scored candidates failed: grippy and stiff at a low horn zero,
        # whose crawls wind a tendon to 165 deg (docs/results/gaits.md, "Headings of gaits that barely move")
        (
            "mu 1.15, E 2.19e7, c 9.2, horn zero 89.7",
            {
                "robot.contact.friction": 1.1458,
                "robot.leg.youngs_modulus": 2.188e7,
                "robot.leg.damping_per_s": 9.16,
                "robot.servo.horn_zero_deg": 89.66,
            },
        ),
        # soft at a high horn zero, where the later settling moves' change, taken at once, whips the legs
        (
            "mu 0.63, E 5.87e6, c 17.8, horn zero 139",
            {
                "robot.contact.friction": 0.627781,
                "robot.leg.youngs_modulus": 5.86656e6,
                "robot.leg.damping_per_s": 17.7972,
                "robot.servo.horn_zero_deg": 139.086,
            },
        ),
    )
)
BY_TURN = {"plant.jacobian_turn": 0.1}  # the rows that refresh the Jacobians by turn
# (label, the plant's settings by config path; the rest the config's)
SETTINGS = (
    ("default step", {}),
    ("default step, no retakes", {"plant.retakes": 0}),
    ("default step, set down at once", {"plant.wind_in_s": 0.0}),
    *((f"default, {dt * 1e3:g} ms", {"sim.dt": dt}) for dt in (1e-3, 2e-3)),
    *((f"default, {dt * 1e3:g} ms, set down at once", {"sim.dt": dt, "plant.wind_in_s": 0.0}) for dt in (1e-3, 2e-3)),
    # the Jacobians made afresh once an element has turned 0.1 rad (plant.jacobian_turn)
    ("default step, Jacobians by turn", BY_TURN),
    *((f"default, {dt * 1e3:g} ms, Jacobians by turn", {"sim.dt": dt, **BY_TURN}) for dt in (1e-3, 2e-3)),
    # ... and every settling move's change wound in (plant.wind_in_every_move)
    *(
        (f"{label}, Jacobians by turn, every move wound in", {**at, **BY_TURN, "plant.wind_in_every_move": True})
        for label, at in (
            ("default step", {}),
            ("default, 1 ms", {"sim.dt": 1e-3}),
            ("default, 2 ms", {"sim.dt": 2e-3}),
        )
    ),
    ("secant, 0.2 ms, at once (the default before)", PREVIOUS_DEFAULT),
    ("secant, 0.2 ms, at once, no retakes", {**PREVIOUS_DEFAULT, "plant.retakes": 0}),
    ("secant, 0.2 ms, wound in, no retakes", {**PREVIOUS_DEFAULT, "plant.wind_in_s": WIND_IN_S, "plant.retakes": 0}),
    ("secant, 0.5 ms, at once", {**PREVIOUS_DEFAULT, "sim.dt": 5e-4}),
    # backward Euler by Newton corrections, with the secant's settings
    *(
        (f"{dt * 1e3:g} ms, newton 8", {**PREVIOUS_DEFAULT, "sim.dt": dt, "plant.jacobian_age": 1, "plant.newton": 8})
        for dt in (1e-3, 5e-3, 1e-2)
    ),
)


def _play(cfg: SlotConfig) -> dict:
    """Play the gaits; what came of it (a divergence is a result here, not an error)."""
    start = time.perf_counter()
    try:
        _, _, retaken = play(cfg, GAITS, DURATION_S, RATE_HZ)
    except DivergenceError as err:
        found = re.search(r"diverged at t = ([0-9.eE+-]+) s", str(err))
        return {
            "ran_to_end": False,
            "diverged_at_s": float(found.group(1)) if found else float("nan"),
            "retaken_periods": float("nan"),
            "wall_s": time.perf_counter() - start,
        }
    return {
        "ran_to_end": True,
        "diverged_at_s": float("nan"),
        "retaken_periods": int(retaken.sum()),
        "wall_s": time.perf_counter() - start,
    }


@register(overrides=["plant=cosserat"])
def bench_stability(cfg: SlotConfig, out_dir: Path) -> list[BenchRow]:
    rows = []
    robot_seconds = len(GAITS) * DURATION_S
    # compile (or load) both friction laws and start the threads, untimed
    for warm in (cfg, with_settings(cfg, PREVIOUS_DEFAULT)):
        play(warm, GAITS, 0.2, RATE_HZ)
    for label, model in MODELS:
        for name, setting in SETTINGS:
            run_cfg = with_settings(cfg, {**model, **setting})
            result = _play(run_cfg)
            per_robot_s = result["wall_s"] / robot_seconds
            rate = robot_seconds / result["wall_s"] if result["ran_to_end"] else float("nan")
            rows.append(
                BenchRow(
                    "stability",
                    f"{label}: {name}",
                    per_robot_s * 1e6,
                    per_robot_s * 1e6,
                    rate,
                    {"model": label, "setting": name, "dt": run_cfg.sim.dt, **result, "robot_seconds_per_wall_s": rate},
                )
            )
    return rows
