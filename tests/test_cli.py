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
from mcap.reader import make_reader

from slotexp.record import is_closed, read_log
from slotexp.signals import child_processes
from tests.helpers import (
    CONF,
    SLOT_CMD,
    as_from_a_terminal,
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


# --------------------------------------------------------------------------- 5. Ctrl-C


def test_ctrl_c_exits_130_and_leaves_a_closed_log(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    log_path = run_dir / "logs" / "baseline.mcap"
    proc = subprocess.Popen(
        [
            *SLOT_CMD,
            "run",
            "experiment=perturb",
            "experiment.scenarios=[baseline]",
            "experiment.duration=600",  # a loaded machine cannot finish it before the signal
            "experiment.n_jobs=1",
            f"hydra.run.dir={run_dir}",
        ],
        cwd=tmp_path,
        env=dict(os.environ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        # as from a terminal: a test run started in the background (`make test &`, CI runners) ignores
        # SIGINT, and an ignored SIGINT is inherited, so the run would rightly never see the Ctrl-C
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 180  # a clean checkout compiles its kernels first
        while time.monotonic() < deadline and proc.poll() is None:
            if log_path.exists() and log_path.stat().st_size > 100_000:
                break
            time.sleep(0.1)
        assert proc.poll() is None, f"run ended before it could be interrupted:\n{proc.stderr.read()}"
        assert log_path.exists(), "no log appeared within 180 s"
        os.killpg(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)  # generous: a loaded machine shuts down slowly
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 130, f"exit {proc.returncode}\nstderr:\n{stderr}"
    assert "Traceback" not in stderr, stderr
    assert "interrupted" in stderr
    assert last_line(stdout) == str(run_dir)

    log = read_log(log_path)
    assert log.truncated is False, "the interrupted run's log was not closed properly"
    t = log["/state"]["t"].to_numpy()
    assert 0 < len(t) < 600 * 30, "the run was not actually interrupted part-way"
    assert np.all(np.diff(t) > 0)
    assert "config" in log.metadata and "run" in log.metadata
    assert "summary" not in log.metadata  # only written when the run completes


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


# --------------------------------------------------------------------------- 7. multirun


def test_multirun_sweeps_solvers_with_joblib(tmp_path: Path) -> None:
    sweep_dir = tmp_path / "sweep"
    proc = ok(
        slot(
            "run",
            "-m",
            "experiment=simulate",
            "experiment.duration=0.5",
            "solver=clarabel,scs",
            f"hydra.sweep.dir={sweep_dir}",
            cwd=tmp_path,
        )
    )
    jobs = sorted(p for p in sweep_dir.iterdir() if p.is_dir())
    assert [p.name.split("_", 1)[0] for p in jobs] == ["0", "1"]
    printed = {ln.strip() for ln in proc.stdout.splitlines()}
    for job, solver in zip(jobs, ["clarabel", "scs"]):
        assert job.name.endswith(f"solver={solver}")
        assert str(job) in printed, f"{job} not printed on stdout"
        metrics = json.loads((job / "metrics.json").read_text())
        assert metrics["gait"] == "walk"
        assert metrics["infeasible_steps"] == 0
        log = read_log(job / "logs" / "walk.mcap")
        assert not log.truncated
        assert log.metadata["run"]["solver"] == solver
        assert yaml.safe_load(log.metadata["config"]["yaml"])["solver"]["name"] == solver
    # a second sweep into the same directory would mix its jobs with these: refused, then replaced on request
    again = [
        "run",
        "-m",
        "experiment=simulate",
        "experiment.duration=0.5",
        "solver=daqp",
        f"hydra.sweep.dir={sweep_dir}",
    ]
    before = (jobs[1] / "logs" / "walk.mcap").read_bytes()
    assert_one_line_error(slot(*again, cwd=tmp_path), str(sweep_dir), "overwrite=true")
    assert (jobs[1] / "logs" / "walk.mcap").read_bytes() == before
    ok(slot(*again, "overwrite=true", cwd=tmp_path))
    (job,) = [p for p in sweep_dir.iterdir() if p.is_dir()]  # job 1 of the earlier sweep is gone, not mixed in
    assert job.name.endswith("solver=daqp")


# --------------------------------------------------------------------------- a controller that never works


@pytest.mark.parametrize(
    "overrides",
    [["mpc.f_max=0.1"], ["solver.time_limit_s=1e-9"]],
    ids=["f_max below the weight", "no time to solve"],
)
def test_a_run_whose_mpc_never_succeeds_fails_with_one_line_and_a_readable_log(
    tmp_path: Path, overrides: list[str]
) -> None:
    run_dir = tmp_path / "run"
    proc = slot(
        "run", "experiment=simulate", "experiment.duration=1", *overrides, f"hydra.run.dir={run_dir}", cwd=tmp_path
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("error: ")]
    assert len(errors) == 1 and "no feasible plan in any of the 30 steps" in errors[0], proc.stderr
    assert proc.stderr.rstrip().splitlines()[-1] == errors[0]  # the progress bar before it, nothing after
    log = run_dir / "logs" / "walk.mcap"
    stats = read_log(log).topics["/mpc/stats"]
    assert len(stats) == 30 and not stats["success"].astype(bool).any()
    with log.open("rb") as fh:
        assert sum(1 for _ in make_reader(fh).iter_messages()) > 0
    forces = read_log(log).topics["/forces"]
    if overrides == ["mpc.f_max=0.1"]:  # the fallback before any success respects the force limit
        assert forces[[f"applied.{i}.2" for i in range(4)]].to_numpy().max() <= 0.1 + 1e-12


@pytest.mark.parametrize("where", ["a file", "/proc", "empty"])
def test_an_output_directory_that_cannot_be_written_is_refused_before_any_work(tmp_path: Path, where: str) -> None:
    target = {"a file": tmp_path / "file", "/proc": Path("/proc/slot-run"), "empty": ""}[where]
    if where == "a file":
        target.write_text("not a directory")
    proc = slot("run", "experiment=simulate", "experiment.duration=0.1", f"hydra.run.dir={target}", cwd=tmp_path)
    assert_one_line_error(proc, "hydra.run.dir")
    assert not (tmp_path / "logs").exists() and not (tmp_path / ".hydra").exists()  # nothing written here
    if where != "empty":  # bench checks its --out before measuring, not after
        bench = slot("bench", "mpc", "--out", str(target), cwd=tmp_path, timeout=60)
        assert_one_line_error(bench, "--out")


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _spawn(args: list[str], cwd: Path) -> subprocess.Popen:
    """``slot`` in its own session, as from a terminal (:func:`tests.helpers.as_from_a_terminal`)."""
    return subprocess.Popen(
        args,
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=as_from_a_terminal,
    )


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=["SIGTERM", "SIGINT", "SIGHUP"])
def test_a_stop_signal_to_the_parent_alone_stops_every_worker_and_closes_every_log(tmp_path: Path, signum) -> None:
    # as timeout, SLURM and systemd send it, to the parent's PID only, with two scenarios running in a pool
    # of two and a third queued behind them
    run_dir = tmp_path / "run"
    proc = _spawn(
        [
            *SLOT_CMD,
            "run",
            "experiment=perturb",
            "experiment.scenarios=[baseline,roll,pitch]",
            "experiment.duration=600",
            "experiment.n_jobs=2",
            f"hydra.run.dir={run_dir}",
        ],
        tmp_path,
    )
    logs = [run_dir / "logs" / f"{name}.mcap" for name in ("baseline", "roll")]
    stdout, _ = _stop_parent_once_logging(proc, logs, signum)
    assert last_line(stdout) == str(run_dir)
    assert not (run_dir / "logs" / "pitch.mcap").exists()  # queued, never started


def test_slot_bench_stopped_by_sigterm_exits_143_with_one_line(tmp_path: Path) -> None:
    # Typer turned every stop outside a Hydra job into a silent exit 130 (a SIGTERM from a timeout or SLURM
    # read as a Ctrl-C); slot bench, figures, layout and summarize now end as slot run does
    proc = _spawn([*SLOT_CMD, "bench", "leg", "--out", str(tmp_path / "bench")], tmp_path)
    try:
        time.sleep(10.0)  # started and measuring (the leg bench runs for minutes)
        assert proc.poll() is None, proc.stderr.read()
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert stderr.strip().splitlines()[-1] == "terminated", stderr
    assert "Traceback" not in stderr


@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGTERM, signal.SIGINT])
def test_a_command_outside_a_hydra_job_ends_on_each_stop_signal_with_its_code(capsys, monkeypatch, signum) -> None:
    import slotexp.cli
    from slotexp.cli import _stoppable, _terminate

    monkeypatch.setattr(slotexp.cli, "_received", [])  # this process's signals so far: none

    @_stoppable
    def command() -> None:
        signal.raise_signal(signum)

    previous = signal.signal(signum, _terminate if signum != signal.SIGINT else signal.default_int_handler)
    try:
        with pytest.raises(SystemExit) as stopped:
            command()
    finally:
        signal.signal(signum, previous)
    assert stopped.value.code == 128 + signum
    word = {signal.SIGTERM: "terminated", signal.SIGHUP: "hung up"}.get(signum, "interrupted")
    assert capsys.readouterr().err.strip() == word


def _stop_parent_once_logging(proc: subprocess.Popen, logs: list[Path], signum: int) -> tuple[str, str]:
    """Send ``signum`` to ``proc``'s PID alone once every log has data; check the exit, the one line on
    stderr, that no worker outlives it and that every log reads completely. Returns (stdout, stderr)."""
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and proc.poll() is None:
            if all(p.exists() and p.stat().st_size > 100_000 for p in logs):
                break
            time.sleep(0.1)
        assert proc.poll() is None, proc.stderr.read()
        workers = child_processes(proc.pid)
        os.kill(proc.pid, signum)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 128 + signum, stderr
    assert "Traceback" not in stderr, stderr
    word = {signal.SIGTERM: "terminated", signal.SIGHUP: "hung up"}.get(signum, "interrupted")
    assert [ln for ln in stderr.splitlines() if ln.startswith(word)], stderr
    time.sleep(1.0)
    assert not [pid for pid in workers if _alive(pid) and "resource_tracker" not in _cmdline(pid)], (
        "a worker outlived its parent"
    )
    for path in logs:
        log = read_log(path)
        assert log.truncated is False and 0 < len(log["/state"]) < 600 * 30
        with path.open("rb") as fh:
            assert sum(1 for _ in make_reader(fh).iter_messages()) > 0
    return stdout, stderr


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")
    except OSError:
        return ""


def test_a_stop_signal_to_a_sweeps_parent_closes_every_running_jobs_log_and_starts_no_other(tmp_path: Path) -> None:
    # slot run -m: the joblib launcher ends its workers with SIGKILL when the parent stops; the parent first
    # passes the signal on and waits for each job to close its log (slotexp/signals.py)
    sweep = tmp_path / "sweep"
    proc = _spawn(
        [
            *SLOT_CMD,
            "run",
            "-m",
            "experiment=simulate",
            "gait=walk,crawl,omni60",
            "experiment.duration=600",
            "hydra.launcher.n_jobs=2",
            f"hydra.sweep.dir={sweep}",
        ],
        tmp_path,
    )
    logs: list[Path] = []
    deadline = time.monotonic() + 120  # until the two running jobs have opened their logs
    while time.monotonic() < deadline and len(logs) < 2:
        logs = sorted(sweep.glob("*/logs/*.mcap"))
        time.sleep(0.1)
    _stop_parent_once_logging(proc, logs, signal.SIGTERM)
    assert not list(sweep.glob("2_*")), "a job queued behind the running two was started"


def test_a_sweeps_jobs_end_when_its_parent_is_killed(tmp_path: Path) -> None:
    # SIGKILL leaves the parent no handler to pass anything on: the kernel tells each job (prctl's parent-death
    # signal, SIGTERM), which stops at its next MPC step with its log closed
    sweep = tmp_path / "sweep"
    proc = _spawn(
        [
            *SLOT_CMD,
            "run",
            "-m",
            "experiment=simulate",
            "gait=walk,crawl",
            "experiment.duration=600",
            "hydra.launcher.n_jobs=2",
            f"hydra.sweep.dir={sweep}",
        ],
        tmp_path,
    )
    try:
        deadline = time.monotonic() + 180  # until both jobs are logging (a clean checkout compiles first)
        logs: list[Path] = []
        while time.monotonic() < deadline and not (len(logs) == 2 and all(p.stat().st_size > 100_000 for p in logs)):
            logs = sorted(sweep.glob("*/logs/*.mcap"))
            time.sleep(0.1)
        assert proc.poll() is None, proc.stderr.read()
        jobs = [pid for pid in child_processes(proc.pid) if "resource_tracker" not in _cmdline(pid)]
        assert jobs
        assert len(logs) == 2, "the jobs' logs did not appear within 180 s"
        os.kill(proc.pid, signal.SIGKILL)
        _, stderr = proc.communicate(timeout=60)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(_alive(pid) for pid in jobs):
            time.sleep(0.1)
        assert not [pid for pid in jobs if _alive(pid)], "a job outlived its sweep's parent"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    for log in logs:
        assert is_closed(log), f"{log} was cut short; stderr:\n{stderr}"


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
