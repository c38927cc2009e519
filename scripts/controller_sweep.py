"""Does any setting of the heading loop hold the closed-loop targets on every model? A sweep.

The closed-loop issue asks for one set of controller settings that holds on models across the
ranges identification reported. This script samples the heading loop's settings (gains, the lean's
reach, the attitude trim, the averaging) and runs the soft closed loop's walk, lateral walk and
omni60 on each model, scoring the issue's targets. Two models are held out: their columns are
written but never used to rank a setting (``summarize`` ranks by the others alone).

It needs only the numerical core, DAQP and PyYAML, so a many-core node without the project's CLI
environment can run it from the package's source (it ran on a lent 16-core node: 357 runs, 307 s):

    python scripts/controller_sweep.py save DIR               # here: the models and the settings
    python scripts/controller_sweep.py run DIR --deadline 370  # there (or here): DIR/sweep.jsonl
    python scripts/controller_sweep.py summarize DIR           # here: DIR/summary.csv, DIR/per_model.csv

Each run is one process (``spawn``) with one thread; every kernel is compiled once before the
workers start, so they load it from numba's cache. Runs are written as they end, so a run stopped at
its deadline leaves every finished one readable.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import pickle
import random
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# The models: make_results' four robustness models, the default, and two held out (never used to rank).
MODELS = {
    "default": [],
    "mu0.4": ["robot.contact.friction=0.4"],
    "mu0.2_E1.4e7_d10": ["robot.contact.friction=0.2", "robot.leg.youngs_modulus=1.4e7", "robot.leg.damping_per_s=10"],
    "E2e7_d5": ["robot.leg.youngs_modulus=2e7", "robot.leg.damping_per_s=5"],
    "mu0.8_E7e6_d50": ["robot.contact.friction=0.8", "robot.leg.youngs_modulus=7e6", "robot.leg.damping_per_s=50"],
    "HELDOUT_mu0.15_E1.2e7_d30": [
        "robot.contact.friction=0.15",
        "robot.leg.youngs_modulus=1.2e7",
        "robot.leg.damping_per_s=30",
    ],
    "HELDOUT_mu0.6_E9e6_d20": [
        "robot.contact.friction=0.6",
        "robot.leg.youngs_modulus=9e6",
        "robot.leg.damping_per_s=20",
    ],
}
HELD_OUT = "HELDOUT_"
# ``save --sample-models N``: N models drawn across the ranges identification reported (the closed-loop issue's:
# friction 0.1-0.8, E 7e6-2e7 Pa, damping 5-50 /s), E and damping log-uniform; an evaluation of one setting, so they
# are held out (named with HELD_OUT) and rank nothing. (The horn zero, 90-130 deg, maps horn angles to tendon angles:
# a controller that commands tendon angles runs the same at any, make_results.py.)
SAMPLED = {
    "robot.contact.friction": ("uniform", 0.1, 0.8, 3),
    "robot.leg.youngs_modulus": ("log", 7e6, 2e7, -4),
    "robot.leg.damping_per_s": ("log", 5.0, 50.0, 1),
}
# The cases (velocity m/s, duration s) and targets: walks yaw <= 2 deg, drift <= 10 mm per 0.8 m, speed
# within 5 %; omni60 yaw <= 3 deg, path RMSE <= 35 mm, speed within 10 %.
CASES = {"walk": ((0.02, 0.0), 30.0), "lateral": ((0.0, 0.015), 30.0), "omni60": ((0.0075, 0.0129904), 45.0)}
# on sampled models also the forward walk commanded beyond every model's reach: what that model can make (no targets)
CEILING = {"ceiling": ((0.03, 0.0), 20.0)}
SETTINGS_BOX = {  # the heading loop's settings: sampled log-uniformly, uniformly or from two; decimals kept
    "heading_kp": ("log", 4.0, 30.0, 2),
    "heading_ki": ("log", 0.25, 4.0, 3),
    "max_lean_deg": ("uniform", 10.0, 30.0, 1),
    "attitude_trim": ("log", 0.03, 0.3, 3),
    "heading_cycles": ("choice", 1, 2, 0),
}
# held, not sampled, but written into every setting (results/controller_sweep ran with attitude_from_plan true and
# blend_hold 1)
RECORDED = ("attitude_from_plan", "blend_hold", "heading_learn_sign", "height_trim")
_MODELS: dict | None = None


def _draw(rng: random.Random, kind: str, a: float, b: float, decimals: int) -> float:
    """One value from ``[a, b]``: log-uniform or uniform, rounded to ``decimals``."""
    if kind == "log":
        return round(math.exp(rng.uniform(math.log(a), math.log(b))), decimals)
    return round(rng.uniform(a, b), decimals)


def sampled_models(n: int, seed: int) -> dict[str, list[str]]:
    """``n`` models across :data:`SAMPLED`'s ranges, as overrides, each named by its values (and held out)."""
    rng = random.Random(seed)
    models = {}
    for i in range(n):
        values = {k: _draw(rng, *spec) for k, spec in SAMPLED.items()}
        mu, e, d = values.values()
        models[f"{HELD_OUT}S{i:02d}_mu{mu:g}_E{e:.3g}_d{d:g}"] = [f"{k}={v}" for k, v in values.items()]
    return models


