"""Regenerate everything committed under results/ with the project's own commands.

Each run writes to experiments/results/<name>/ (logs included, not committed);
the tables, figures and metrics are then copied to results/<name>/. Wall times
are written to results/timing.json.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SLOT = str(Path(sys.executable).parent / "slot")
KEEP = ("*.csv", "*.md", "*.png", "metrics.json")

RUNS = {
    # Paper Table I, Figs. 7-8 on the ideal plant with the default solver.
    "perturb": ["experiment=perturb"],
    # The paper's solver stack: CVXPY + SCS.
    "perturb_scs": ["experiment=perturb", "solver=scs"],
    # OSQP through CVXPY, for comparison.
    "perturb_osqp": ["experiment=perturb", "solver=osqp"],
    # The paper's strict force balance, eq. (9): sum f_z = m g exactly.
    "perturb_strict_balance": ["experiment=perturb", "mpc.force_balance_band=0"],
    # Paper Figs. 4 and 6.
    "simulate_walk": ["experiment=simulate", "gait=walk"],
    "simulate_crawl": ["experiment=simulate", "gait=crawl"],
    "simulate_omni60": ["experiment=simulate", "gait=omni60"],
}


def main(names: list[str]) -> None:
    timing_path = ROOT / "results" / "timing.json"
    timing = json.loads(timing_path.read_text()) if timing_path.exists() else {}
    for name in names or list(RUNS):
        run_dir = ROOT / "experiments" / "results" / name
        shutil.rmtree(run_dir, ignore_errors=True)
        print(f"== {name}: slot run {' '.join(RUNS[name])}", flush=True)
        start = time.perf_counter()
        subprocess.run([SLOT, "run", *RUNS[name], f"hydra.run.dir={run_dir}"], cwd=ROOT, check=True)
        timing[name] = {"wall_s": round(time.perf_counter() - start, 1), "args": RUNS[name]}
        dest = ROOT / "results" / name
        shutil.rmtree(dest, ignore_errors=True)
        dest.mkdir(parents=True)
        for pattern in KEEP:
            for f in run_dir.glob(pattern):
                shutil.copy2(f, dest / f.name)
    timing_path.write_text(json.dumps(timing, indent=2) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])
