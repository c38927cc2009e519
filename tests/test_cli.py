"""End-to-end tests of the ``slot`` command line, run as a subprocess like a user would.

Every run is short (0.5-1 s of simulated time) so the whole file stays well under
a minute and a half on a 2-core machine. Runs shared by several tests are module-scoped
fixtures; a test that modifies a run directory works on its own copy.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from slotexp.record import read_log
from tests.helpers import (
    CONF,
    SLOT_CMD,
    assert_one_line_error,
    assert_png,
    last_line,
    ok,
    slot,
    slot_after,
)

TABLE1_HEADER = ["scenario", "max_cost", "mean_cost", "final_cost", "settle_s", "infeasible_steps"]
PERTURB_SCENARIOS = ["baseline", "height"]
PERTURB_HORIZON = 12  # not the default (15): proves the logged config is the resolved one
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def plain(text: str) -> str:
    """Help text without colour codes, box drawing or line wrapping."""
    text = ANSI.sub("", text)
    text = re.sub(r"[\u2500-\u257f]", " ", text)
    return " ".join(text.split())


# --------------------------------------------------------------------------- shared runs


@pytest.fixture(scope="module")
def perturb_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, subprocess.CompletedProcess]:
    """A 1 s, 2-scenario perturb run through the parallel (n_jobs=2) path."""
    base = tmp_path_factory.mktemp("perturb")
    run_dir = base / "run"
    proc = slot(
        "run",
        "experiment=perturb",
        f"experiment.scenarios=[{','.join(PERTURB_SCENARIOS)}]",
        "experiment.duration=1.0",
        "experiment.n_jobs=2",
        f"mpc.horizon={PERTURB_HORIZON}",
        f"hydra.run.dir={run_dir}",
        cwd=base,
    )
    return run_dir, proc


@pytest.fixture(scope="module")
def simulate_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 1 s walk-gait simulate run (directory A of the validate tests)."""
    base = tmp_path_factory.mktemp("simulate")
    run_dir = base / "A"
    proc = ok(slot("run", "experiment=simulate", "experiment.duration=1", f"hydra.run.dir={run_dir}", cwd=base))
    assert last_line(proc.stdout) == str(run_dir)
    return run_dir


# --------------------------------------------------------------------------- 1. perturb


def test_perturb_run_writes_table_logs_and_figures(perturb_run) -> None:
    run_dir, proc = perturb_run
    ok(proc)
    assert last_line(proc.stdout) == str(run_dir)

    with open(run_dir / "table1.csv", newline="") as f:
        header = f.readline().strip().split(",")
    assert header == TABLE1_HEADER
    table = pd.read_csv(run_dir / "table1.csv")
    assert list(table["scenario"]) == PERTURB_SCENARIOS
    assert (table["infeasible_steps"] == 0).all()
    assert (table["final_cost"] <= table["max_cost"]).all()
    assert (table["max_cost"] > 0).all()
    assert np.isfinite(table[["max_cost", "mean_cost", "final_cost"]].to_numpy()).all()

    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert [r["scenario"] for r in metrics["table1"]] == PERTURB_SCENARIOS
    assert "Infeasible steps" in (run_dir / "table1.md").read_text()

    logs = sorted((run_dir / "logs").glob("*.mcap"))
    assert [p.stem for p in logs] == sorted(PERTURB_SCENARIOS)
    steps = int(round(1.0 * 30.0))
    for path in logs:
        log = read_log(path)
        assert not log.truncated, f"{path} was not closed properly"
        assert len(log["/state"]) == steps
        assert np.all(np.diff(log["/state"]["t"].to_numpy()) > 0)

        conf = yaml.safe_load(log.metadata["config"]["yaml"])
        assert conf["mpc"]["horizon"] == PERTURB_HORIZON
        assert conf["experiment"]["name"] == "perturb"
        assert conf["experiment"]["scenarios"] == PERTURB_SCENARIOS
        assert conf["experiment"]["duration"] == 1.0

        run = log.metadata["run"]
        assert run["experiment"] == "perturb"
        assert run["scenario"] == path.stem
        assert re.fullmatch(r"[0-9a-f]{40}(-dirty)?|unknown", run["git_commit"]), run["git_commit"]
        assert log.metadata["summary"]["infeasible_steps"] == "0"
        assert int(log.metadata["summary"]["steps"]) == steps

    assert_png(run_dir / "fig7_cost.png")
    assert_png(run_dir / "fig8_dcm.png")


# --------------------------------------------------------------------------- 2. figures