def save(out: Path, n: int, seed: int, grid: tuple[str, list[float]] | None = None, sample_models: int = 0) -> None:
    """The models' configs (pickled, without their experiment) and the default plus ``n`` sampled settings; with
    ``grid`` (a setting and its values), the default and then the default with that setting at each value; with
    ``sample_models``, that many models drawn across the ranges (:data:`SAMPLED`) instead of :data:`MODELS`,
    each also run at the forward ceiling (:data:`CEILING`)."""
    from slotexp.cli import compose_config

    out.mkdir(parents=True, exist_ok=True)
    models = {"default": [], **sampled_models(sample_models, seed)} if sample_models else MODELS
    cfgs = {k: dataclasses.replace(compose_config(["plant=cosserat", *v]), experiment=None) for k, v in models.items()}
    cases = {**CASES, **CEILING} if sample_models else CASES
    (out / "cases.json").write_text(json.dumps(cases) + "\n")
    if sample_models:
        (out / "models.json").write_text(json.dumps(models, indent=1) + "\n")
    (out / "models.pkl").write_bytes(pickle.dumps(cfgs))
    c = cfgs["default"].controller
    settings = [{k: getattr(c, k) for k in SETTINGS_BOX}]
    rng = random.Random(seed)
    for _ in range(n):
        s = {}
        for k, (kind, a, b, decimals) in SETTINGS_BOX.items():
            s[k] = rng.choice([a, b]) if kind == "choice" else _draw(rng, kind, a, b, decimals)
        settings.append(s)
    if grid is not None:
        key, values = grid
        settings = [settings[0], *({**settings[0], key: type(getattr(c, key))(v)} for v in values)]
    for s in settings:  # held at the default, but written down: a sweep records the loop it ran
        s.update({k: getattr(c, k) for k in RECORDED if k not in s})
    (out / "settings.json").write_text(json.dumps(settings, indent=1) + "\n")
    print(f"wrote {out}/models.pkl ({len(cfgs)} models) and settings.json ({len(settings)} settings, seed {seed})")


