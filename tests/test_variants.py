"""A plant, controller or QP backend with settings of its own is one module plus its YAML.

Each test adds a variant from a temporary package (a directory put on the registry
package's search path) and a YAML in a copy of the config tree, touching no file of
slotexp: its settings compose through Hydra onto the schema it declares, their
ranges and its own ``check`` refuse bad values in one line, and the run uses it.
"""

from __future__ import annotations

import shutil
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import HydraException
from omegaconf import OmegaConf

import slotexp.backends
import slotexp.controllers
import slotexp.plants
from slotexp.composition import register_schemas, validate
from slotexp.errors import ConfigError
from tests.helpers import CONF

PACKAGES = {"plant": slotexp.plants, "controller": slotexp.controllers, "solver": slotexp.backends}


def add_variant(tmp_path: Path, monkeypatch, kind: str, name: str, module: str, yaml: str) -> Path:
    """``module`` as ``slotexp.<package>.<name>`` from a temporary directory, ``yaml`` as
    ``conf/<kind>/<name>.yaml`` in a copy of the config tree; returns that tree."""
    package = tmp_path / "package"
    package.mkdir()
    (package / f"{name}.py").write_text(textwrap.dedent(module))
    monkeypatch.setattr(PACKAGES[kind], "__path__", [*PACKAGES[kind].__path__, str(package)])
    conf = tmp_path / "conf"
    shutil.copytree(CONF, conf)
    (conf / kind / f"{name}.yaml").write_text(textwrap.dedent(yaml))
    register_schemas(conf)
    return conf


def load_from(conf: Path, *overrides: str):
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        return validate(OmegaConf.to_object(compose("config", overrides=list(overrides))))


DRAGGED = '''
    """A test plant: the ideal plant with viscous drag on the torso's horizontal velocity."""
    from dataclasses import dataclass
    from typing import ClassVar

    import numpy as np

    from slotexp.config import PlantConfig, num_field
    from slotexp.errors import ConfigError
    from slotexp.plants import PLANTS
    from slotexp.plants.ideal import IdealPlant


    @dataclass
    class DraggedConfig(PlantConfig):
        name: str = "dragged"
        drag: float = num_field(0.0, lo=0.0, unit="N s/m")


    @PLANTS.register()
    class DraggedPlant(IdealPlant):
        schema: ClassVar[type] = DraggedConfig

        @staticmethod
        def check(cfg):
            if cfg.plant.drag * cfg.sim.dt > 0.5 * cfg.robot.torso.mass:
                raise ConfigError(f"plant.drag = {cfg.plant.drag:g} N s/m is too high for sim.dt: lower either")

        @classmethod
        def from_config(cls, cfg, robot, x0):
            plant = super().from_config(cfg, robot, x0)
            plant.drag = cfg.plant.drag
            return plant

        def step(self, command, period, external_force=None):
            base = np.zeros(3) if external_force is None else np.asarray(external_force, float)
            n = max(1, int(round(period / self.dt)))
            for _ in range(n):  # the drag explicit over each of the period's n steps
                velocity = self.state()[9:12]
                drag = -self.drag * np.array([velocity[0], velocity[1], 0.0])
                super().step(command, period / n, base + drag)
'''


def test_a_plant_with_settings_is_one_module_and_its_yaml(tmp_path, monkeypatch):
    from slotexp.plants import ForceCommand, make_plant, nominal_state
    from slotexp.robot import build_robot

    conf = add_variant(
        tmp_path,
        monkeypatch,
        "plant",
        "dragged",
        DRAGGED,
        """\
        # @package _global_
        defaults:
          - dragged_schema
          - _self_
        plant:
          name: dragged
          drag: 2.0
        sim:
          dt: 0.001
        """,
    )
    cfg = load_from(conf, "plant=dragged")
    assert type(cfg.plant).__name__ == "DraggedConfig" and cfg.plant.drag == 2.0
    assert load_from(conf, "plant=dragged", "plant.drag=3").plant.drag == 3.0
    with pytest.raises(ConfigError, match=r"plant.drag = -1.* out of range: must be >= 0"):
        load_from(conf, "plant=dragged", "plant.drag=-1")
    with pytest.raises(ConfigError, match="too high for sim.dt"):  # the plant's own check
        load_from(conf, "plant=dragged", "plant.drag=5000")
    with pytest.raises(HydraException, match="plant.drag"):  # not a setting of the default plant
        load_from(conf, "plant.drag=1")
    # the run uses it: a coasting torso, its weight carried, slows as v0 exp(-c t / m)
    robot = build_robot(cfg.robot)
    x0 = nominal_state(robot)
    x0[9] = 0.1
    plant = make_plant(cfg, robot, x0)
    weight = np.tile([0.0, 0.0, robot.mass * cfg.sim.gravity / 4.0], (4, 1))
    for _ in range(30):
        plant.step(ForceCommand(weight), 1.0 / 30.0)
    assert plant.state()[9] == pytest.approx(0.1 * np.exp(-2.0 * 1.0 / robot.mass), rel=2e-3)


