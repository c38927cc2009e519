"""``slot summarize``: a sweep's jobs gathered into one table and one figure; bad input is one line."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest

from slotexp.summarize import summarize
from tests.helpers import assert_one_line_error, last_line, ok, slot

TABLE1 = "scenario,max_cost,mean_cost,final_cost,settle_s,infeasible_steps\n"


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> Path:
    # A two-scenario perturb sweep over two solvers, as the README shows it: the joblib launcher's jobs cannot
    # start process pools of their own, so each runs its scenarios in its own process (slotexp.parallel)
    root = tmp_path_factory.mktemp("sweep")
    out = root / "multirun"
    proc = ok(
        slot(
            "run",
            "-m",
            "experiment=perturb",
            "experiment.scenarios=[baseline,noise]",
            "experiment.duration=0.5",
            "solver=daqp,osqp_direct",  # experiment.n_jobs at its default: each job runs its scenarios itself
            f"hydra.sweep.dir={out}",
            cwd=root,
            timeout=300,
        )
    )
    said = proc.stdout + proc.stderr
    # the sweep says where it writes and what each job runs, not the joblib pool's settings
    assert "Launching jobs, sweep output dir" in said and "#1 : " in said and "Joblib.Parallel(" not in said
    return out


def test_summarize_gathers_every_job_of_a_sweep(sweep: Path) -> None:
    proc = ok(slot("summarize", sweep, cwd=sweep.parent))
    assert last_line(proc.stdout) == str(sweep)
    table = pd.read_csv(sweep / "summary.csv")
    assert list(table["solver"]) == ["daqp", "osqp_direct"]
    assert (table["scenarios"] == 2).all() and (table["steps"] == 2 * 15).all()
    assert (table["infeasible_steps"] == 0).all() and (table["infeasible_deterministic"] == 0).all()
    assert ((table["update_median_ms"] > 0) & (table["update_p99_ms"] >= table["update_median_ms"])).all()
    assert (table["update_max_ms"] >= table["update_p99_ms"]).all()
    for col in ("max_cost", "mean_cost", "final_cost_max"):
        assert table[col].notna().all() and (table[col] >= 0).all()
    md = (sweep / "summary.md").read_text()
    assert "daqp" in md and "osqp_direct" in md
    assert (sweep / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_sweep_cut_short_is_summarized_with_its_missing_jobs_named(tmp_path: Path, sweep: Path) -> None:
    # summarize once said nothing of the jobs an interrupted sweep never ran
    cut = tmp_path / "cut"
    shutil.copytree(sweep, cut)
    assert "no directory" not in ok(slot("summarize", cut, cwd=tmp_path)).stderr  # the whole sweep: none missing
    second = next(p for p in cut.iterdir() if p.name.startswith("1_"))
    shutil.rmtree(second)
    proc = ok(slot("summarize", cut, cwd=tmp_path))
    assert "1 planned job(s) have no directory (numbers 1)" in proc.stderr
    assert "1 planned job(s) have no directory" in (cut / "summary.md").read_text()
    assert len(pd.read_csv(cut / "summary.csv")) == 1


def test_swept_settings_become_columns_and_deterministic_counts_apart(tmp_path: Path, sweep: Path) -> None:
    for i, horizon in enumerate((10, 12)):
        job = tmp_path / f"{i}_mpc.horizon={horizon},solver=scs"
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(f"- mpc.horizon={horizon}\n- solver=scs\n- hydra.sweep.dir=x\n")
        (job / "table1.csv").write_text(TABLE1 + f"baseline,0.{i + 1},0.01,0.0,0.5,0\nnoise,0.2,0.02,0.001,,3\n")
    # one job also has logs: the noise scenario's fallbacks are not deterministic infeasible steps
    shutil.copytree(next(sweep.glob("0_*")) / "logs", tmp_path / "0_mpc.horizon=10,solver=scs" / "logs")
    table = summarize(tmp_path)
    assert list(table["mpc.horizon"]) == ["10", "12"] and "hydra.sweep.dir" not in table
    assert list(table["solver"]) == ["scs", "scs"]
    assert list(table["max_cost"]) == [0.2, 0.2] and list(table["unsettled"]) == [1, 1]
    assert table.loc[0, "steps"] == 30 and table.loc[1, "steps"] == 0
    assert (tmp_path / "summary.csv").is_file() and (tmp_path / "summary.png").is_file()


BROKEN_JOB = {  # a job file -> contents that are not what slot writes there
    "corrupt_metrics": ("metrics.json", "{not json"),
    "list_metrics": ("metrics.json", "[1, 2]"),
    "scalar_override": (".hydra/overrides.yaml", "solver=scs\n"),
    "corrupt_table": ("table1.csv", "scenario,max_cost\nbaseline,high\n"),
}


@pytest.mark.parametrize("case", ["missing", "empty", "corrupt_log", *BROKEN_JOB])
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, sweep: Path, case: str) -> None:
    target = tmp_path / "multirun"
    if case == "empty":
        target.mkdir()
    elif case == "corrupt_log":
        shutil.copytree(sweep, target, ignore=shutil.ignore_patterns("summary.*"))
        log = next(target.glob("1_*/logs/*.mcap"))
        log.write_bytes(b"not an mcap file at all")
    elif case in BROKEN_JOB:
        shutil.copytree(sweep, target, ignore=shutil.ignore_patterns("summary.*"))
        name, text = BROKEN_JOB[case]
        job = next(target.glob("1_*"))
        if name == "metrics.json":
            (job / "table1.csv").unlink()  # a job without Table I is summarised from its metrics
        (job / name).write_text(text)
    proc = slot("summarize", target, cwd=tmp_path)
    line = assert_one_line_error(proc)
    assert str(target) in line or "multirun" in line
    if case in BROKEN_JOB:
        assert BROKEN_JOB[case][0].split("/")[-1] in line  # it names the file to fix


def test_a_sweep_over_commanded_velocities_gets_the_envelope_and_a_polar(tmp_path: Path) -> None:
    # Each job: the command it swept, the speed it made (metrics.json) and the envelope its controller logged on
    # /controller (max_speed); the summary gains the envelope's median and the fraction made, and a polar figure
    import json

    from slotexp.record import Recorder

    for i, (vx, vy, made, top) in enumerate([(0.03, 0.0, 0.012, 0.024), (0.0, 0.03, 0.018, 0.02)]):
        job = tmp_path / f"{i}_gait.velocity=[{vx},{vy}]"
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(f"- gait.velocity=[{vx},{vy}]\n- plant=cosserat\n")
        (job / "metrics.json").write_text(json.dumps({"speed_mps": made, "heading_error_deg": -2.0}))
        (job / "logs").mkdir()
        with Recorder(job / "logs" / "walk.mcap") as rec:
            for k, t in enumerate((0.0, 1 / 30, 2 / 30)):  # a median that is not the mean: one step at 0
                rec.write("/controller", t, {"max_speed": 0.0 if k == 0 else top})
    table = summarize(tmp_path)
    assert list(table["gait.velocity"]) == ["[0.03,0.0]", "[0.0,0.03]"]
    assert table["command_heading_deg"].tolist() == pytest.approx([0.0, 90.0])
    assert table["command_speed_mps"].tolist() == pytest.approx([0.03, 0.03])
    assert table["envelope_mps"].tolist() == pytest.approx([0.024, 0.02])
    assert table["speed_of_envelope"].tolist() == pytest.approx([0.5, 0.9])
    assert (tmp_path / "summary_polar.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # a sweep over something else has no envelope to set its speeds beside, and no polar
    other = tmp_path / "other"
    for i in range(2):
        job = other / f"{i}_mpc.horizon={10 + i}"
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(f"- mpc.horizon={10 + i}\n")
        (job / "metrics.json").write_text(json.dumps({"speed_mps": 0.01}))
    assert "envelope_mps" not in summarize(other) and not (other / "summary_polar.png").exists()
    assert not (other / "summary_gaits.png").exists()  # no gait's distance in its metrics


def test_a_replay_sweeps_per_gait_metrics_are_columns_named_gait_dot_metric(tmp_path: Path) -> None:
    # a replay's metrics.json holds one object per gait: a sweep over a model setting gathers each gait's numbers
    import json

    for i, e in enumerate((2.0e7, 2.1e7)):
        job = tmp_path / f"{i}_robot.leg.youngs_modulus={e}"
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(f"- robot.leg.youngs_modulus={e}\n")
        gait = {"gait": "forward", "distance_per_cycle_mm": 30.0 - 20 * i, "heading_defined": True,
                "slide_min_mm": 35.0 - 25 * i, "slide_max_mm": 60.0}  # fmt: skip
        (job / "metrics.json").write_text(json.dumps({"forward": gait, "cost": 1.5}))
    table = summarize(tmp_path)
    assert table["forward.distance_per_cycle_mm"].tolist() == [30.0, 10.0]
    assert table["cost"].tolist() == [1.5, 1.5]
    assert table["forward.slide_min_mm"].tolist() == [35.0, 10.0]
    assert "forward.gait" not in table and "forward.heading_defined" not in table  # numbers only
    # one numeric model setting swept and a per-gait distance: the gaits' figure against that setting
    assert (tmp_path / "summary_gaits.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
