"""Turn one run's MCAP log into arrays: what every table and figure is rebuilt from."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from . import telemetry as T
from .errors import UserError
from .mpc import CONSTRAINT_GROUPS
from .record import Log, read_log


@dataclass
class RunData:
    path: Path
    run: dict[str, str]  # metadata "run": experiment, scenario, gait, solver, plant, commit
    summary: dict[str, str]  # metadata "summary" (absent if the run was interrupted)
    truncated: bool
    t: np.ndarray
    x: np.ndarray  # (n, 12) true state
    x_meas: np.ndarray  # (n, 12) state the MPC saw
    x_ref: np.ndarray  # (n, 12) reference at the same time
    cost: np.ndarray  # (n,) stage cost
    stats: pd.DataFrame  # status, success, fallback, iterations, solve_time_s, ...
    violations: pd.DataFrame  # one column per constraint group, N
    stance: np.ndarray  # (n, 4) bool
    forces: np.ndarray  # (n, 4, 3) applied
    markers: pd.DataFrame  # t plus <marker>.0/.1/.2

    @property
    def name(self) -> str:
        return self.run.get("scenario", self.path.stem)

    @property
    def infeasible_steps(self) -> int:
        return int(self.stats["fallback"].astype(bool).sum())


def _states(df: pd.DataFrame, n: int) -> np.ndarray:
    cols = [f"{f}.{i}" for f in T.STATE_FIELDS for i in range(3)]
    return df[cols].to_numpy(dtype=float)[:n]


# the topics a RunData is built from; read_log decodes only these
RUN_TOPICS = (
    T.STATE,
    T.STATE_MEASURED,
    T.REFERENCE,
    T.COST,
    T.MPC_STATS,
    T.CONSTRAINTS,
    T.CONTACT,
    T.FORCES,
    T.MARKERS,
)


def load_run(path: str | Path) -> RunData:
    path = Path(path)
    log: Log = read_log(path, RUN_TOPICS)
    n = min(len(log.topics.get(topic, [])) for topic in RUN_TOPICS)
    if n == 0:
        what = "was cut off before its first whole chunk" if log.truncated else "holds no MPC step"
        raise UserError(f"{path}: the log {what}: there is nothing to rebuild tables and figures from")
    stats = log[T.MPC_STATS].iloc[:n].reset_index(drop=True)
    cons = log[T.CONSTRAINTS].iloc[:n].reset_index(drop=True)
    forces = log[T.FORCES][[f"applied.{i}.{j}" for i in range(4) for j in range(3)]].to_numpy(float)[:n]
    return RunData(
        path=path,
        run=dict(log.metadata.get("run", {})),
        summary=dict(log.metadata.get("summary", {})),
        truncated=log.truncated,
        t=log[T.STATE]["t"].to_numpy(float)[:n],
        x=_states(log[T.STATE], n),
        x_meas=_states(log[T.STATE_MEASURED], n),
        x_ref=_states(log[T.REFERENCE], n),
        cost=log[T.COST]["stage"].to_numpy(float)[:n],
        stats=stats,
        violations=cons[[g for g in CONSTRAINT_GROUPS]],
        stance=log[T.CONTACT][[f"stance.{i}" for i in range(4)]].to_numpy(float)[:n] > 0.5,
        forces=forces.reshape(-1, 4, 3),
        markers=log[T.MARKERS].iloc[:n].reset_index(drop=True),
    )


def find_logs(run_dir: str | Path) -> list[Path]:
    """The MCAP logs of a run directory (``logs/*.mcap``), or the file itself."""
    run_dir = Path(run_dir)
    if run_dir.is_file():
        return [run_dir]
    return sorted((run_dir / "logs").glob("*.mcap"))
