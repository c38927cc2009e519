"""A whole run's config: the variants' own schemas and checks joined to the root's, and their names.

:mod:`slotexp.config` is a leaf: the root schema and the rules among its own fields.
The variants live above it, each beside its code and found by its registry: a plant
(``plant=<name>``), a controller, a QP backend (``solver=<name>``), an experiment. A
variant may declare, as class attributes,

- ``schema``: its settings, a subclass of the base (``PlantConfig``, ``ControllerConfig``,
  ``SolverConfig``) that its YAML composes with ``defaults: [<name>_schema, _self_]``
  (experiments: ``ExperimentClass.schema``, always);
- ``check(cfg)``: the rules it puts on the whole config (one :class:`ConfigError` line);
- capabilities the checks here read (a plant's ``free_space``).

So adding a plant, controller or backend with settings is one module plus its YAML:
nothing here or in ``config.py`` names it. This module checks the names against the
registries, that each composed section is its variant's schema, and runs the checks.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .config import ControllerConfig, PlantConfig, SlotConfig, SolverConfig, check_fields
from .configtree import CONF_DIR
from .errors import ConfigError, missing_extra
from .registry import Registry

__all__ = [
    "VARIANT_KINDS",
    "registry",
    "variant",
    "schema_of",
    "validate",
    "declared_schemas",
    "register_schemas",
    "config_from_yaml",
]

# config section -> the base schema of its variants
VARIANT_KINDS: dict[str, type] = {"plant": PlantConfig, "controller": ControllerConfig, "solver": SolverConfig}


def registry(kind: str) -> Registry:
    """The registry of ``kind`` (a key of :data:`VARIANT_KINDS`)."""
    if kind == "plant":
        from .plants import PLANTS

        return PLANTS
    if kind == "controller":
        from .controllers import CONTROLLERS

        return CONTROLLERS
    if kind == "solver":
        from .backends import BACKENDS

        return BACKENDS
    raise KeyError(kind)


def variant(kind: str, name: str) -> Any:
    """The class of variant ``name`` of ``kind``, its name first checked (one line naming the choices)."""
    reg = registry(kind)
    if name not in reg.names():
        raise ConfigError(f"{kind}.name = {name!r} is not supported: choose one of {', '.join(reg.names())}")
    try:
        return reg.get(name)
    except ModuleNotFoundError as exc:  # a variant of an optional extra (plant=rigid needs MuJoCo)
        raise missing_extra(exc) or exc from None


def schema_of(kind: str, name: str) -> type:
    """The settings of variant ``name``: its own ``schema``, or the kind's base."""
    return getattr(variant(kind, name), "schema", VARIANT_KINDS[kind])


def validate(cfg: SlotConfig) -> SlotConfig:
    """Every check of a composed config: the root's fields, each variant's name, schema and ``check``,
    the robot's model file, and the experiment's; raise :class:`ConfigError` (one line). Returns the config
    each variant's ``derive`` (if it has one) has made of it."""
    check_fields(cfg)
    classes = {kind: variant(kind, getattr(cfg, kind).name) for kind in VARIANT_KINDS}
    for kind, cls in classes.items():
        section = getattr(cfg, kind)
        if type(section) is not getattr(cls, "schema", VARIANT_KINDS[kind]):
            raise ConfigError(
                f"{kind}.name = {section.name!r} does not match the {kind}'s settings ({type(section).__name__}): "
                f"the name comes with {kind}=<name>; choose {kind}={section.name} instead of setting the name"
            )
    if not cfg.sim.ground and not getattr(classes["plant"], "free_space", False):
        raise ConfigError(
            f"sim.ground=false (free space) is not a setting plant={cfg.plant.name} has: use plant=cosserat or drop it"
        )
    if cfg.robot.rigid.model:
        from .rigid.model import read_spec  # the file must exist and parse before any work starts

        read_spec(cfg.robot.rigid)
    for cls in classes.values():
        check = getattr(cls, "check", None)
        if check is not None:
            check(cfg)
    _check_experiment(cfg)
    for cls in classes.values():  # what a variant makes of the rest (a schedule names and paces the run)
        derive = getattr(cls, "derive", None)
        if derive is not None:
            cfg = derive(cfg)
    return cfg


