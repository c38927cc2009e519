"""experiment=identify: parameters, observations, the fit's recovery of known values, and its engines."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from slotexp.errors import ConfigError
from slotexp.jobs.identify import (
    ParameterSpec,
    heading_sigma,
    load_observations,
    read_track,
    report,
    residuals,
    run,
    setting,
    to_unit,
    to_values,
    with_setting,
    write_track_csv,
)
from slotexp.parallel import ParallelConfig, pool
from slotexp.record import read_log
from tests.helpers import assert_one_line_error, assert_png, load, slot

SMALL = (
    "plant=cosserat",
    "experiment=identify",
    "experiment.schedules=[forward]",
    "experiment.duration=1.68",  # two cycles of 0.84 s
    "experiment.measure_from_s=0.84",
    "experiment.parameters=[{path: robot.servo.horn_zero_deg, lo: 100.0, hi: 130.0}]",
    "robot.servo.horn_zero_deg=[120,120,120,120]",  # the search starts here
    "experiment.synthetic.truth=[112.0]",
    "experiment.synthetic.noise_mm=0.2",
    "experiment.synthetic.noise_deg=1.0",
    "experiment.popsize=4",
    "experiment.max_evals=16",
    "experiment.sigma0=0.3",
    "experiment.initial_design=0",  # the search from the config's values alone
)


def test_a_parameter_sets_scalars_and_every_entry_of_a_list_and_maps_to_the_unit_cube_and_back():
    cfg = load("plant=cosserat")
    out = with_setting(with_setting(cfg, "robot.contact.friction", 0.37), "robot.servo.horn_zero_deg", 101.0)
    assert out.robot.contact.friction == 0.37 and out.robot.servo.horn_zero_deg == [101.0] * 4
    assert cfg.robot.contact.friction != 0.37  # the original is untouched
    assert setting(out, "robot.servo.horn_zero_deg") == [101.0] * 4
    with pytest.raises(ConfigError, match="robot.contact.frictoin is not a setting"):
        setting(cfg, "robot.contact.frictoin")
    from slotexp.config import setting_unit  # the unit a figure labels a swept setting with

    assert setting_unit(cfg, "robot.leg.youngs_modulus") == "Pa" and setting_unit(cfg, "plant.retakes") == "retakes"
    assert setting_unit(cfg, "robot.contact.friction") == "" and setting_unit(cfg, "robot.contact.frictoin") == ""
    specs = [ParameterSpec("a", 0.05, 1.0, True), ParameterSpec("b", 80.0, 140.0, False)]
    values = np.array([0.3, 110.0])
    np.testing.assert_allclose(to_values(specs, to_unit(specs, values)), values, rtol=1e-12)
    np.testing.assert_allclose(to_values(specs, np.array([0.5, 0.5])), [math.sqrt(0.05), 110.0], rtol=1e-12)


def test_a_track_round_trips_through_the_marker_csv_as_a_displacement(tmp_path: Path):
    t = np.arange(0, 1.0, 0.02)
    com = np.column_stack([0.1 + 0.01 * t, -0.2 + 0 * t, 0.04 + 0.001 * np.sin(t)])
    write_track_csv(tmp_path / "c.csv", t, com)
    t2, d = read_track(str(tmp_path / "c.csv"))
    np.testing.assert_allclose(t2, t, atol=1e-4)
    np.testing.assert_allclose(d, com - com[0], atol=2e-6)


def test_identification_recovers_a_known_horn_zero_from_the_models_own_noisy_observations(tmp_path: Path):
    # Observations made by the model at horn zero 112 deg (noise 0.2 mm, 1 deg), the search starting at 120:
    # the fit comes back within 5 % (the target), and within the spread it reports.
    cfg = load(*SMALL, "experiment.parallel.workers=1")
    run(cfg, tmp_path, "{}")
    spread = pd.read_csv(tmp_path / "spread.csv")
    row = spread.iloc[0]
    assert row["parameter"] == "robot.servo.horn_zero_deg" and row["truth"] == 112.0
    assert abs(row["error_rel"]) < 0.05
    # the track's height pins the horn zero to a few degrees, and the truth lies in the 68 % region the fit
    # reports, up to its sampling: the region is the candidates within the chi^2 quantile of the best, so its
    # true edges lie between the last candidate in it and the next one out (measured, at 5e-4 s with the
    # friction solved: best 112.9, region 112.9-113.5, the next candidates out at 108.6 and 115.2; at 2e-4 s
    # with the secant: best 109.9, region 108.8-113.1)
    assert row["hi_68"] - row["lo_68"] < 6.0
    candidates = pd.read_csv(tmp_path / "candidates.csv")
    tried = candidates["robot.servo.horn_zero_deg"].to_numpy()
    below, above = tried[tried < row["lo_68"]], tried[tried > row["hi_68"]]
    assert (below.max() if len(below) else 100.0) <= 112.0 <= (above.min() if len(above) else 130.0)
    fit = yaml.safe_load((tmp_path / "fit.yaml").read_text())
    assert fit["overrides"]["robot.servo.horn_zero_deg"] == [pytest.approx(row["best"], rel=1e-5)] * 4
    residuals = pd.read_csv(tmp_path / "residuals.csv")
    assert set(residuals["observation"]) == {
        "compass_deg",
        "distance_per_cycle_mm",
        "track_cycle_rms_x_mm",
        "track_cycle_rms_y_mm",
        "track_cycle_rms_z_mm",
    }
    assert fit["cost"] == pytest.approx(float((residuals["residual"] ** 2).sum()), rel=1e-4)  # CSV: 6 digits
    # the start, 16 of the search, then 8 across the horn zero's range (100 to 130) with nothing else to hold;
    # the fit is the lowest cost of all of them
    assert len(candidates) == 25
    assert candidates["cost"].min() == pytest.approx(fit["cost"], rel=1e-5)
    scan = candidates["robot.servo.horn_zero_deg"].iloc[-8:].to_numpy()
    np.testing.assert_allclose(scan, np.linspace(100.0, 130.0, 8), rtol=1e-5)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["evaluations"] == 25
    assert_png(tmp_path / "fig_identify.png")
    (tmp_path / "spread.csv").unlink()
    assert report(tmp_path, cfg) == metrics  # every output is rebuilt from the log alone (slot figures)
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "spread.csv"), spread)


def test_the_torso_height_is_an_observation_of_every_gait_from_the_config_or_the_table(tmp_path: Path):
    # experiment.height_mm holds every gait's mean torso height to a number; a CSV's height_mm column per gait
    args = ("plant=cosserat", "experiment=identify", "experiment.schedules=[forward,crawl_forward]")
    cfg = load(*args)
    gaits = {
        g: {"compass_deg": 10.0, "distance_per_cycle_mm": 20.0, "height_mm": 55.0} for g in cfg.experiment.schedules
    }
    result = {"gaits": gaits}
    assert "height_mm" not in set(residuals(cfg, load_observations(cfg, "robot", {}), result)["observation"])
    held = load(*args, "experiment.height_mm=40", "experiment.height_sigma_mm=5")
    table = residuals(held, load_observations(held, "robot", {}), result)
    rows = table[table["observation"] == "height_mm"]
    assert list(rows["gait"]) == ["forward", "crawl_forward"]
    np.testing.assert_allclose(rows["residual"], (55.0 - 40.0) / 5.0)
    csv = tmp_path / "obs.csv"
    csv.write_text("gait,compass_deg,distance_per_cycle_mm,height_mm\nforward,0,50,42\ncrawl_forward,0,40,\n")
    table = residuals(held, load_observations(held, str(csv), {}), result)
    rows = table[table["observation"] == "height_mm"]
    assert list(rows["gait"]) == ["forward"] and rows["observed"].iloc[0] == 42.0  # a blank: not observed
    csv.write_text("gait,compass_deg,distance_per_cycle_mm\nforward,0,50\n")  # no column: the config's height
    rows = residuals(held, load_observations(held, str(csv), {}), result).query("observation == 'height_mm'")
    assert list(rows["observed"]) == [40.0]


def test_a_headings_sigma_grows_as_its_gaits_displacement_shrinks_as_error_propagation_says():
    # a displacement of d known to +-s in every direction points within +-s/d rad (for s << d): Monte Carlo
    rng = np.random.default_rng(0)
    for d, s in ((10.0, 1.0), (30.0, 2.0)):
        ends = np.array([d, 0.0]) + rng.normal(0.0, s, (200_000, 2))
        spread = np.degrees(np.std(np.arctan2(ends[:, 1], ends[:, 0])))
        assert heading_sigma(0.0 + 1e-12, s, d) == pytest.approx(spread, rel=0.02)
    assert heading_sigma(15.0, 0.0, 0.1) == 15.0  # off: the observation's sigma alone, however little it moves
    assert heading_sigma(15.0, 1.0, 50.0) == pytest.approx(math.hypot(15.0, math.degrees(math.atan(1 / 50))))
    assert heading_sigma(15.0, 1.0, 0.0) == pytest.approx(math.hypot(15.0, 90.0))  # standing still: no direction
    # in the cost: a gait that creeps 0.3 mm per cycle the wrong way is charged little, one that walks it, fully
    args = ("plant=cosserat", "experiment=identify", "experiment.schedules=[walk_45]")
    cfg = load(*args, "experiment.heading_displacement_sigma_mm=1.0")
    obs = load_observations(cfg, "robot", {})
    for distance, lo, hi in ((0.3, 1.0, 2.0), (20.0, 7.0, 8.0)):
        result = {"gaits": {"walk_45": {"compass_deg": 45.0 + 120.0, "distance_per_cycle_mm": distance}}}
        (residual,) = residuals(cfg, obs, result)["residual"]
        assert residual == pytest.approx(120.0 / heading_sigma(15.0, 1.0, distance))
        assert lo < residual < hi
    fixed = load(*args)
    (residual,) = residuals(fixed, load_observations(fixed, "robot", {}), result)["residual"]
    assert residual == pytest.approx(120.0 / 15.0)


def test_a_dask_cluster_and_local_processes_evaluate_the_same_candidates(tmp_path: Path):
    # The engine is a setting: a real local Dask cluster (two worker processes) gives the in-process results.
    pytest.importorskip("distributed")
    tasks = [(k, 3.0) for k in range(5)]
    with pool(ParallelConfig(engine="dask", workers=2), 5) as dask, pool(ParallelConfig(workers=1), 5) as here:
        assert dask.workers == 2
        assert dask.map(_power, tasks) == here.map(_power, tasks) == [k**3.0 for k in range(5)]
    cfg = load(*SMALL, "experiment.max_evals=4", "experiment.parallel.engine=dask", "experiment.parallel.workers=2")
    run(cfg, tmp_path / "dask", "{}")
    cfg = load(*SMALL, "experiment.max_evals=4", "experiment.parallel.workers=1")
    run(cfg, tmp_path / "here", "{}")
    a, b = (pd.read_csv(tmp_path / d / "candidates.csv") for d in ("dask", "here"))
    pd.testing.assert_frame_equal(a, b)  # the same seeded search, the same arithmetic, wherever it ran


def test_a_dask_address_that_is_not_one_gets_one_line(tmp_path: Path):
    args = ["plant=cosserat", "experiment=identify", "experiment.parallel.engine=dask"]
    proc = slot("run", *args, "experiment.parallel.address=http://h:1", f"hydra.run.dir={tmp_path}", cwd=tmp_path)
    assert_one_line_error(proc, "not a Dask scheduler address", "host:port")


def test_a_dask_scheduler_with_no_workers_is_one_clear_error_not_a_hang() -> None:
    # tasks sent to a scheduler with no workers wait forever: the pool waits worker_wait_s for one, then says so
    from distributed import LocalCluster

    from slotexp.errors import ConfigError

    with LocalCluster(n_workers=0, dashboard_address=None, processes=True) as empty:
        cfg = ParallelConfig(engine="dask", address=empty.scheduler_address, worker_wait_s=1.0)
        with pytest.raises(ConfigError, match="has no workers after 1 s"), pool(cfg, 3):
            pass


def _power(task: tuple[int, float]) -> float:
    return task[0] ** task[1]


@pytest.mark.parametrize(
    ("override", "names"),
    [
        ("experiment.synthetic.truth=[0.3,110,1]", ["synthetic.truth", "one per parameter"]),
        ("experiment.synthetic.truth=[0.3,60]", ["horn_zero_deg = 60", "outside its range"]),
        ("experiment.parameters=[{path: robot.contact.frictoin, lo: 0.1, hi: 1}]", ["frictoin is not a setting"]),
        ("experiment.parameters=[{path: robot.contact.friction, lo: 1, hi: 0.1}]", ["lo < hi"]),
        ("experiment.parameters=[{path: robot.leg.names, lo: 0.1, hi: 1}]", ["not a numeric setting"]),
        ("experiment.observations=/nonexistent.csv", ["neither 'robot' nor a CSV"]),
        ("experiment.parallel.address=tcp://localhost:1", ["engine=dask"]),
        ("experiment.height_mm=-40", ["height_mm = -40", "mm above the floor"]),
        ("experiment.schedules=[forward,walk_60]", ["walk_60", "held-out"]),
        # a range the setting itself refuses would write a fit the tool refuses to run
        ("experiment.parameters=[{path: robot.contact.friction, lo: -1, hi: 1}]", ["-1 to 1", "narrow the range"]),
        ("experiment.restarts=30", ["restarts = 30", "initial_design >= 29"]),
        ("experiment.restarts=16", ["shared by 16 searches", "max_evals >= 128"]),
    ],
)
def test_bad_identification_settings_get_one_line(tmp_path: Path, override: str, names: list[str]):
    args = ["plant=cosserat", "experiment=identify", override]
    assert_one_line_error(slot("run", *args, f"hydra.run.dir={tmp_path}", cwd=tmp_path), *names)


def test_an_initial_design_is_evaluated_first_and_the_search_starts_from_its_best(tmp_path: Path):
    cfg = load(*SMALL, "experiment.max_evals=4", "experiment.initial_design=5", "experiment.parallel.workers=1")
    run(cfg, tmp_path, "{}")
    candidates = pd.read_csv(tmp_path / "candidates.csv")
    first = candidates[candidates["generation"] == 0]
    assert len(first) == 6 and first.iloc[0]["robot.servo.horn_zero_deg"] == 120.0  # the config's, then 5 points
    design = np.sort(first.iloc[1:]["robot.servo.horn_zero_deg"].to_numpy())
    assert all(100.0 + 6.0 * i <= d <= 100.0 + 6.0 * (i + 1) for i, d in enumerate(design))  # one per fifth
    best = first.loc[first["cost"].idxmin()]
    assert candidates.iloc[6]["robot.servo.horn_zero_deg"] == pytest.approx(best["robot.servo.horn_zero_deg"], rel=1e-5)
    assert len(candidates) == 6 + 1 + 4 + 8  # the design with the start, the search's start, 4, the scan of 8


def test_restarted_searches_start_from_the_designs_best_points_in_turn(tmp_path: Path):
    args = (
        "experiment.max_evals=8",
        "experiment.initial_design=5",
        "experiment.restarts=2",
        "experiment.slice_points=0",
    )
    run(load(*SMALL, *args, "experiment.parallel.workers=1"), tmp_path, "{}")
    candidates = pd.read_csv(tmp_path / "candidates.csv")
    sizes = candidates.groupby("generation").size().tolist()
    assert sizes == [6, 1, 4, 1, 4]  # the design; each search: its start, then one generation of 4 (8 shared by 2)
    design = candidates[candidates["generation"] == 0].sort_values("cost", kind="stable")
    starts = [candidates[candidates["generation"] == g].iloc[0] for g in (1, 3)]
    for start, (_, point) in zip(starts, design.head(2).iterrows(), strict=True):
        assert start["robot.servo.horn_zero_deg"] == point["robot.servo.horn_zero_deg"]
    fit = yaml.safe_load((tmp_path / "fit.yaml").read_text())
    assert fit["cost"] == pytest.approx(candidates["cost"].min())  # the best of both searches


def test_a_robust_fit_costs_each_candidate_its_worst_run_under_the_perturbations(tmp_path: Path):
    """experiment.robust: every candidate also runs with the friction 10 % lower and higher; its cost is the worst
    of the three, each perturbed run is the candidate's own model with just that setting moved."""
    from slotexp.jobs.identify import candidate_config, perturbed

    args = (*SMALL, "experiment.max_evals=4", "experiment.slice_points=2", "experiment.parallel.workers=1")
    cfg = load(*args, "experiment.robust.parameters=[robot.contact.friction]")
    model = candidate_config(cfg, cfg.experiment.parameters, np.array([115.0]))
    runs = perturbed(cfg, model)
    assert [m.robot.contact.friction for m in runs] == pytest.approx([0.1, 0.09, 0.11])
    assert all(m.robot.servo.horn_zero_deg == [115.0] * 4 for m in runs)
    run(cfg, tmp_path, "{}")
    candidates = pd.read_csv(tmp_path / "candidates.csv")
    each = candidates[["cost_own", "cost_perturbed.0", "cost_perturbed.1"]].to_numpy(float)
    np.testing.assert_allclose(candidates["cost"], each.max(axis=1))
    assert (candidates["cost"] > candidates["cost_own"]).any()  # a perturbation costs something somewhere
    plain = load(*args)
    assert perturbed(plain, model) == [model]  # no robust parameters: the candidate alone
    with pytest.raises(ConfigError, match="robust.parameters: robot.leg.names is not a numeric setting"):
        load(*args, "experiment.robust.parameters=[robot.leg.names]")