HELD = '''
    """A test controller: the paper's, with every tendon command raised by a fixed angle."""
    from dataclasses import dataclass, replace
    from typing import ClassVar

    from slotexp.config import ControllerConfig, num_field
    from slotexp.controllers import CONTROLLERS
    from slotexp.controllers.paper import PaperController
    from slotexp.errors import ConfigError


    @dataclass
    class RaisedConfig(ControllerConfig):
        name: str = "raised"
        raise_deg: float = num_field(0.0, lo=0.0, hi=90.0, unit="deg")


    @CONTROLLERS.register()
    class RaisedController(PaperController):
        schema: ClassVar[type] = RaisedConfig

        @staticmethod
        def check(cfg):
            if cfg.plant.name == "rigid":
                raise ConfigError("controller=raised drives tendons: use plant=ideal or plant=cosserat")

        def step(self, t, x, feet):
            out = super().step(t, x, feet)
            return replace(out, tendon_deg=out.tendon_deg + self.cfg.controller.raise_deg)
'''


def test_a_controller_with_settings_is_one_module_and_its_yaml(tmp_path, monkeypatch):
    from slotexp.controllers import make_controller
    from slotexp.plants import nominal_state
    from slotexp.robot import build_robot

    conf = add_variant(
        tmp_path,
        monkeypatch,
        "controller",
        "raised",
        HELD,
        """\
        # @package _global_
        defaults:
          - raised_schema
          - _self_
        controller:
          name: raised
          raise_deg: 5.0
        """,
    )
    cfg = load_from(conf, "controller=raised", "controller.raise_deg=7.5")
    assert type(cfg.controller).__name__ == "RaisedConfig" and cfg.controller.raise_deg == 7.5
    with pytest.raises(ConfigError, match=r"controller.raise_deg = 120.* out of range"):
        load_from(conf, "controller=raised", "controller.raise_deg=120")
    paper = load_from(conf)
    robot = build_robot(cfg.robot)
    x0 = nominal_state(robot)
    feet = robot.feet_body + x0[3:6]
    raised = make_controller(cfg, robot).step(0.0, x0, feet).tendon_deg
    plain = make_controller(paper, robot).step(0.0, x0, feet).tendon_deg
    np.testing.assert_allclose(raised - plain, 7.5, atol=1e-9)


TIGHT = '''
    """A test backend: DAQP with its constraint tolerance set in units of the default."""
    from dataclasses import dataclass, replace
    from typing import ClassVar

    from slotexp.backends import BACKENDS
    from slotexp.backends.daqp import CondensedMpc
    from slotexp.config import SolverConfig, num_field


    @dataclass
    class TightConfig(SolverConfig):
        name: str = "tight"
        tolerance_factor: float = num_field(1.0, lo=0.0, lo_open=True, hi=1.0, unit="")


    @BACKENDS.register()
    class TightMpc(CondensedMpc):
        schema: ClassVar[type] = TightConfig

        def __init__(self, cfg_mpc, cfg_solver, *args):
            tight = replace(cfg_solver, eps_abs=cfg_solver.eps_abs * cfg_solver.tolerance_factor)
            super().__init__(cfg_mpc, tight, *args)
            self.tolerance = tight.eps_abs
'''