def metrics(t, x, velocity, height: float) -> dict:
    """The issue's measures of one run: :func:`slotexp.metrics.tracking` (as `experiment=simulate` measures it)
    against the path the velocity asks for from where the robot starts, the largest roll, and the mean height
    over the run's second half against the reference ``height`` (m)."""
    import numpy as np

    from slotexp.metrics import tracking

    x_ref = np.zeros_like(x)
    x_ref[:, 3:5] = x[0, 3:5] + np.outer(t - t[0], velocity)  # yaw 0: no yaw rate is commanded
    m = tracking(t, x, x_ref, velocity, 0.8)
    return {
        "speed_error": m["speed_error_fraction"],
        "yaw_drift_deg": m["yaw_drift_deg"],
        "drift_per_08m_mm": 800.0 * m["lateral_drift_per_m"],
        "path_rmse_mm": 1000.0 * m["path_rmse_m"],
        "roll_max_deg": float(np.degrees(np.max(np.abs(x[:, 0])))),
        "height_offset_mm": 1000.0 * (float(np.mean(x[len(x) // 2 :, 5])) - height),
    }


def _task(args: tuple) -> dict:
    """One closed-loop run: a setting on a model in a case."""
    global _MODELS
    directory, index, setting, model, case, (velocity, duration) = args
    from slotexp.bench._accuracy import Case, run_case

    if _MODELS is None:
        _MODELS = pickle.loads((Path(directory) / "models.pkl").read_bytes())
    cfg = _MODELS[model]
    cfg = dataclasses.replace(cfg, controller=dataclasses.replace(cfg.controller, **setting))
    start = time.perf_counter()
    try:
        trace = run_case(cfg, Case(case, "baseline", velocity, duration, 0.0))
        out = metrics(trace.t, trace.x, velocity, cfg.gait.height)
    except Exception as e:  # a run that fails is a result too
        out = {"error": f"{type(e).__name__}: {e}"}
    return {"setting": index, **setting, "model": model, "case": case, "wall_s": time.perf_counter() - start, **out}


def run(directory: Path, deadline: float, workers: int) -> None:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ.setdefault(k, "1")
    start = time.perf_counter()
    from slotexp.bench._accuracy import Case, run_case

    settings = json.loads((directory / "settings.json").read_text())
    cfgs = pickle.loads((directory / "models.pkl").read_bytes())
    models = list(cfgs)
    cases = _cases(directory)
    # compile or load every kernel once, here, on a short walk (the workers then load them from numba's cache)
    run_case(cfgs[models[0]], Case("warm-up", "baseline", CASES["walk"][0], 0.2, 0.0))
    print(f"kernels ready in {time.perf_counter() - start:.0f} s", flush=True)
    jobs = [(str(directory), i, s, m, c, v) for i, s in enumerate(settings) for m in models for c, v in cases.items()]
    tasks = iter(jobs)
    total = len(settings) * len(models) * len(cases)
    done = 0
    with (
        ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool,
        (directory / "sweep.jsonl").open("w") as f,
    ):
        pending = {pool.submit(_task, t) for t in [next(tasks, None) for _ in range(workers)] if t is not None}
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                f.write(json.dumps(future.result()) + "\n")
                f.flush()
                done += 1
                following = next(tasks, None) if time.perf_counter() - start < deadline else None
                if following is not None:
                    pending.add(pool.submit(_task, following))
    print(f"{done} of {total} runs in {time.perf_counter() - start:.0f} s", flush=True)


def _cases(directory: Path) -> dict:
    """The cases a saved sweep runs (name: (velocity, duration)); a sweep saved before cases.json, :data:`CASES`."""
    path = directory / "cases.json"
    return json.loads(path.read_text()) if path.exists() else CASES


def checks(row: dict) -> dict[str, bool]:
    """The issue's targets for one run (the ceiling run has none: it measures what the model can make)."""
    if row["case"] in CEILING:
        return {}
    if "error" in row:
        return {"yaw": False, "drift" if row["case"] != "omni60" else "path": False, "speed": False}
    if row["case"] == "omni60":
        return {
            "yaw": abs(row["yaw_drift_deg"]) <= 3.0,
            "path": row["path_rmse_mm"] <= 35.0,
            "speed": abs(row["speed_error"]) <= 0.10,
        }
    return {
        "yaw": abs(row["yaw_drift_deg"]) <= 2.0,
        "drift": row["drift_per_08m_mm"] <= 10.0,
        "speed": abs(row["speed_error"]) <= 0.05,
    }


def summarize(directory: Path) -> None:
    """summary.csv: per setting, the targets met on the models that rank (and, apart, on the held-out ones);
    per_model.csv: per model, case and target, how many settings meet it, and the default's value; by_case.csv:
    per setting, case and target, how many models meet it; runs.csv: every run's measures, one row each."""
    import pandas as pd

    rows = [json.loads(line) for line in (directory / "sweep.jsonl").read_text().splitlines() if line.strip()]
    marks = pd.DataFrame(
        [
            {"setting": r["setting"], "model": r["model"], "case": r["case"], "target": k, "met": v}
            for r in rows
            for k, v in checks(r).items()
        ]
    )
    held = marks.model.str.startswith(HELD_OUT)
    by_setting = pd.DataFrame(
        {
            "met": marks[~held].groupby("setting").met.sum(),
            "of": marks[~held].groupby("setting").met.size(),
            "yaw_met": marks[~held & (marks.target == "yaw")].groupby("setting").met.sum(),
            "held_out_met": marks[held].groupby("setting").met.sum(),
            "held_out_yaw_met": marks[held & (marks.target == "yaw")].groupby("setting").met.sum(),
            "held_out_of": marks[held].groupby("setting").met.size(),
        }
    )
    table = pd.DataFrame(rows)
    table.sort_values(["model", "case", "setting"]).to_csv(directory / "runs.csv", index=False)
    settings = table.groupby("setting")[[k for k in (*SETTINGS_BOX, *RECORDED) if k in table]].first()
    summary = by_setting.join(settings).reset_index().sort_values(["met", "yaw_met"], ascending=False)
    summary["default"] = summary.setting == 0
    summary.to_csv(directory / "summary.csv", index=False)
    per_model = marks.groupby(["model", "case", "target"]).met.agg(settings_met="sum", settings="size").reset_index()
    per_model["default_met"] = [
        bool(marks[(marks.setting == 0) & (marks.model == m) & (marks.case == c) & (marks.target == t)].met.iloc[0])
        for m, c, t in zip(per_model.model, per_model.case, per_model.target)
    ]
    per_model["held_out"] = per_model.model.str.startswith(HELD_OUT)
    per_model["every_setting_met"] = per_model.settings_met == per_model.settings
    per_model.to_csv(directory / "per_model.csv", index=False)
    by_case = marks.groupby(["setting", "case", "target"]).met.agg(models_met="sum", models="size").reset_index()
    by_case.to_csv(directory / "by_case.csv", index=False)
    if (directory / "models.json").exists():
        _by_model(directory, table, marks)
    best, default = summary.iloc[0], summary[summary.default].iloc[0]
    print(f"{len(rows)} runs; best setting {best.setting}: {best.met} of {best.of} met (the default {default.met})")


def _by_model(directory: Path, table, marks) -> None:
    """models.csv for a sweep over sampled models: each model's values, the default setting's targets met per case,
    and the forward speed it makes commanded beyond its reach (its ceiling). A model whose ceiling is below a
    case's command cannot meet that case's speed target with any controller."""
    import pandas as pd

    models = json.loads((directory / "models.json").read_text())
    command = math.hypot(*CEILING["ceiling"][0])
    rows = []
    for name, overrides in models.items():
        row = {"model": name, **{o.split("=")[0].rsplit(".", 1)[1]: float(o.split("=")[1]) for o in overrides}}
        mine = table[(table.setting == 0) & (table.model == name)].set_index("case")
        for case in CASES:
            met = marks[(marks.setting == 0) & (marks.model == name) & (marks.case == case)]
            row[f"{case}_met"] = int(met.met.sum())
            row[f"{case}_speed_error"] = mine.speed_error.get(case, float("nan"))
            row[f"{case}_yaw_drift_deg"] = mine.yaw_drift_deg.get(case, float("nan"))
        ceiling = mine.loc["ceiling"] if "ceiling" in mine.index else None
        row["ceiling_mps"] = float("nan") if ceiling is None else command * (1.0 + ceiling.speed_error)
        rows.append(row)
    pd.DataFrame(rows).to_csv(directory / "models.csv", index=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="verb", required=True)
    s = sub.add_parser("save", help="write DIR/models.pkl and DIR/settings.json")
    s.add_argument("directory", type=Path)
    s.add_argument("--settings", type=int, default=16, help="settings sampled besides the default")
    s.add_argument("--seed", type=int, default=36)
    s.add_argument("--grid", help="KEY=V1,V2,...: the default with one setting at each value (no sampling)")
    s.add_argument("--sample-models", type=int, default=0, help="N models across the ranges instead of the seven")
    r = sub.add_parser("run", help="run every setting on every model and case into DIR/sweep.jsonl")
    r.add_argument("directory", type=Path)
    r.add_argument("--deadline", type=float, default=math.inf, help="s after which no new run starts")
    r.add_argument("--workers", type=int, default=os.cpu_count())
    m = sub.add_parser("summarize", help="write DIR/summary.csv and DIR/per_model.csv")
    m.add_argument("directory", type=Path)
    args = parser.parse_args()
    if args.verb == "save":
        if args.sample_models < 0:
            parser.error(f"--sample-models {args.sample_models}: give a number of models, 1 or more (0: the seven)")
        grid = None
        if args.grid:
            key, _, values = args.grid.partition("=")
            try:
                grid = (key, [float(v) for v in values.split(",")])
            except ValueError:
                pass  # refused below, with the keys named
            if key not in (*SETTINGS_BOX, *RECORDED) or grid is None:
                keys = ", ".join((*SETTINGS_BOX, *RECORDED))
                parser.error(f"--grid {args.grid!r}: give KEY=V1,V2 (numbers), KEY one of {keys}")
        save(args.directory, args.settings, args.seed, grid, args.sample_models)
    elif args.verb == "run":
        run(args.directory, args.deadline, args.workers)
    else:
        summarize(args.directory)


if __name__ == "__main__":
    main()