def test_figures_rebuilds_table_and_figures_from_logs_alone(perturb_run, tmp_path: Path) -> None:
    run_dir, proc = perturb_run
    ok(proc)
    original = (run_dir / "table1.csv").read_text()
    copy = tmp_path / "copy"
    shutil.copytree(run_dir, copy)
    for name in ("table1.csv", "table1.md", "fig7_cost.png", "fig8_dcm.png", "metrics.json"):
        (copy / name).unlink()
    shutil.rmtree(copy / ".hydra")  # nothing but logs/ is left to rebuild from

    out = ok(slot("figures", copy, cwd=tmp_path, timeout=60))
    assert last_line(out.stdout) == str(copy)
    assert (copy / "table1.csv").read_text() == original
    assert (copy / "table1.md").read_text() == (run_dir / "table1.md").read_text()
    assert_png(copy / "fig7_cost.png")
    assert_png(copy / "fig8_dcm.png")
    assert (copy / "metrics.json").is_file()


# --------------------------------------------------------------------------- 3. bad input

GARBAGE_CSV = "this is not,a marker file\n1,2\n3,4\n"

PRECHECKED = [  # (overrides, words the error must name): rejected before Hydra launches anything
    (["robot.torso.mass=-1"], ["robot.torso.mass"]),
    (["mpc.horizon=0"], ["mpc.horizon"]),
    (["robot.leg.thickness_root=0"], ["robot.leg.thickness_root"]),
    (["experiment=nope"], ["experiment", "nope"]),
    (["gait=nope"], ["gait", "nope"]),
    (["mpc.horizon=abc"], ["mpc.horizon", "abc"]),
    (["solver=nope"], ["solver", "nope"]),
    (["nonexistent_key=1"], ["nonexistent_key"]),
    (["solver=scs,osqp"], ["solver=scs,osqp", "-m"]),
    (["experiment=validate"], ["experiment.reference"]),
    (["--cfg", "job", "gait=nope"], ["gait", "nope"]),
    (["--cfg", "job", "mpc.horizon=abc"], ["mpc.horizon", "abc"]),
    # non-finite numbers anywhere, declared range or not (they ran and gave NaN states, finite-looking metrics)
    (["scenarios.roll.offset.roll=inf"], ["scenarios.roll.offset.roll", "finite"]),
    (["scenarios.baseline.offset.vz=nan"], ["scenarios.baseline.offset.vz", "finite"]),
    (["scenarios.combined.impulses.0.linear=[0,nan,0]"], ["scenarios.combined.impulses[0].linear[1]", "finite"]),
    # values the schema accepted but the run could not use (they printed tracebacks)
    (["experiment=simulate", "experiment.duration=0.01"], ["experiment.duration = 0.01", "0.0667 s"]),
    (["experiment=perturb", "experiment.duration=0.01"], ["experiment.duration = 0.01", "0.0667 s"]),
    (["=5"], ["'=5'", "key=value"]),
    (["experiment=calibrate", "experiment.max_deg=-10"], ["experiment.max_deg = -10"]),
    (["experiment=leg", "leg_load.root_height=-1"], ["leg_load.root_height = -1"]),
    # errors that point the right way: the key the user meant, not Hydra's "+key" (which nothing would read)
    (["mpc.horizonn=10"], ["unknown key mpc.horizonn", "did you mean mpc.horizon?"]),
    (["+mpc.horizonn=10"], ["unknown key mpc.horizonn", "did you mean mpc.horizon?"]),
    (["gaits=walk"], ["unknown key gaits", "did you mean gait?"]),
    (["hydra.rundir=x"], ["unknown key hydra.rundir", "did you mean hydra.run?"]),
    (["hydra.launcher.n_jobs=abc"], ["hydra.launcher.n_jobs=abc"]),
    (["hydra/launcher=jobllib"], ["jobllib", "joblib"]),
    (["hydra.sweep.dir=out[1,2]"], ["hydra.sweep.dir=out[1,2]", "quote", "hydra.sweep.dir='out[1,2]'"]),
    (["-m", "hydra.launcher.n_jobs=1,2"], ["hydra.launcher.n_jobs=1,2", "one value"]),
    (["-m", "gait=walk,crawl", "live=true"], ["live=true", "live_port=0"]),  # the jobs would share one port
    ([""], ["empty"]),
    (["experiment.scenario=bäseline"], ["must be quoted", "experiment.scenario='bäseline'"]),
    (["mpç.horizon=3"], ["'mpç.horizon' is not a setting's name"]),
    (["experiment=simulate", "experiment.name=perturb"], ["experiment.name = 'perturb'", "experiment=perturb"]),
    (["experiment=legmap", "plant=cosserat", "experiment.angles=3"], ["experiment.angles = 3", "needs 6"]),
    (["-m", "hydra.launcher.n_jobs=0", "experiment=simulate"], ["hydra.launcher.n_jobs=0", "-1 for every core"]),
    (
        ["-m", "experiment=simulate", "gait.name=" + "a" * 99, "scenarios.baseline.name=" + "b" * 99, "mpc.horizon=10"],
        ["over the file system's 255", "hydra.sweep.subdir"],
    ),
    (
        ["experiment=gait_search", "plant=cosserat", "experiment.verify_duration=0.5", "experiment.settle=1"],
        ["experiment.verify_duration = 0.5", "raise verify_duration"],
    ),
    (["sim.dt=1e-9"], ["sim.dt", ">= 1e-06"]),
    # names that become file names never leave the run directory, and each names one log
    (["experiment=perturb", "experiment.scenarios=[../../x]"], ["experiment.scenarios", "'../../x'", "no '..'"]),
    (["gait.name=../x"], ["gait.name", "'../x'", "cannot name a file"]),
    (["gait.name=a/b"], ["gait.name", "'a/b'"]),
    (["gait.name=" + "a" * 300], ["gait.name", "1-100 letters"]),
    (["experiment=perturb", "experiment.scenarios=[baseline,baseline]"], ["baseline more than once"]),
    (["experiment=perturb", "experiment.scenarios=[baseline,roll]", "scenarios.roll.name=baseline"], ["baseline"]),
]