def test_a_backend_with_settings_is_one_module_and_its_yaml(tmp_path, monkeypatch):
    from slotexp.backends import make_mpc
    from slotexp.robot import build_robot

    conf = add_variant(
        tmp_path,
        monkeypatch,
        "solver",
        "tight",
        TIGHT,
        """\
        defaults:
          - tight_schema
          - _self_
        name: tight
        eps_abs: 1.0e-6
        tolerance_factor: 0.1
        """,
    )
    cfg = load_from(conf, "solver=tight")
    assert type(cfg.solver).__name__ == "TightConfig" and cfg.solver.tolerance_factor == 0.1
    with pytest.raises(ConfigError, match=r"solver.tolerance_factor = 2.* out of range"):
        load_from(conf, "solver=tight", "solver.tolerance_factor=2")
    robot = build_robot(cfg.robot)
    mpc = make_mpc(cfg.mpc, cfg.solver, robot.mass, robot.inertia_body, cfg.sim.gravity)
    assert mpc.tolerance == pytest.approx(1e-7)


@pytest.mark.parametrize(
    "overrides, words",
    [
        # the plant comes from the default: the message names the plant that has the setting
        (
            ["plant.integrator=symplectic"],
            ["plant.integrator is a setting of plant=cosserat, which this run does not use", "choose plant=cosserat"],
        ),
        # the controller is chosen: the message says it lacks the setting
        (
            ["plant=cosserat", "controller=paper", "controller.blend=cycles"],
            ["controller=gait_mpc or controller=open_loop, not of controller=paper"],
        ),
        (["plant=cosserat", "plant.integrater=implicit"], ["did you mean plant.integrator?"]),
        (["plant.name=cosserat"], ["choose plant=cosserat instead of setting the name"]),
    ],
)
def test_a_setting_of_another_variant_is_one_line_naming_the_variant_that_has_it(tmp_path, overrides, words):
    from tests.helpers import slot

    proc = slot("run", "experiment=simulate", *overrides, f"hydra.run.dir={tmp_path / 'x'}", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for word in words:
        assert word in errors[0], errors[0]
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    "overrides",
    [("plant=cosserat",), ("plant=cosserat", "controller=schedule", "mpc.rate_hz=50"), ("experiment=simulate",)],
)
def test_a_stored_config_reads_back_with_each_variants_own_settings(overrides):
    """What a log stores (the resolved YAML) reads back to the same typed config, variant schemas included."""
    from slotexp.composition import config_from_yaml
    from slotexp.jobs import EXPERIMENTS
    from tests.helpers import load

    cfg = load(*overrides, "plant.jacobian_age=7" if "plant=cosserat" in overrides else "sim.seed=3")
    text = OmegaConf.to_yaml(OmegaConf.structured(cfg))
    back = config_from_yaml(text, EXPERIMENTS.get(cfg.experiment.name).schema)
    assert back == cfg
    assert type(back.plant) is type(cfg.plant) and type(back.controller) is type(cfg.controller)


def test_a_setting_every_variant_has_passes_the_override_check_with_no_variant_chosen():
    """``solver.time_limit_s`` is the base's: no variant is named, and none need be."""
    from slotexp.cli import _variant_key_problem
    from slotexp.config import SlotConfig

    assert _variant_key_problem("solver.time_limit_s", SlotConfig, {}, "solver", None) is None
    assert _variant_key_problem("plant.name", SlotConfig, {}, "plant", None) is None
    assert "did you mean solver.time_limit_s" in _variant_key_problem(
        "solver.time_limt_s", SlotConfig, {}, "solver", None
    )


@pytest.mark.parametrize(
    "registry",
    ["slotexp.plants:PLANTS", "slotexp.controllers:CONTROLLERS", "slotexp.backends:BACKENDS",
     "slotexp.jobs:EXPERIMENTS", "slotexp.bench:COMPONENTS"],
)  # fmt: skip
def test_every_module_a_registry_lists_defines_its_variant(registry: str) -> None:
    """A module in a registry's package that is not a variant (shared code) must start with ``_``: otherwise
    the CLI offers it as a choice and ``slot bench`` with no names, which runs every component, fails on it."""
    import importlib

    module, name = registry.split(":")
    variants = getattr(importlib.import_module(module), name)
    assert set(variants.load_all()) == set(variants.names())
