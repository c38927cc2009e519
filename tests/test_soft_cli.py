"""The soft-leg experiments through the CLI: leg, calibrate, closed loop on plant=cosserat."""

import json
import math

import pytest
import yaml

from slotexp.record import read_log
from tests.helpers import ok, slot


def one_line_error(proc, *words):
    assert proc.returncode == 2, proc.stderr
    # progress bars may precede it on stderr; the error itself is one line, and the last
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and proc.stderr.rstrip().endswith(errors[0]), proc.stderr
    assert "Traceback" not in proc.stderr
    for w in words:
        assert w in errors[0]


def test_leg_experiment_matches_euler_bernoulli(tmp_path):
    out = tmp_path / "leg"
    ok(
        slot(
            "run",
            "experiment=leg",
            "robot.leg.rest_shape=straight",
            "robot.leg.thickness_tip=0.0135",
            "sim.gravity=0",
            "leg_load.ground=false",
            "leg_load.tip_force=[0,-0.01]",
            f"hydra.run.dir={out}",
            cwd=tmp_path,
        )
    )
    result = json.loads((out / "leg.json").read_text())
    ei = 1e7 * 0.02 * 0.0135**3 / 12
    assert result["tip_z"] == pytest.approx(-0.01 * 0.19**3 / (3 * ei), rel=0.01)
    assert result["tip_x"] == pytest.approx(0.19, abs=1e-4)
    assert (out / "fig_leg.png").stat().st_size > 10_000
    (out / "fig_leg.png").unlink()
    ok(slot("figures", out, cwd=tmp_path))
    assert (out / "fig_leg.png").is_file()


def test_calibrate_fits_an_affine_map_the_controller_can_load(tmp_path):
    out = tmp_path / "cal"
    ok(
        slot(
            "run",
            "experiment=calibrate",
            "experiment.angles=6",
            "leg_load.settle_time=0.9",
            f"hydra.run.dir={out}",
            cwd=tmp_path,
        )
    )
    fit = json.loads((out / "calibrate.json").read_text())
    assert fit["slope_n_per_deg"] > 0 and fit["r2"] > 0.99
    assert fit["paper"] == {"slope_n_per_deg": 0.107, "offset_n": -6.91}
    snippet = (out / "actuation_calibrated.yaml").read_text()
    assert snippet.startswith("# @package robot.actuation")
    assert yaml.safe_load(snippet)["slope_n_per_deg"] == pytest.approx(fit["slope_n_per_deg"], rel=1e-5)
    assert len((out / "calibration.csv").read_text().splitlines()) == 7


def test_closed_loop_on_the_soft_plant_logs_legs_and_animates(tmp_path):
    out = tmp_path / "sim"
    ok(
        slot(
            "run",
            "experiment=simulate",
            "plant=cosserat",
            "experiment.duration=1",
            f"hydra.run.dir={out}",
            cwd=tmp_path,
        )
    )
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["infeasible_steps"] == 0
    assert abs(metrics["com_rmse_z_m"]) < 0.02
    log = read_log(out / "logs" / "walk.mcap")
    for topic in ("/legs/shape", "/legs/tendon", "/legs/contact", "/legs/root", "/markers"):
        assert topic in log
    assert {"FL_n0.0", "FL_n10.2", "RR_n30.1"} <= set(log["/markers"].columns)
    assert log["/legs/tendon"][["tension_n.0", "tension_n.3"]].to_numpy().max() > 10.0
    assert (out / "walk.gif").stat().st_size > 10_000
    assert not [p.name for p in out.iterdir() if p.name.startswith(".walk.")]  # written aside, then renamed
    conf = yaml.safe_load(log.metadata["config"]["yaml"])
    assert conf["robot"]["actuation"]["slope_n_per_deg"] != 0.107  # plant=cosserat uses the calibrated map


def test_divergence_stops_with_one_line_naming_dt(tmp_path):
    proc = slot(
        "run",
        "experiment=simulate",
        "plant=cosserat",
        "plant.integrator=symplectic",
        "sim.dt=2e-4",
        "experiment.duration=1",
        f"hydra.run.dir={tmp_path / 'div'}",
        cwd=tmp_path,
    )
    one_line_error(proc, "sim.dt", "stability limit")


def test_paper_leg_model_needs_the_symplectic_step(tmp_path):
    proc = slot("run", "experiment=leg", "robot.leg.model=paper", f"hydra.run.dir={tmp_path / 'x'}", cwd=tmp_path)
    one_line_error(proc, "robot.leg.model=paper", "symplectic")


def test_gait_search_sweeps_headings_as_a_hydra_multirun(tmp_path):
    """One heading per job, the jobs in parallel (joblib), candidates evaluated in each job's process."""
    sweep = tmp_path / "sweep"
    ok(
        slot(
            "run",
            "-m",
            "experiment=gait_search",
            "plant=cosserat",
            "experiment.headings=[0],[90]",
            "experiment.turn=false",
            "experiment.max_evals=2",
            "experiment.popsize=2",
            "experiment.duration=1",
            "experiment.settle=0.5",
            "experiment.verify_duration=1",
            "experiment.parallel.workers=1",
            f"hydra.sweep.dir={sweep}",
            cwd=tmp_path,
            timeout=600,
        )
    )
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir())
    assert len(jobs) == 2
    for job, target in zip(jobs, ("h+000.0", "h+090.0"), strict=True):
        candidates = read_log(job / "logs" / "gait_search.mcap")["/search/candidate"]
        assert set(candidates["target"]) == {target} and len(candidates) == 3  # the start, then 2
        metrics = json.loads((job / "metrics.json").read_text())
        assert [v["target"] for v in metrics["verified"]][0] == target
        assert (job / "library.yaml").is_file() and (job / "fig_search.png").is_file()


def test_gait_search_measures_the_library_as_it_stands_with_stroke_and_turning_authority(tmp_path):
    """experiment.search=false: every primitive of the style measured as it is (no candidates), a translating
    one also leaning either way; library.md tabulates speed, stroke, ceiling and turning authority."""
    run_dir = tmp_path / "verify"
    ok(
        slot(
            "run",
            "experiment=gait_search",
            "plant=cosserat",
            "experiment.style=crawl",
            "experiment.search=false",
            "experiment.settle=0.5",
            "experiment.verify_duration=2.5",  # the crawl's cycle is 1.33 s: at least one whole cycle measured
            "experiment.parallel.workers=1",
            f"hydra.run.dir={run_dir}",
            cwd=tmp_path,
            timeout=600,
        )
    )
    log = read_log(run_dir / "logs" / "gait_search.mcap")
    assert "/search/candidate" not in log
    verified = json.loads((run_dir / "metrics.json").read_text())["verified"]
    assert [v["name"] for v in verified] == ["crawl_h+000.0", "crawl_h+000.0_my", "crawl_h+090.0", "crawl_h+090.0_mx"]
    for v in verified:
        assert v["stroke_mm"] > 1.0 and v["stroke_ceiling_mm_s"] > v["speed"]  # a ceiling above what it does
        assert math.isfinite(v["lean_yaw_left_dps"]) and math.isfinite(v["lean_yaw_right_dps"])
    table = (run_dir / "library.md").read_text().splitlines()
    assert sum(line.startswith("| crawl_") for line in table) == 4
    library = (run_dir / "library.yaml").read_text()
    assert all(name in library for name in ("crawl_h+000.0_my", "crawl_h+090.0_mx"))
