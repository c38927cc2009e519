"""`slot bench mesh`: the soft leg's mesh against its converged limit, clamped and in closed loop.

`slot bench leg` judges each step against the converged step on the default mesh; this bench asks the other
question, how far that mesh is from the rod it discretises. The error it finds is the tendon's: the cable bends the
leg with the moment T d up to its anchor and not beyond, and the staggered rod counts the turn it is pulled through
to the last routed element's angle, at that element's middle, so the moment bends a span half an element short.
That error is first order in the element's length, where the rest of the rod converges faster (a tip load's
deflection at 31 nodes is within 0.01 mm of 241 nodes'). ``robot.leg.anchor_refinement`` splits the element before
the anchor (:func:`slotexp.soft.rod.node_arclengths`).

- **Statics** (component ``statics``): one leg clamped at its root with its tendon wound to 80 deg, free (no ground,
  no gravity) and loaded (its foot on the ground under gravity): the tension, the tip and the foot's load on even
  meshes of 31 to 241 nodes and on the 31-node mesh with the anchor's element split, each against the limit of the
  even meshes (Richardson's, first order in the element's length, from 121 and 241 nodes).
- **Closed loop** (component ``mesh``): `slot bench leg`'s cases (the forward and lateral walks, the walk with the
  heading loop off, the standing push) on each mesh at the converged step, against a fine mesh (61 nodes, the
  anchor's element split in 8) at that step, judged by the same tolerances; the finer mesh still (121 nodes) shows
  whether that reference is converged, as the reference's half step does for the step; and the meshes at the
  default step and at 1 ms, for what each costs.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..config import SlotConfig, with_settings
from ..soft.statics import clamped_leg, settle
from . import BenchRow, register
from ._accuracy import CASES, REFERENCE_DT, compare, real_time_factor, resolved, run_case, with_plant, within

TENDON_DEG = 80.0
# (label, settings) of the clamped leg's two loads
LOADS = (
    ("free leg", {"leg_load.ground": False, "sim.gravity": 0.0}),
    ("loaded leg", {"leg_load.ground": True, "sim.gravity": 9.81}),
)
EVEN = (31, 61, 121, 241)  # even meshes' node counts
SPLITS = (2, 4, 8, 16)  # the 31-node mesh's anchor element split into so many
LIMIT_FROM = (121, 241)  # the even meshes the limit is extrapolated from (first order)
STATIC_FIGURES = ("tension_n", "tip_x", "tip_z", "normal_force_n")
FINER = "(the reference's finer mesh)"  # the label of the row that shows the reference converged in space
REFERENCE_MESH = (61, 8)  # (nodes, anchor refinement) of the closed loop's reference
FINER_MESH = (121, 8)  # ... and of the check of its convergence
CASE_NAMES = ("walk", "lateral walk", "walk, heading loop off", "standing push")
# (nodes, anchor refinement) at the reference's step; then at the default step and at 1 ms
AT_REFERENCE_STEP = ((31, 1), (31, 4), (31, 8), (61, 1))
AT_LARGER_STEPS = ((31, 1), (31, 8))


def _mesh(cfg: SlotConfig, nodes: int, refinement: int) -> SlotConfig:
    return with_settings(cfg, {"robot.leg.n_nodes": nodes, "robot.leg.anchor_refinement": refinement})


def _label(nodes: int, refinement: int) -> str:
    return f"{nodes} nodes" + (f", the anchor's element split in {refinement}" if refinement > 1 else "")


def _statics_rows(cfg: SlotConfig) -> list[BenchRow]:
    rows: list[BenchRow] = []
    meshes = [(n, 1) for n in EVEN] + [(EVEN[0], r) for r in SPLITS]
    settle(clamped_leg(cfg), with_settings(cfg, {"leg_load.settle_time": 0.01}))  # compile (or load) first, untimed
    for load, settings in LOADS:
        base = with_settings(cfg, {**settings, "leg_load.tendon_deg": TENDON_DEG})
        found = {}
        for nodes, refinement in meshes:
            leg_cfg = _mesh(base, nodes, refinement)
            start = time.perf_counter()
            sim = clamped_leg(leg_cfg)
            result = settle(sim, leg_cfg)
            found[nodes, refinement] = (sim.model.n_nodes, result, time.perf_counter() - start)
        coarse, fine = (found[n, 1][1] for n in LIMIT_FROM)
        ratio = (LIMIT_FROM[1] - 1) / (LIMIT_FROM[0] - 1)  # the element's length falls by this
        limit = {k: fine[k] + (fine[k] - coarse[k]) / (ratio - 1.0) for k in STATIC_FIGURES}
        for (nodes, refinement), (n_total, result, wall) in found.items():
            errors = {f"{k}_error": result[k] - limit[k] for k in STATIC_FIGURES}
            rows.append(
                BenchRow(
                    "statics",
                    f"{load}, {_label(nodes, refinement)}",
                    wall * 1e6,
                    wall * 1e6,
                    0.0,
                    {
                        "load": load,
                        "mesh": _label(nodes, refinement),
                        "nodes": n_total,
                        **{k: result[k] for k in STATIC_FIGURES},
                        **errors,
                        "tension_error_fraction": errors["tension_n_error"] / limit["tension_n"],
                        "tip_error_mm": 1e3 * (errors["tip_x_error"] ** 2 + errors["tip_z_error"] ** 2) ** 0.5,
                        "normal_error_fraction": (
                            errors["normal_force_n_error"] / limit["normal_force_n"] if limit["normal_force_n"] else 0.0
                        ),
                        "limit": limit,
                    },
                )
            )
    return rows


def _closed_loop_rows(cfg: SlotConfig) -> list[BenchRow]:
    rows: list[BenchRow] = []
    settings = [(*mesh, REFERENCE_DT, 1) for mesh in (*AT_REFERENCE_STEP, FINER_MESH)]
    settings += [(*mesh, dt, cfg.plant.jacobian_age) for dt in (cfg.sim.dt, 1e-3) for mesh in AT_LARGER_STEPS]
    for case in (c for c in CASES if c.name in CASE_NAMES):
        case_rows: list[BenchRow] = []
        reference = run_case(with_plant(_mesh(cfg, *REFERENCE_MESH), "implicit", REFERENCE_DT, 1, 1), case)
        for nodes, refinement, dt, age in settings:
            trace = run_case(with_plant(_mesh(cfg, nodes, refinement), "implicit", dt, age, 1), case)
            result = compare(trace, reference, case.judged_from)
            speed = real_time_factor(trace)
            label = f"{case.name}, {_label(nodes, refinement)}, dt={dt:.3g}"
            if (nodes, refinement) == FINER_MESH:
                label += f" {FINER}"
            case_rows.append(
                BenchRow(
                    "mesh",
                    label,
                    float(np.median(trace.step_wall_s)) * 1e6,
                    float(np.quantile(trace.step_wall_s, 0.99)) * 1e6,
                    speed,
                    {
                        **result,
                        "case": case.name,
                        "mesh": _label(nodes, refinement),
                        "dt": dt,
                        "within_tolerance": within(result),
                        "reference": f"{_label(*REFERENCE_MESH)}, dt={REFERENCE_DT:g}",
                        "judged_from_s": case.judged_from,
                        "real_time_factor": speed,
                    },
                )
            )
        rows += resolved(case_rows, FINER)
    return rows


@register(overrides=["plant=cosserat"])
def bench_mesh(cfg: SlotConfig, out_dir: Path) -> list[BenchRow]:
    return _statics_rows(cfg) + _closed_loop_rows(cfg)