def test_a_search_pools_workers_end_when_the_search_is_killed(tmp_path: Path):
    # gait_search and identify evaluate candidates in a pool of spawned processes; killed outright (SIGKILL, no
    # handler runs), the search takes its workers with it (prctl's parent-death signal, slotexp/signals.py)
    import os
    import signal
    import subprocess
    import sys
    import time

    import psutil

    script = (
        "import time\n"
        "from slotexp.parallel import ParallelConfig, pool\n"
        "with pool(ParallelConfig(workers=2), 2) as p:\n"
        "    p.map(time.sleep, [120, 120])\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path)
    try:
        deadline = time.monotonic() + 60
        workers: list[psutil.Process] = []
        while time.monotonic() < deadline and len(workers) < 2:
            workers = [
                c for c in psutil.Process(proc.pid).children() if "resource_tracker" not in " ".join(c.cmdline())
            ]
            time.sleep(0.1)
        assert len(workers) == 2
        time.sleep(1.0)  # past the workers' initializer
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        _, alive = psutil.wait_procs(workers, timeout=20)
        assert not alive, "a worker outlived its search"
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.parametrize(
    ("rows", "words"),
    [
        ("", ["observes nothing", "0 rows"]),
        ("forward,,\ncrawl_forward,,\n", ["observes nothing"]),
        ("forward,0,-50\n", ["distance_per_cycle_mm = -50", "the heading gives the direction"]),
        ("forward,0,50000\n", ["distance_per_cycle_mm = 50000", "mm per gait cycle"]),  # micrometres
        ("forward,720,50\n", ["compass_deg = 720"]),
    ],
    ids=["no-rows", "all-blank", "negative-distance", "not-mm", "compass"],
)
def test_an_observation_table_that_observes_nothing_or_in_other_units_is_refused(tmp_path: Path, rows, words):
    # each once gave a fit: cost 0 and a fit.yaml for an empty or blank table, a negative distance read as one
    from slotexp.errors import UserError
    from slotexp.jobs.identify import read_table

    path = tmp_path / "observations.csv"
    path.write_text("gait,compass_deg,distance_per_cycle_mm\n" + rows)
    with pytest.raises(UserError) as err:
        read_table(path, ["forward", "crawl_forward"])
    assert "\n" not in str(err.value) and all(w in str(err.value) for w in words), str(err.value)


def test_a_track_in_millimetres_is_refused_not_fitted(tmp_path: Path):
    # it once gave a cost of 1.8e7 and a fit: positions are metres
    from slotexp.errors import UserError
    from slotexp.jobs.identify import read_track

    path = tmp_path / "forward.csv"
    path.write_text("t,com_x,com_y,com_z\n0,0,0,40\n1,50,0,40\n")
    with pytest.raises(UserError, match="millimetres"):
        read_track(str(path))


def test_a_best_value_at_its_ranges_end_is_flagged_in_the_searched_space():
    # the robust fit's damping, 79.26 of 5-80 searched in log space, stopped at the range, not at the data
    from slotexp.jobs.identify import ParameterSpec, _at_edge

    damping = ParameterSpec(path="robot.leg.damping_per_s", lo=5.0, hi=80.0, log=True)
    assert _at_edge(damping, 79.26) == "hi" and _at_edge(damping, 5.05) == "lo" and _at_edge(damping, 20.0) == ""
    linear = ParameterSpec(path="robot.servo.horn_zero_deg", lo=80.0, hi=140.0)
    assert _at_edge(linear, 80.5) == "lo" and _at_edge(linear, 82.0) == ""  # 1 % of 60 deg is 0.6 deg


def test_the_manuals_track_syntax_works_as_written(tmp_path: Path):
    # docs/schedules.md: '+experiment.tracks={forward: markers_forward.csv}' (without the + Hydra refuses a new
    # key of the map, in one line saying to add it)
    docs = (Path(__file__).parents[1] / "docs" / "schedules.md").read_text()
    syntax = "+experiment.tracks={forward: markers_forward.csv}"
    assert f"'{syntax}'" in docs
    (tmp_path / "markers_forward.csv").write_text("t,com_x,com_y,com_z\n0,0,0,0.04\n1,0.02,0,0.04\n2,0.04,0,0.04\n")
    (tmp_path / "obs.csv").write_text("gait,compass_deg,distance_per_cycle_mm\nforward,0,50\n")
    small = ["experiment.max_evals=2", "experiment.popsize=2", "experiment.initial_design=0",
             "experiment.slice_points=0", "experiment.schedules=[forward]", "experiment.duration=4.2"]  # fmt: skip
    proc = slot("run", "experiment=identify", "plant=cosserat", "experiment.observations=obs.csv", syntax, *small,
                cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    meta = json.loads(read_log(Path(proc.stdout.strip().splitlines()[-1]) / "logs" / "identify.mcap").metadata[
        "observations"]["tracks"])  # fmt: skip
    assert list(meta) == ["forward"] and meta["forward"].endswith("markers_forward.csv")
