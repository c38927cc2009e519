"""Metrics and figures from a hardware run's log: what `slot hardware` writes at the end and `slot figures` redoes.

The log has the simulation schema, so the simulate experiment's report applies
unchanged (CoM against reference, Fig. 4; path, Fig. 6; tracking metrics); the
loop-timing summary from the log's ``loop`` record is added to ``metrics.json``.
"""

from __future__ import annotations

from pathlib import Path

from ..atomic import write_json
from ..jobs.simulate import write_report
from ..record import read_log
from ..runlog import find_logs

DRIFT_DISTANCE_M = 0.8  # as the simulate experiment's default: lateral drift over the first 0.8 m


def report(run_dir: Path, velocity: list[float], legs: list[str]) -> dict:
    """Write metrics.json, fig4_com.png and fig6_path.png for a hardware run directory."""
    result = write_report(run_dir, list(velocity), DRIFT_DISTANCE_M, list(legs))
    meta = read_log(find_logs(run_dir)[0], topics=()).metadata  # the metadata alone
    result["loop"] = {k: float(v) for k, v in meta.get("loop", {}).items()}
    result["stop_reason"] = meta.get("summary", {}).get("stop_reason", "")
    write_json(run_dir / "metrics.json", result)
    return result
