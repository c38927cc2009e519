"""Experiment ``validate``: a trajectory against a reference (a run's log or a marker CSV).

Reference and candidate are each a run directory (its first ``logs/*.mcap``), an
``.mcap`` log, or (reference only) a marker-track CSV; with no candidate given,
the current config is simulated and becomes the candidate. Time alignment and
resampling are those of :mod:`slotexp.compare`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from .. import telemetry as T
from ..atomic import write_csv, write_json, write_text
from ..compare import Alignment, Trajectory, align, compare, load_marker_csv, trajectory_from_frame
from ..config import SlotConfig, check_scenario, choice_field, num_field
from ..errors import ConfigError, UserError
from ..record import read_log
from ..runlog import find_logs
from ..tables import to_markdown
from . import EXPERIMENTS, Experiment
from ._logged import git_commit, run_logged

INPUTS_FILE = "validate_inputs.json"


@dataclass
class ValidateExperiment:
    """Compare a trajectory with a reference (another run's log, or a marker CSV)."""

    name: str = "validate"
    reference: str | None = None
    candidate: str | None = None  # None: simulate the current config
    duration: float = num_field(10.0, lo=0.0, lo_open=True, hi=3600.0, unit="s")
    scenario: str = "baseline"
    align: str = choice_field("start", "start", "absolute")
    offset_s: float = 0.0
    markers: list[str] | None = None

    def check(self, cfg: SlotConfig) -> None:
        check_scenario(cfg, self.scenario, "experiment.scenario names")
        if not self.reference:
            raise ConfigError(
                "experiment.reference is not set: pass experiment.reference=<run dir, .mcap log or marker .csv>"
            )


def load_trajectory(spec: str) -> Trajectory:
    path = Path(spec).expanduser()
    if not path.exists():
        raise UserError(f"{spec}: no such file or directory (give a run dir, an .mcap log or a marker .csv)")
    if path.is_dir():
        logs = find_logs(path)
        if not logs:
            raise UserError(f"{spec}: no logs/*.mcap in this directory: is it a run's output directory?")
        path = logs[0]
    if path.suffix.lower() == ".csv":
        return load_marker_csv(path)
    log = read_log(path)
    if T.MARKERS not in log:
        raise UserError(f"{path}: the log has no /markers topic to compare")
    return trajectory_from_frame(log[T.MARKERS])


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    exp = cfg.experiment
    load_trajectory(exp.reference)  # fail fast: a bad reference is reported before any simulation
    if exp.candidate:
        candidate_spec = exp.candidate
    else:
        log = out_dir / "logs" / f"{cfg.gait.name}.mcap"
        run_logged(cfg, cfg.scenarios[exp.scenario], exp.duration, log, resolved_yaml, git_commit())
        candidate_spec = str(log)
    inputs = {
        "reference": str(Path(exp.reference).expanduser().resolve()),
        "candidate": str(Path(candidate_spec).expanduser().resolve()),
        "align": exp.align,
        "offset_s": exp.offset_s,
        "markers": exp.markers,
    }
    write_json(out_dir / INPUTS_FILE, inputs)
    rebuild(out_dir)


def rebuild(out_dir: Path, cfg: SlotConfig | None = None) -> None:
    """Redo the comparison from the inputs a validate run recorded (its config is not needed)."""
    inputs = json.loads((out_dir / INPUTS_FILE).read_text())
    report(
        out_dir,
        load_trajectory(inputs["reference"]),
        load_trajectory(inputs["candidate"]),
        Alignment(inputs["align"], float(inputs["offset_s"])),
        inputs["markers"],
        inputs["reference"],
        inputs["candidate"],
    )


def report(
    out_dir: Path,
    reference: Trajectory,
    candidate: Trajectory,
    alignment: Alignment,
    markers: list[str] | None,
    reference_name: str,
    candidate_name: str,
) -> None:
    from ..figures.validate import plot_overlay

    table = compare(reference, candidate, alignment, markers)
    write_csv(table, out_dir / "validate.csv", index=False, float_format="%.6g")
    header = (
        f"Reference: `{reference_name}`  \nCandidate: `{candidate_name}`  \n"
        f"Alignment: {alignment.mode}, offset {alignment.offset_s:g} s\n\n"
    )
    write_text(out_dir / "validate.md", header + to_markdown(table))
    times, ref, cand = align(reference, candidate, alignment)
    if markers:
        ref = {m: ref[m] for m in markers}
        cand = {m: cand[m] for m in markers}
    plot_overlay(times, ref, cand, out_dir / "fig_validate.png", title="candidate vs reference")
    write_json(
        out_dir / "metrics.json",
        {
            "reference": reference_name,
            "candidate": candidate_name,
            "alignment": {"mode": alignment.mode, "offset_s": alignment.offset_s},
            "rows": table.to_dict(orient="records"),
        },
    )


EXPERIMENTS.add("validate", Experiment(ValidateExperiment, run, rebuild, walks_gait=True))
