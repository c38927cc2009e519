"""Batch throughput of the soft plant on a machine with only numpy, numba and scipy.

``slot bench leg`` measures the batch rows on this machine; a many-core node (a
cluster's, a lent accelerator host's) may lack the project's CLI environment (Hydra,
the QP solvers). This script runs the same measurement (:mod:`slotexp.bench._batch`)
there from the package's source and a pickled config:

    # here, with the project installed: write the config
    python scripts/batch_throughput.py save batch_cfg.pkl plant=cosserat
    # there (PyYAML on the path; psutil is not needed):
    PYTHONPATH=. python3 scripts/batch_throughput.py run batch_cfg.pkl --sizes 1 8 16 64 128 --out batch.json

``run`` writes one JSON object: the machine (cores, numba threads, Python), the
config's step, the numba compile-or-load time, and one row per batch size.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def save(path: Path, overrides: list[str]) -> None:
    import dataclasses

    from slotexp.cli import compose_config

    # The experiment's settings are left out: their classes live with the jobs, which need the log
    # and solver packages; the batch needs the robot, the plant, the gait library and the rates only.
    cfg = dataclasses.replace(compose_config(overrides), experiment=None)
    path.write_bytes(pickle.dumps(cfg))
    print(f"wrote {path} ({' '.join(overrides) or 'defaults'})")


def run(path: Path, sizes: tuple[int, ...], seconds: float, out: Path | None) -> None:
    import numba
    import numpy as np

    from slotexp.bench._batch import batch_throughput

    cfg = pickle.loads(path.read_bytes())
    start = time.perf_counter()
    batch_throughput(cfg, sizes=(1,), seconds=1.0 / cfg.mpc.rate_hz)  # compile or load every kernel
    compile_s = time.perf_counter() - start
    rows = []
    for r in batch_throughput(cfg, sizes=sizes, seconds=seconds):
        rows.append(
            {
                "robots": r.robots,
                "robot_seconds_per_wall_second": r.robot_seconds_per_wall_second,
                "one_after_another_robot_seconds_per_wall_second": r.one_after_another_robot_seconds_per_wall_second,
                "median_step_ms": float(np.median(r.step_wall_s)) * 1e3,
            }
        )
        print(
            f"B={r.robots:4d}  {r.robot_seconds_per_wall_second:8.1f} robot-s/s batched, "
            f"{r.one_after_another_robot_seconds_per_wall_second:6.1f} one after another",
            flush=True,
        )
    record = {
        "machine": {
            "cpu_count": os.cpu_count(),
            "numba_threads": numba.get_num_threads(),
            "python": platform.python_version(),
            "numba": numba.__version__,
            "processor": platform.processor() or platform.machine(),
        },
        "integrator": cfg.plant.integrator,
        "dt": cfg.sim.dt,
        "jacobian_age": cfg.plant.jacobian_age,
        "simulated_s_per_robot": seconds,
        "compile_or_load_s": compile_s,
        "rows": rows,
    }
    if out is not None:
        out.write_text(json.dumps(record, indent=1) + "\n")
    print(json.dumps(record["machine"]), f"compile or load {compile_s:.1f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="verb", required=True)
    s = sub.add_parser("save", help="pickle the config that Hydra composes from OVERRIDES")
    s.add_argument("path", type=Path)
    s.add_argument("overrides", nargs="*")
    r = sub.add_parser("run", help="measure batch throughput with a pickled config")
    r.add_argument("path", type=Path)
    r.add_argument("--sizes", type=int, nargs="+", default=[1, 8, 64])
    r.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per robot")
    r.add_argument("--out", type=Path)
    args = parser.parse_args()
    if args.verb == "save":
        save(args.path, args.overrides)
    else:
        run(args.path, tuple(args.sizes), args.seconds, args.out)


if __name__ == "__main__":
    main()