@pytest.mark.parametrize("overrides,names", PRECHECKED, ids=[" ".join(o) for o, _ in PRECHECKED])
def test_bad_override_is_one_line_error(tmp_path: Path, overrides: list[str], names: list[str]) -> None:
    run_dir = tmp_path / "run"
    proc = slot("run", *overrides, f"hydra.run.dir={run_dir}", cwd=tmp_path, timeout=60)
    assert_one_line_error(proc, *names)
    assert not run_dir.exists(), "a run directory was created for a rejected config"
    assert not (tmp_path / "experiments").exists()


@pytest.mark.mujoco
def test_a_rigid_model_mujoco_cannot_read_is_one_line_error(tmp_path: Path) -> None:
    overrides = ["plant=rigid", "robot=mini_cheetah", f"robot.rigid.model={__file__}"]
    run_dir = tmp_path / "run"
    proc = slot("run", *overrides, f"hydra.run.dir={run_dir}", cwd=tmp_path, timeout=60)
    assert_one_line_error(proc, "is not a model MuJoCo can read")
    assert not run_dir.exists(), "a run directory was created for a rejected config"


@pytest.mark.parametrize("bad", ["experiment.scenario=bäseline", "x=[1,2", "mpç.horizon=3", "gait=wälk"])
def test_every_override_the_precheck_suggests_parses(tmp_path: Path, bad: str) -> None:
    import re

    from hydra.core.override_parser.overrides_parser import OverridesParser

    proc = slot("run", bad, f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path, timeout=60)
    line = assert_one_line_error(proc)
    for suggestion in re.findall(r'"([^"]+=[^"]*)"', line):
        OverridesParser.create().parse_override(suggestion)  # raises if the suggested fix does not parse


def test_validate_missing_reference_path_is_one_line_error(tmp_path: Path) -> None:
    proc = slot(
        "run",
        "experiment=validate",
        "experiment.reference=/does/not/exist",
        f"hydra.run.dir={tmp_path / 'run'}",
        cwd=tmp_path,
        timeout=60,
    )
    assert_one_line_error(proc, "/does/not/exist")


def test_validate_garbage_reference_csv_is_one_line_error(tmp_path: Path) -> None:
    ref = tmp_path / "garbage.csv"
    ref.write_text(GARBAGE_CSV)
    proc = slot(
        "run",
        "experiment=validate",
        f"experiment.reference={ref}",
        "experiment.duration=0.5",
        f"hydra.run.dir={tmp_path / 'run'}",
        cwd=tmp_path,
        timeout=60,
    )
    assert_one_line_error(proc, "garbage.csv")


def test_figures_on_missing_dir_is_one_line_error(tmp_path: Path) -> None:
    proc = slot("figures", "/does/not/exist", cwd=tmp_path, timeout=60)
    assert_one_line_error(proc, "/does/not/exist")


