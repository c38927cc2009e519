"""Experiment ``leg``: one clamped leg under ``leg_load``, run to equilibrium."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..atomic import write_json
from ..config import SlotConfig
from ..errors import ConfigError
from ..record import Recorder
from ..soft.statics import clamped_leg, settle
from . import EXPERIMENTS, Experiment
from ._logged import git_commit


def check_leg_load(cfg: SlotConfig) -> None:
    """The clamped-leg experiments step the leg with ``leg_load.integrator``: the paper's model has no Jacobian."""
    if cfg.robot.leg.model == "paper" and cfg.leg_load.integrator != "symplectic":
        raise ConfigError(
            "robot.leg.model=paper has no Jacobian for the implicit step: add "
            "leg_load.integrator=symplectic leg_load.dt=2e-5"
        )


@dataclass
class LegExperiment:
    """Static response of one clamped leg to ``leg_load``: tip position and angle."""

    name: str = "leg"

    def check(self, cfg: SlotConfig) -> None:
        check_leg_load(cfg)


def run(cfg: SlotConfig, out_dir: Path, resolved_yaml: str) -> None:
    sim = clamped_leg(cfg)
    result = settle(sim, cfg)
    load = cfg.leg_load
    result.update(
        {
            "tip_force_n": list(load.tip_force),
            "tip_moment_nm": load.tip_moment,
            "tendon_deg": load.tendon_deg,
            "ground": load.ground,
            "n_nodes": sim.model.n_nodes,
        }
    )
    write_json(out_dir / "leg.json", result)
    (out_dir / "logs").mkdir(parents=True, exist_ok=True)
    meta = {"config": {"yaml": resolved_yaml}, "run": {"experiment": "leg", "git_commit": git_commit()}}
    with Recorder(out_dir / "logs" / "leg.mcap", metadata=meta) as rec:
        rec.write(
            "/leg/equilibrium",
            sim.time,
            {"rest": sim.model.rest_pos, "shape": sim.pos, **{k: v for k, v in result.items() if isinstance(v, float)}},
        )
    report(out_dir, cfg)


def report(out_dir: Path, cfg: SlotConfig | None = None) -> None:
    """The deformed shape against the rest shape, from the log (the load is read from its stored config)."""
    from ..figures.leg import plot_leg
    from ..record import read_log

    log = read_log(out_dir / "logs" / "leg.mcap")
    row = log["/leg/equilibrium"].iloc[-1]
    n = len([c for c in row.index if c.startswith("shape.") and c.endswith(".0")])
    shape = row[[f"shape.{i}.{j}" for i in range(n) for j in range(2)]].to_numpy(float).reshape(n, 2)
    rest = row[[f"rest.{i}.{j}" for i in range(n) for j in range(2)]].to_numpy(float).reshape(n, 2)
    import yaml

    conf = yaml.safe_load(log.metadata["config"]["yaml"])
    load = conf["leg_load"]
    title = (
        f"tip force {load['tip_force']} N, moment {load['tip_moment']} N m, tendon {load['tendon_deg']} deg: "
        f"tip ({1e3 * row['tip_x']:.1f}, {1e3 * row['tip_z']:.1f}) mm"
    )
    plot_leg(rest, shape, out_dir / "fig_leg.png", title, ground=bool(load["ground"]))


EXPERIMENTS.add("leg", Experiment(LegExperiment, run, report))