def _check_experiment(cfg: SlotConfig) -> None:
    exp = cfg.experiment
    if exp is None:
        from .jobs import run_names

        raise ConfigError(f"no experiment selected: pass experiment=<name>, one of {', '.join(run_names())}")
    from .jobs import EXPERIMENTS

    registered = EXPERIMENTS.get(exp.name).schema if exp.name in EXPERIMENTS.names() else None
    if registered is not None and not isinstance(exp, registered):
        raise ConfigError(
            f"experiment.name = {exp.name!r} does not match the experiment's settings ({type(exp).__name__}): "
            f"the name comes with experiment=<name>; choose experiment={exp.name} instead of setting the name"
        )
    check = getattr(exp, "check", None)
    if check is not None:
        check(cfg)


def declares_schema(yaml_file: Path, name: str) -> bool:
    """Whether a variant's YAML composes its own schema (``<name>_schema`` in its defaults list)."""
    import yaml

    try:
        text = yaml.safe_load(yaml_file.read_text()) if yaml_file.is_file() else None
    except yaml.YAMLError:
        return False  # composing it reports the file in one line
    defaults = text.get("defaults", []) if isinstance(text, dict) else []
    return f"{name}_schema" in (d for d in defaults if isinstance(d, str))


def declared_schemas(kind: str, conf_dir: Path | None = None) -> dict[str, type]:
    """The schemas of ``kind``'s variants that declare their own (by name), and the base under ``""``."""
    conf_dir = conf_dir or CONF_DIR
    found = {"": VARIANT_KINDS[kind]}
    for name in registry(kind).names():
        if declares_schema(conf_dir / kind / f"{name}.yaml", name):
            found[name] = schema_of(kind, name)
    return found


def register_schemas(conf_dir: Path | None = None) -> None:
    """Register the root schema, every experiment's, and every variant schema a YAML in ``conf_dir`` composes,
    with Hydra's ConfigStore (the CLI and the tests' composition call it; only the variants that declare a
    schema are imported, so a backend's solver library is not loaded to start a run that does not use it)."""
    from hydra.core.config_store import ConfigStore

    from .jobs import EXPERIMENTS

    cs = ConfigStore.instance()
    cs.store(name="slot_schema", node=SlotConfig)
    for name, experiment in EXPERIMENTS.load_all().items():
        cs.store(group="experiment", name=f"{name}_schema", node=experiment.schema)
    for kind in VARIANT_KINDS:
        for name, schema in declared_schemas(kind, conf_dir).items():
            if name:
                cs.store(group=kind, name=f"{name}_schema", node=schema, package=kind)


def config_from_yaml(text: str, experiment_schema: type, root: type | None = None) -> SlotConfig:
    """The typed config a run stored in its log (resolved YAML), checked again.

    ``root`` is the root schema (:class:`SlotConfig` unless the run was a hardware run).
    A log whose config no longer fits the schema (written by another version) is
    reported as a :class:`ConfigError`.
    """
    import yaml
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    root = root or SlotConfig
    try:
        stored = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}: {getattr(exc, 'problem', '')})" if mark is not None else ""
        raise ConfigError(
            f"the config stored in this log is not valid YAML{where}: the log's metadata is damaged; "
            "rerun the experiment"
        ) from None
    if not isinstance(stored, dict):
        raise ConfigError("the config stored in this log is not a mapping: the log's metadata is damaged; rerun it")
    sections = {}
    for kind, base in VARIANT_KINDS.items():  # each variant's section as its own schema
        section = stored.get(kind)
        name = section.get("name", base.name) if isinstance(section, dict) else base.name
        try:
            sections[kind] = schema_of(kind, name)()
        except ConfigError as exc:
            raise ConfigError(f"the config stored in this log names a {kind} this version lacks ({exc})") from None
    base = OmegaConf.structured(root(experiment=experiment_schema(), **sections))
    try:  # OmegaConf's own YAML reading (its floats: 1e-4 is a number to it, a string to PyYAML)
        return validate(OmegaConf.to_object(OmegaConf.merge(base, OmegaConf.create(text))))
    except OmegaConfBaseException as exc:
        raise ConfigError(
            f"the config stored in this log does not fit this version's schema "
            f"({str(exc).splitlines()[0]}): rerun it with this version"
        ) from None