def test_multirun_with_one_bad_value_fails_before_launching(tmp_path: Path) -> None:
    sweep_dir = tmp_path / "sweep"
    proc = slot(
        "run",
        "-m",
        "experiment=simulate",
        "experiment.duration=0.5",
        "mpc.horizon=15,0",
        f"hydra.sweep.dir={sweep_dir}",
        cwd=tmp_path,
        timeout=60,
    )
    assert_one_line_error(proc, "mpc.horizon")
    assert not sweep_dir.exists(), "the sweep launched before the bad value was rejected"
    assert not (tmp_path / "experiments").exists()
    assert proc.stdout.strip() == ""


# --------------------------------------------------------------------------- 4. info and help


def test_cfg_job_prints_composed_yaml(tmp_path: Path) -> None:
    proc = ok(slot("run", "--cfg", "job", "experiment=simulate", "gait=crawl", cwd=tmp_path, timeout=60))
    assert "name: crawl" in proc.stdout
    conf = yaml.safe_load(proc.stdout)
    assert conf["gait"]["name"] == "crawl"
    assert conf["experiment"]["name"] == "simulate"
    assert conf["gait"]["phases"][0] == [30, 1, 0, 1, 1]
    assert list(tmp_path.iterdir()) == [], "printing the config must not start a run"


def test_help(tmp_path: Path) -> None:
    top = ok(slot("--help", cwd=tmp_path, timeout=60))
    text = plain(top.stdout)
    assert "run" in text and "figures" in text
    sub = ok(slot("run", "--help", cwd=tmp_path, timeout=60))
    text = plain(sub.stdout)
    assert "Usage: slot run" in text
    assert "overrides" in text and "-m" in text
    # every choice of every group is listed, read from the config tree (a new file appears without an edit)
    words = set(text.replace(",", " ").replace(":", " ").split())
    for group in ("experiment", "gait", "plant", "robot", "solver", "controller", "scenario", "schedule"):
        assert {p.stem for p in (CONF / group).glob("*.yaml")} <= words, group
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- 6. validate


def _rows(run_dir: Path) -> pd.DataFrame:
    return pd.DataFrame(json.loads((run_dir / "metrics.json").read_text())["rows"])


def test_validate_run_against_itself_is_zero(simulate_run: Path, tmp_path: Path) -> None:
    out_dir = tmp_path / "V"
    proc = ok(
        slot(
            "run",
            "experiment=validate",
            f"experiment.reference={simulate_run}",
            f"experiment.candidate={simulate_run}",
            f"hydra.run.dir={out_dir}",
            cwd=tmp_path,
        )
    )
    assert last_line(proc.stdout) == str(out_dir)
    table = pd.read_csv(out_dir / "validate.csv")
    assert list(table.columns) == ["marker", "axis", "rmse_m", "mae_m", "nrmse", "n_samples"]
    assert "com" in set(table["marker"])
    assert len(table) == 3 * table["marker"].nunique()
    assert (table["rmse_m"].abs() <= 1e-12).all()
    assert (table["n_samples"] == 30).all()
    rows = _rows(out_dir)
    assert len(rows) == len(table)
    assert (rows["rmse_m"].abs() <= 1e-12).all()
    assert (out_dir / "validate.md").is_file()
    assert_png(out_dir / "fig_validate.png")


def test_validate_marker_csv_with_known_z_offset(simulate_run: Path, tmp_path: Path) -> None:
    markers = read_log(simulate_run / "logs" / "walk.mcap")["/markers"]
    offset = 0.005
    ref = tmp_path / "markers.csv"
    lines = ["# built from the simulate run's /markers, com z shifted by +5 mm", "t,com_x,com_y,com_z"]
    for t, x, y, z in markers[["t", "com.0", "com.1", "com.2"]].itertuples(index=False):
        lines.append(f"{t!r},{x!r},{y!r},{z + offset!r}")
    ref.write_text("\n".join(lines) + "\n")

    out_dir = tmp_path / "V"
    proc = ok(
        slot(
            "run",
            "experiment=validate",
            f"experiment.reference={ref}",
            f"experiment.candidate={simulate_run}",
            f"hydra.run.dir={out_dir}",
            cwd=tmp_path,
        )
    )
    assert last_line(proc.stdout) == str(out_dir)
    for table in (pd.read_csv(out_dir / "validate.csv"), _rows(out_dir)):
        assert list(table["marker"]) == ["com"] * 3
        by_axis = table.set_index("axis")
        assert by_axis.loc["z", "rmse_m"] == pytest.approx(offset, rel=1e-6)
        assert by_axis.loc["z", "mae_m"] == pytest.approx(offset, rel=1e-6)
        assert by_axis.loc["x", "rmse_m"] <= 1e-12
        assert by_axis.loc["y", "rmse_m"] <= 1e-12
        assert (table["n_samples"] == len(markers)).all()


