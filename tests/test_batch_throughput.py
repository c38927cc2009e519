"""The batch measurement runs where only the numerical core is installed (a many-core node)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ABSENT = ("hydra", "omegaconf", "osqp", "clarabel", "daqp", "cvxpy", "scs", "psutil", "orjson", "mcap", "matplotlib")

# A process in which the project's CLI, log and solver packages cannot be imported: reads the pickled config
# and imports the measurement, as on a node that has numpy, numba, scipy and PyYAML only.
WITHOUT = f"""
import importlib.abc, pickle, sys
class Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {ABSENT!r}:
            raise ModuleNotFoundError(f"{{name}} is not installed on the node")
sys.meta_path.insert(0, Absent())
cfg = pickle.loads(open(sys.argv[1], "rb").read())
from slotexp.bench._batch import batch_throughput
print(cfg.plant.integrator, cfg.sim.dt, cfg.experiment)
"""


def test_a_pickled_config_and_the_batch_measurement_load_without_the_cli_solvers_or_logs(tmp_path: Path) -> None:
    cfg = tmp_path / "batch_cfg.pkl"
    save = [sys.executable, str(REPO / "scripts" / "batch_throughput.py"), "save", str(cfg), "plant=cosserat"]
    subprocess.run([*save, "sim.dt=1e-4"], check=True, capture_output=True, cwd=tmp_path)
    proc = subprocess.run([sys.executable, "-c", WITHOUT, str(cfg)], capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["implicit", "0.0001", "None"]