def test_figures_rebuilds_validate_run_with_candidate(simulate_run: Path, tmp_path: Path) -> None:
    out_dir = tmp_path / "V"
    ok(
        slot(
            "run",
            "experiment=validate",
            f"experiment.reference={simulate_run}",
            f"experiment.candidate={simulate_run}",
            f"hydra.run.dir={out_dir}",
            cwd=tmp_path,
        )
    )
    original = (out_dir / "validate.csv").read_text()
    (out_dir / "validate.csv").unlink()
    ok(slot("figures", out_dir, cwd=tmp_path, timeout=60))
    assert (out_dir / "validate.csv").read_text() == original


# --------------------------------------------------------------------------- an output directory is never reused


def test_a_run_directory_with_another_runs_outputs_is_refused_unless_overwrite(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    first = slot("run", "experiment=simulate", "experiment.duration=1", f"hydra.run.dir={run_dir}", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    log = run_dir / "logs" / "walk.mcap"
    before = log.read_bytes()
    again = slot("run", "experiment=simulate", "experiment.duration=2", f"hydra.run.dir={run_dir}", cwd=tmp_path)
    assert_one_line_error(again, str(run_dir), "overwrite=true")
    assert log.read_bytes() == before  # nothing already written is lost
    replaced = slot(
        "run",
        "experiment=simulate",
        "experiment.duration=2",
        f"hydra.run.dir={run_dir}",
        "overwrite=true",
        cwd=tmp_path,
    )
    assert replaced.returncode == 0, replaced.stderr
    assert len(read_log(log)["/state"]) == 60  # the new run's, whole


def test_an_overwrite_sets_the_earlier_outputs_aside_until_the_new_run_succeeds(tmp_path: Path) -> None:
    # an overwrite once cleared the old outputs before the new run's input was checked (a bad CSV path lost the
    # earlier run), and left another experiment's files beside the new ones
    run_dir = tmp_path / "run"
    ok(slot("run", "experiment=simulate", "experiment.duration=1", f"hydra.run.dir={run_dir}", cwd=tmp_path))
    before = (run_dir / "logs" / "walk.mcap").read_bytes()
    bad = slot(
        "run", "experiment=validate", "experiment.reference=/nowhere.csv", f"hydra.run.dir={run_dir}",
        "overwrite=true", cwd=tmp_path,
    )  # fmt: skip
    assert bad.returncode == 2 and "no such file" in bad.stderr
    kept = run_dir / ".replaced"
    assert f"kept in {kept}" in bad.stderr
    assert (kept / "logs" / "walk.mcap").read_bytes() == before  # nothing already written is lost
    replaced = ok(
        slot("run", "experiment=perturb", "experiment.scenarios=[baseline]", "experiment.duration=1",
             f"hydra.run.dir={run_dir}", "overwrite=true", cwd=tmp_path)
    )  # fmt: skip
    assert "kept in" not in replaced.stderr
    assert not kept.exists()  # the new run succeeded: what it replaced is gone ...
    assert not (run_dir / "fig6_path.png").exists()  # ... and no other experiment's file stays beside its own
    assert (run_dir / "table1.csv").exists()


def test_the_directory_hydra_resolves_is_the_one_claimed(tmp_path: Path) -> None:
    # an interpolated hydra.run.dir once bypassed the guard (an earlier run overwritten, a literal ${gait.name}
    # directory made); a file in the way, or a sweep whose jobs would share one directory, end in one line
    first = ok(slot("run", "experiment=simulate", "experiment.duration=1", "hydra.run.dir=runs/${gait.name}",
                    cwd=tmp_path))  # fmt: skip
    assert last_line(first.stdout) == str(tmp_path / "runs" / "walk")
    again = slot("run", "experiment=simulate", "experiment.duration=1", "hydra.run.dir=runs/${gait.name}", cwd=tmp_path)
    assert_one_line_error(again, "runs/walk", "overwrite=true")
    assert not (tmp_path / "runs" / "${gait.name}").exists()
    (tmp_path / "blocked").write_text("a file where a directory should go")
    blocked = slot("run", "experiment=simulate", "experiment.duration=1", "hydra.run.dir=blocked/run", cwd=tmp_path)
    assert_one_line_error(blocked, "blocked/run", "choose")
    same = slot("run", "-m", "experiment=simulate", "gait=walk,crawl", "hydra.sweep.subdir=one", cwd=tmp_path)
    assert_one_line_error(same, "hydra.sweep.subdir", "the same for every job")


def test_default_directories_of_runs_started_in_the_same_second_differ(tmp_path: Path) -> None:
    from slotexp.rundir import claim, unique

    default = tmp_path / "experiments" / "simulate" / "2026-01-01_00-00-00"
    claim(unique(default), False)  # the first run's, held by this process (a live run)
    second = unique(default)
    assert second == default.with_name(default.name + "_2")
    (second / "slot.log").parent.mkdir(parents=True)
    (second / "slot.log").write_text("a finished run's log")
    assert unique(default) == default.with_name(default.name + "_3")


def test_slot_bench_and_figures_follow_the_same_directory_rules(tmp_path: Path) -> None:
    from slotexp.rundir import claim

    assert_one_line_error(slot("bench", "mpc", "--out=", cwd=tmp_path), "--out is empty")
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / "bench.csv").write_text("an earlier benchmark")
    assert_one_line_error(slot("bench", "mpc", "--out", str(earlier), cwd=tmp_path), "holds another", "overwrite=true")
    refused = slot("bench", "mpc", f"hydra.run.dir={earlier}", cwd=tmp_path)  # honoured, under the same rules
    assert_one_line_error(refused, "hydra.run.dir", "overwrite=true")
    assert (earlier / "bench.csv").read_text() == "an earlier benchmark"
    busy = tmp_path / "busy"
    claim(busy, False)  # a run still writing there (this process holds its lock)
    assert_one_line_error(slot("figures", str(busy), cwd=tmp_path), "still writing")


def test_a_run_directory_in_use_is_refused(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    busy = subprocess.Popen(
        [*SLOT_CMD, "run", "experiment=simulate", "experiment.duration=600", f"hydra.run.dir={run_dir}"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (run_dir / "logs" / "walk.mcap").exists():
            time.sleep(0.1)
        second = slot(
            "run",
            "experiment=simulate",
            "experiment.duration=1",
            f"hydra.run.dir={run_dir}",
            "overwrite=true",
            cwd=tmp_path,
        )
        assert_one_line_error(second, "in use by another slot run")
    finally:
        os.killpg(busy.pid, signal.SIGTERM)
        busy.wait(timeout=60)
    assert read_log(run_dir / "logs" / "walk.mcap").truncated is False  # the first run's log, closed


def test_figures_and_summarize_say_which_logs_are_truncated(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    proc = slot(
        "run",
        "-m",
        "experiment=simulate",
        "experiment.duration=2",  # long enough that half the log holds a whole chunk (about 0.6 s)
        "mpc.horizon=5,6",
        f"hydra.sweep.dir={sweep}",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    job = sorted(p for p in sweep.iterdir() if p.is_dir())[0]
    log = job / "logs" / "walk.mcap"
    log.write_bytes(log.read_bytes()[: log.stat().st_size // 2])  # as a SIGKILL leaves it
    metrics = (job / "metrics.json").read_bytes()
    refused = slot("figures", str(job), cwd=tmp_path)
    assert_one_line_error(refused, "walk.mcap", "truncated", "--force")
    assert (job / "metrics.json").read_bytes() == metrics  # built from the complete log: kept
    forced = slot("figures", str(job), "--force", cwd=tmp_path)
    assert forced.returncode == 0 and "walk.mcap is truncated" in forced.stderr, forced.stderr
    other = sorted(p for p in sweep.iterdir() if p.is_dir())[1] / "logs" / "walk.mcap"
    head = other.read_bytes()
    # killed after the run's metadata but before its first chunk was written: no step to rebuild from
    for cut in range(1000, len(head), 1000):
        other.write_bytes(head[:cut])
        if read_log(other).metadata.get("run"):
            break
    assert not read_log(other).topics
    empty = slot("figures", str(other.parent.parent), "--force", cwd=tmp_path)
    assert empty.returncode == 2 and "Traceback" not in empty.stderr, empty.stderr
    warning, error = empty.stderr.strip().splitlines()  # the truncation warning, then one line of error
    assert "walk.mcap is truncated" in warning
    assert error.startswith("error: ") and "first whole chunk" in error and "nothing to rebuild" in error, error
    other.write_bytes(head)
    summary = slot("summarize", str(sweep), cwd=tmp_path)
    assert summary.returncode == 0, summary.stderr
    assert f"warning: {job.name}: logs incomplete: walk.mcap" in summary.stderr
    table = pd.read_csv(sweep / "summary.csv")
    assert list(table["logs"]) == ["incomplete: walk.mcap", "complete"]


def test_perturb_ends_by_printing_table_i_and_its_time_before_the_output_directory(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = ok(
        slot(
            "run",
            "experiment=perturb",
            "experiment.duration=0.5",
            "experiment.scenarios=[baseline,roll]",
            f"hydra.run.dir={run_dir}",
            cwd=tmp_path,
        )
    )
    lines = proc.stdout.strip().splitlines()
    assert lines[-1] == str(run_dir) and lines[-2].startswith("done in ")
    table = (run_dir / "table1.md").read_text().rstrip()
    assert table in proc.stdout and "| baseline |" in table and "| roll |" in table
    assert "PillowWriter" not in proc.stdout + proc.stderr


def test_a_config_file_that_is_not_yaml_is_named_in_one_line(tmp_path: Path) -> None:
    import yaml

    from slotexp.cli import yaml_error_line

    bad = tmp_path / "default.yaml"
    bad.write_text("walk:\n  frequency_hz: [1, 2\n")
    try:
        with open(bad) as f:
            yaml.safe_load(f)
    except yaml.YAMLError as exc:
        line = yaml_error_line(exc)
    assert "\n" not in line and str(bad) in line and "line 3" in line and "not valid YAML" in line


@pytest.mark.parametrize(("stored", "named"), [("a: [unclosed", "not valid YAML"), ("- a list", "not a mapping")])
def test_figures_on_a_log_with_damaged_config_metadata_is_one_line(tmp_path: Path, stored: str, named: str) -> None:
    from slotexp.record import Recorder

    (tmp_path / "run" / "logs").mkdir(parents=True)
    meta = {"config": {"yaml": stored}, "run": {"experiment": "simulate"}}
    with Recorder(tmp_path / "run" / "logs" / "walk.mcap", metadata=meta) as rec:
        rec.write("/cost", 0.0, {"stage": 0.0})
    assert_one_line_error(slot("figures", str(tmp_path / "run"), cwd=tmp_path), "config stored in this log", named)


@pytest.mark.parametrize(
    ("case", "state"),
    [("strings", {"rpy": ["a", "b", "c"], "p": ["x", "y", "z"]}), ("other_fields", {"foo": 1.0, "bar": [2.0]})],
)
def test_figures_on_a_log_whose_topics_hold_other_fields_is_one_line(
    simulate_run: Path, tmp_path: Path, case: str, state: dict
) -> None:
    # a log with the run's own (valid) config, whose numeric topics hold strings or other fields than slot writes
    from slotexp.record import Recorder, read_log
    from slotexp.runlog import RUN_TOPICS

    source = next((simulate_run / "logs").glob("*.mcap"))
    meta = read_log(source, topics=()).metadata
    (tmp_path / "run" / "logs").mkdir(parents=True)
    with Recorder(tmp_path / "run" / "logs" / source.name, metadata=meta) as rec:
        for k in range(5):
            for topic in RUN_TOPICS:  # every topic a run's tables read, none with what slot writes there
                rec.write(topic, k / 30, state)
    line = assert_one_line_error(slot("figures", str(tmp_path / "run"), cwd=tmp_path, timeout=60), "do not hold")
    assert "simulate" in line and str(tmp_path / "run" / "logs") in line


@pytest.mark.parametrize(
    ("module", "extra", "args"),
    [
        ("mujoco", "rigid", ["run", "experiment=simulate", "plant=rigid", "experiment.duration=0.1"]),
        ("dynamixel_sdk", "hardware", ["hardware", "--dry-run", "duration=0.1", "hardware.port=/dev/null"]),
    ],
    ids=["mujoco", "dynamixel_sdk"],
)
def test_a_missing_optional_dependency_names_its_extra_in_one_line(
    tmp_path: Path, module: str, extra: str, args: list[str]
) -> None:
    # the optional dependency made unimportable (None in sys.modules), then the real CLI
    prelude = f"import sys; sys.modules[{module!r}] = None"
    proc = slot_after(prelude, *args, f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert_one_line_error(proc, module, f"[{extra}]", f"pip install 'slotexp[{extra}]'")


def test_every_optional_dependency_maps_to_an_extra_that_pyproject_declares() -> None:
    import tomllib

    from slotexp.errors import EXTRAS, missing_extra

    extras = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    for module, extra in EXTRAS.items():
        assert extra in extras
        error = missing_extra(ModuleNotFoundError(f"No module named {module!r}", name=f"{module}.sub"))
        assert error is not None and f"[{extra}]" in str(error) and "\n" not in str(error)
    assert missing_extra(ModuleNotFoundError("No module named 'numpy'", name="numpy")) is None  # a real bug


def test_a_closed_stdout_ends_in_one_line_and_the_run_is_complete(tmp_path: Path) -> None:
    # stdout's reader gone before the run's last lines (as in `slot run ... | head -0`): one line on stderr
    # naming where the outputs are, exit 2, no traceback; the run's outputs are all there
    def closed(*args: str) -> tuple[int, str]:
        proc = subprocess.Popen(
            [*SLOT_CMD, *args], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        proc.stdout.close()  # the reader goes away at once
        err = proc.stderr.read()
        return proc.wait(timeout=120), err

    run_dir = tmp_path / "run"
    code, err = closed(
        "run", "experiment=perturb", "experiment.duration=0.3", "experiment.scenarios=[baseline]",
        f"hydra.run.dir={run_dir}",
    )  # fmt: skip
    lines = [ln for ln in err.splitlines() if ln.startswith("error") or "Traceback" in ln]
    assert code == 2 and lines == [
        f"error: stdout was closed before the command's last lines: its outputs are complete in {run_dir}"
    ]
    assert (run_dir / "table1.md").is_file() and (run_dir / "metrics.json").is_file()
    assert read_log(run_dir / "logs" / "baseline.mcap")["/state"].shape[0] > 0
    code, err = closed("figures", str(run_dir))  # a command outside Hydra
    assert (
        code == 2
        and "Traceback" not in err
        and err.strip().splitlines() == ["error: stdout was closed before the command's last lines"]
    )


def test_a_full_disk_ends_in_one_line_and_keeps_what_was_written(tmp_path: Path) -> None:
    # the file system refuses the run's tables (ENOSPC from every atomic write, as a full disk gives):
    # one line naming the file and the run directory, exit 2, no traceback; the logs written before stay
    prelude = (
        "import errno, contextlib, slotexp.atomic as atomic\n"
        "@contextlib.contextmanager\n"
        "def full(path):\n"
        "    raise OSError(errno.ENOSPC, 'No space left on device', str(path))\n"
        "    yield\n"
        "atomic.replacing = full"
    )
    run_dir = tmp_path / "run"
    args = ["run", "experiment=perturb", "experiment.duration=0.3", "experiment.scenarios=[baseline]"]
    proc = slot_after(prelude, *args, f"hydra.run.dir={run_dir}", cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("error")]  # after the progress bar
    assert len(errors) == 1 and errors[0].startswith(f"error: {run_dir}/")  # the file it could not write
    assert "No space left on device" in errors[0] and "slot figures" in errors[0]
    assert read_log(run_dir / "logs" / "baseline.mcap")["/state"].shape[0] > 0


def test_slot_hardware_on_a_full_disk_ends_in_one_line(tmp_path: Path) -> None:
    # the same failure class as slot run's: the log cannot be opened (ENOSPC), one line naming it, exit 2
    prelude = (
        "import errno, slotexp.record as record\n"
        "def full(self, path, *args, **kwargs):\n"
        "    raise OSError(errno.ENOSPC, 'No space left on device', str(path))\n"
        "record.Recorder.__init__ = full"
    )
    run_dir = tmp_path / "run"
    proc = slot_after(prelude, "hardware", "odometry=sim", "duration=0.2", f"hydra.run.dir={run_dir}", cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("error")]
    assert len(errors) == 1 and "No space left on device" in errors[0] and "hardware.mcap" in errors[0], errors


@pytest.fixture
def read_only_dir(tmp_path: Path):
    """A directory nothing can be created in, holding one page: by its mode for a user, a read-only tmpfs for root
    (whose writes ignore modes); skipped where root may not mount."""
    where = tmp_path / "ro"
    where.mkdir()
    if os.geteuid() != 0:
        (where / "page.md").write_text("# page\n")
        where.chmod(0o555)
        yield where
        where.chmod(0o755)
        return
    mount = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(where)], capture_output=True)
    if mount.returncode != 0:
        pytest.skip("running as root where tmpfs cannot be mounted: no directory here is read-only to root")
    try:
        (where / "page.md").write_text("# page\n")
        subprocess.run(["mount", "-o", "remount,ro", str(where)], check=True, capture_output=True)
        yield where
    finally:
        subprocess.run(["umount", str(where)], capture_output=True)


@pytest.mark.parametrize("command", [["figures"], ["manual", "--pages"]], ids=["figures", "manual"])
def test_a_command_that_writes_into_a_read_only_directory_says_so_before_any_work(
    read_only_dir: Path, command: list[str], tmp_path: Path
) -> None:
    proc = slot(*command, str(read_only_dir), cwd=tmp_path)
    assert_one_line_error(proc, str(read_only_dir), "cannot create anything")
    assert [p.name for p in read_only_dir.iterdir()] == ["page.md"]
