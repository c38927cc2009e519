"""The ``slot`` command line: parse, check, dispatch. No physics here.

``slot run`` hands its arguments to Hydra unchanged (overrides, ``-m`` multirun,
``--cfg job``, ``hydra.run.dir=...``). Before Hydra starts, every override (and
every value of a sweep) is composed and checked against the typed schema, so a
bad value stops the run with one line and exit status 2 instead of a traceback
from inside a job.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import functools
import itertools
import logging
import os
import signal
import sys
import tempfile
import time
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import typer

from .composition import validate
from .configtree import CONF_DIR
from .errors import UserError, missing_extra

GROUPS = (
    "robot", "gait", "solver", "plant", "controller", "library", "experiment", "scenario", "actuation", "schedule",
)  # fmt: skip
HARDWARE_GROUPS = ("robot", "gait", "solver", "actuation", "plant", "controller", "library", "hardware", "odometry")
HARDWARE_CONFIG = "hardware_config"
HELP_FLAGS = {"--hydra-help", "--help", "-h", "--shell-completion", "-sc"}
VALUE_FLAGS = {
    "--cfg",
    "-c",
    "--package",
    "-p",
    "--config-path",
    "-cp",
    "--config-name",
    "-cn",
    "--config-dir",
    "-cd",
    "--experimental-rerun",
    "--info",
    "-i",
}
MAX_PRECHECK = 256
EXIT_USER_ERROR = 2

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help=(
        "slotexp: reproduce and extend the SLOT soft-quadruped convex-MPC paper.\n\n"
        "  slot run experiment=perturb            Table I, Figs. 7-8\n\n"
        "  slot run experiment=simulate gait=omni60\n\n"
        "  slot run -m experiment=perturb solver=scs,osqp,clarabel\n\n"
        "  slot figures experiments/perturb/<timestamp>"
    ),
)


def fail(message: str) -> None:
    typer.echo(f"error: {message}", err=True)
    raise SystemExit(EXIT_USER_ERROR)


def check_output_dir(path: str | Path, what: str) -> None:
    """Fail with one line, before any work, if ``path`` cannot be an output directory: it is empty or a
    file, or nothing can be created in it or in its first existing ancestor (tried, then removed)."""
    if str(path).strip() == "":
        fail(f"{what} is empty: give a directory")
    path = Path(path)
    if path.exists() and not path.is_dir():
        fail(f"{what} = {path} is a file, not a directory: give a directory")
    ancestor = path.absolute()
    while not ancestor.exists():
        ancestor = ancestor.parent
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".slot-write-check-", dir=ancestor))
    except OSError:
        fail(f"{what} = {path}: cannot create anything in {ancestor}: choose a directory you can write to")


def _check_hydra_dirs(overrides: list[str]) -> None:
    """``hydra.run.dir`` / ``hydra.sweep.dir`` and the launcher's job count given on the command line: checked
    before Hydra starts."""
    for key in ("hydra.run.dir", "hydra.sweep.dir"):
        value = _override_value(overrides, key)
        if value is not None:
            check_output_dir(value, key)
    jobs = _override_value(overrides, "hydra.launcher.n_jobs")
    if jobs is not None and jobs.lstrip("-").isdigit() and int(jobs) == 0:
        fail("hydra.launcher.n_jobs=0 runs no job: give a count of parallel jobs (1, 2, ...) or -1 for every core")


def _overwrite(overrides: list[str]) -> bool:
    """Whether the overrides say ``overwrite=true`` (the root setting, read before Hydra composes anything)."""
    return (_override_value(overrides, "overwrite") or "false").lower() in ("true", "yes", "on", "1")


def _override_value(overrides: list[str], key: str) -> str | None:
    """The value the last ``key=...`` override gives (quotes removed), or None."""
    value = None
    for o in overrides:
        k, _, v = o.lstrip("+").partition("=")
        if k == key:
            value = v[1:-1] if len(v) >= 2 and v[0] == v[-1] and v[0] in "'\"" else v
    return value


PRINT_FLAGS = ("--cfg", "-c", "--info", "-i")  # Hydra prints the config or its setup and runs nothing


def _prints_only(args: list[str]) -> bool:
    """Whether Hydra is asked to print (``--cfg job``, ``--info``) rather than run: nothing is claimed then."""
    return any(a in PRINT_FLAGS or a.startswith(tuple(f"{f}=" for f in PRINT_FLAGS)) for a in args)


def _claim_run_dir(overrides: list[str], multirun: bool, config_name: str = "config") -> list[str]:
    """Before Hydra writes anything: resolve the directory it would write (``hydra.run.dir``, or with ``-m``
    ``hydra.sweep.dir``: the default or the one given, interpolations resolved), lock it, and refuse another
    process's or another run's (unless ``overwrite=true``: then set aside, :mod:`slotexp.rundir`). A default
    directory already taken gets a suffix. Returns the overrides that give Hydra exactly that directory."""
    from hydra import compose, initialize_config_dir
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    from .rundir import claim, unique

    key = "hydra.sweep.dir" if multirun else "hydra.run.dir"
    given = _override_value(overrides, key)
    plain = []  # the first job's settings: a sweep's directory is the sweep's, whatever each job sets
    for parsed in OverridesParser.create().parse_overrides(overrides):
        if parsed.is_sweep_override():
            plain.append(_override_text(parsed, next(iter(parsed.sweep_string_iterator()))))
        else:
            plain.append(parsed.input_line)
    register_schemas()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            cfg = compose(config_name, overrides=plain, return_hydra_config=True)
            directory = Path(str(OmegaConf.select(cfg, key)))
            subdir = OmegaConf.to_container(cfg.hydra.sweep, resolve=False).get("subdir", "")
    except (HydraException, OmegaConfBaseException) as exc:
        fail(f"{key}: cannot resolve the output directory ({_compose_message(exc)})")
    if multirun and "${" not in str(subdir):
        fail(
            f"hydra.sweep.subdir = {subdir!r} is the same for every job, so every job would write into one directory: "
            "include ${hydra.job.num}"
        )
    if given is None:
        directory = unique(directory)
    if "'" in str(directory):  # before anything is made there
        fail(f"{key} = {directory}: a directory name with a quote (') cannot be passed to Hydra: rename it")
    try:
        claim(directory, _overwrite(overrides), key, "sweep" if multirun else "run's outputs")
    except UserError as exc:
        fail(str(exc))
    return [o for o in overrides if o.lstrip("+").partition("=")[0] != key] + [f"{key}='{directory}'"]


def register_schemas() -> None:
    """Every schema the CLI's configs compose onto: ``slot run``'s and ``slot hardware``'s."""
    from .composition import register_schemas as register_run_schemas
    from .hardware.config import register_hardware_schemas

    register_run_schemas(CONF_DIR)
    register_hardware_schemas()


def group_options(group: str, search: tuple[Path, ...] = ()) -> list[str]:
    """A config group's options: the files in ``conf/<group>/`` and in each of ``search`` (a user's own config
    directories, ``hydra.searchpath=[file://DIR]``)."""
    return sorted({p.stem for root in (CONF_DIR, *search) for p in (Path(root) / group).glob("*.yaml")})


def _search_dirs(overrides: list[str]) -> tuple[Path, ...]:
    """The directories ``hydra.searchpath=[file://DIR, ...]`` adds to the config tree (pkg:// ones are packages')."""
    value = _override_value(overrides, "hydra.searchpath") or ""
    items = [v.strip().strip("'\"") for v in value.strip("[]").split(",") if v.strip()]
    return tuple(Path(v[len("file://") :]) for v in items if v.startswith("file://"))


def load_config(cfg) -> SlotConfig:  # noqa: F821 - forward ref to avoid importing at CLI start
    """DictConfig -> checked dataclasses."""
    from omegaconf import OmegaConf

    return validate(OmegaConf.to_object(cfg))


def _split(args: list[str]) -> tuple[list[str], bool, bool]:
    """(overrides, multirun, help_requested)."""
    overrides, multirun, info = [], False, False
    skip = False
    for a in args:
        if skip:
            skip = False
            if "=" not in a:  # a flag's value (e.g. --cfg job), not an override
                continue
        if a in ("-m", "--multirun"):
            multirun = True
        elif a.split("=")[0] in HELP_FLAGS:
            info = True
        elif a in VALUE_FLAGS:
            skip = True
        elif a.startswith("-"):
            continue
        else:
            overrides.append(a)
    return overrides, multirun, info


def unknown_key(key: str, root: type, sections: dict[str, type] | None = None) -> str | None:
    """The complaint for a dotted override key that names no field of the schema (with the closest field
    as a suggestion), or None when it names one or leads where the schema cannot tell (Any, a leaf).
    A dict accepts any key (scenario names), a list an index. ``sections`` gives the schema of a top-level
    section whose type the root leaves open or to a variant (``experiment``, ``plant``, ...)."""
    import dataclasses
    import difflib
    import typing

    tp: Any = root
    parts = key.split(".")
    for i, part in enumerate(parts):
        origin = typing.get_origin(tp)
        if origin is dict:
            tp = typing.get_args(tp)[1]
            continue
        if origin is list:
            if not part.isdigit():
                return None
            tp = typing.get_args(tp)[0]
            continue
        if not (isinstance(tp, type) and dataclasses.is_dataclass(tp)):
            return None
        hints = typing.get_type_hints(tp)
        if part not in hints:
            close = difflib.get_close_matches(part, list(hints), n=1)
            prefix = ".".join(parts[:i])
            if close:
                return f"unknown key {key} (did you mean {'.'.join([*parts[:i], close[0]])}?)"
            return f"unknown key {key}: {prefix or 'the config'} has {', '.join(sorted(hints))}"
        tp = (sections or {}).get(part, hints[part]) if i == 0 else hints[part]
        if typing.get_origin(tp) in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            tp = args[0] if len(args) == 1 else Any
    return None


def _override_text(o, value: str) -> str:
    key = o.key_or_group + (f"@{o.package}" if o.package else "")
    prefix = {"ADD": "+", "FORCE_ADD": "++", "DEL": "~"}.get(o.type.name, "")
    return f"{prefix}{key}={value}"


def yaml_error_line(exc: Exception) -> str:
    """One line for a YAML file that does not parse: which file, where, and what."""
    mark = getattr(exc, "problem_mark", None)
    where = f"{mark.name}, line {mark.line + 1}, column {mark.column + 1}" if mark is not None else "a config file"
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    return f"{where}: not valid YAML ({problem}): fix the file (or restore it from git)"


def precheck(
    overrides: list[str],
    multirun: bool,
    config_name: str = "config",
    groups: tuple[str, ...] = GROUPS,
    loader=None,
    root: type | None = None,
) -> None:
    """Compose and validate every combination the run would launch; fail with one line."""
    import yaml
    from hydra import compose, initialize_config_dir
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    parser = OverridesParser.create()
    every = []
    for o in overrides:
        if not o.strip():
            fail("an argument is empty (an empty '' on the command line?): remove it, or write key=value")
        if o.lstrip("+~").startswith("="):
            fail(f"{o!r} has no key: write key=value, e.g. mpc.horizon=10")
        key, _, value = o.partition("=")

        def parses(text: str) -> bool:
            try:
                parser.parse_override(text)
            except HydraException:
                return False
            return True

        quoted = f"{key}='{value}'"  # a suggestion is only made when it parses itself
        if not key.isascii() or not parses(f"{key}=0"):
            fail(f"{o}: {key!r} is not a setting's name: keys are ASCII names such as mpc.horizon (slot run --help)")
        if not value.isascii() and not (value.startswith(("'", '"')) and value.endswith(value[0])):
            hint = f'write "{quoted}"' if parses(quoted) else "write it in ASCII"
            fail(f"{o}: a value with non-ASCII characters must be quoted for Hydra: {hint}")
        try:  # one at a time, so that the message can name the one that does not parse
            every.append(parser.parse_override(o))
        except HydraException as exc:
            hint = f'quote the value, e.g. "{quoted}"' if parses(quoted) else "check its brackets and quotes"
            fail(f"cannot parse override {o!r} ({str(exc).splitlines()[0]}): {hint}")
    for p in every:
        if p.key_or_group.startswith("hydra") and p.is_sweep_override():
            fail(f"{p.input_line}: Hydra cannot sweep its own settings: give {p.key_or_group} one value")
    parsed = [p for p in every if not p.key_or_group.startswith("hydra")]
    choices: list[list[str]] = []
    _check_keys(parsed, groups, root)
    search = _search_dirs(overrides)  # the user's own config directories, if any (hydra.searchpath)
    searchpath = [o for o in overrides if o.startswith("hydra.searchpath")]
    for o in parsed:
        if o.is_sweep_override():
            if not multirun:
                fail(f"{o.input_line} is a sweep: add -m (multirun) to run every value")
            values = list(o.sweep_string_iterator())
        else:
            values = [o.get_value_element_as_str()] if not o.is_delete() or o.value() is not None else [""]
        group = o.key_or_group.split("@")[0]
        if group in groups:
            options = group_options(group, search)
            for v in values:
                if v not in options:
                    where = f"conf/{group}/" + "".join(f" or {d}/{group}/" for d in search)
                    fail(f"unknown {group} {v!r}: choose one of {', '.join(options)} (files in {where})")
        choices.append([_override_text(o, v) if not o.is_delete() else o.input_line for v in values])
    register_schemas()
    subdir_setting = next((o.input_line for o in every if o.key_or_group == "hydra.sweep.subdir"), None)
    named_by_overrides = subdir_setting is None or "override_dirname" in subdir_setting
    combos = itertools.islice(itertools.product(*choices), MAX_PRECHECK)
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        for number, combo in enumerate(combos):
            # a sweep's job directory is <number>_<its overrides, sorted and joined> (Hydra's override_dirname)
            subdir = f"{number}_" + ",".join(sorted(combo))
            if multirun and named_by_overrides and len(subdir.encode()) > 255:
                fail(
                    f"a sweep job's directory name would be {len(subdir.encode())} bytes, over the file system's 255 "
                    "(the job's overrides joined): shorten the values, or add 'hydra.sweep.subdir=${hydra.job.num}'"
                )
            try:
                cfg = compose(config_name, overrides=[*combo, *searchpath])
            except (HydraException, OmegaConfBaseException) as exc:
                fail(_variant_setting_message(exc) or _compose_message(exc))
            except yaml.YAMLError as exc:  # a config file that is not YAML (edited by hand, truncated)
                fail(yaml_error_line(exc))
            try:
                loaded = (loader or load_config)(cfg)
            except UserError as exc:
                fail(str(exc))
            except (OmegaConfBaseException, ValueError, TypeError) as exc:
                fail(_compose_message(exc))
            if multirun and loaded.live and loaded.live_port != 0:
                fail(
                    f"live=true on a sweep: its jobs run at once and only one can listen on port {loaded.live_port}: "
                    "add live_port=0 (each job picks a free port and prints it), or drop live=true"
                )
        hydra_settings = [p for p in every if p.key_or_group.startswith("hydra")]
        if hydra_settings:  # Hydra's own settings (launcher, run dir): composed with the first combination
            from hydra.conf import HydraConf

            for p in hydra_settings:
                key = p.key_or_group
                problem = unknown_key(key[len("hydra.") :], HydraConf) if key.startswith("hydra.") else None
                if problem:
                    fail(problem.replace("unknown key ", "unknown key hydra.").replace("mean ", "mean hydra."))
            first = next(iter(itertools.product(*choices)), ())
            try:
                compose(
                    config_name, overrides=[*first, *(p.input_line for p in hydra_settings)], return_hydra_config=True
                )
            except (HydraException, OmegaConfBaseException) as exc:
                fail(_compose_message(exc))


def _check_keys(parsed: list, groups: tuple[str, ...], root: type | None) -> None:
    """Every ``key=value`` and ``+key=value`` names a field of the schema (Hydra's own hint, "use
    +key=value", would add a key that nothing reads). A plant's, controller's or backend's setting is
    looked up in the variant the overrides choose, or, where they choose none, in any of its kind."""
    from .composition import VARIANT_KINDS
    from .config import SlotConfig
    from .jobs import EXPERIMENTS

    root = root or SlotConfig
    chosen = {
        o.key_or_group: o.value()
        for o in parsed
        if o.key_or_group in ("experiment", *VARIANT_KINDS) and isinstance(o.value(), str)
    }
    sections = {}
    if chosen.get("experiment") in EXPERIMENTS.names():
        sections["experiment"] = EXPERIMENTS.get(chosen["experiment"]).schema
    for o in parsed:
        key = o.key_or_group
        if "/" in key or key.split("@")[0] in groups or o.is_delete():
            continue
        head = key.split(".")[0]
        if head in VARIANT_KINDS and "." in key:
            problem = _variant_key_problem(key, root, sections, head, chosen.get(head))
        else:
            problem = unknown_key(key, root, sections)
        if problem:
            fail(problem)


def _key_problems(key: str, kind: str, root: type, sections: dict) -> dict[str, str | None]:
    """What :func:`unknown_key` says of ``key`` under each schema of ``kind``: the base's (under ``""``) and
    each variant's own (by name; :func:`slotexp.composition.declared_schemas`, read once)."""
    from .composition import declared_schemas

    return {name: unknown_key(key, root, {**sections, kind: s}) for name, s in declared_schemas(kind).items()}


def _having(problems: dict[str, str | None]) -> list[str]:
    """The variants whose own settings include the key :func:`_key_problems` was asked about."""
    return sorted(name for name, problem in problems.items() if name and problem is None)


def _setting_of(key: str, kind: str, having: list[str], this_run: str) -> str:
    """One line: ``key`` belongs to the variants ``having``, not to ``this_run``'s."""
    return (
        f"{key} is a setting of {' or '.join(f'{kind}={n}' for n in having)}, {this_run}: choose {kind}={having[0]}, "
        "or drop the setting"
    )


def _variant_key_problem(key: str, root: type, sections: dict, kind: str, chosen: str | None) -> str | None:
    """``key`` in a variant's section: a field of the chosen variant (or, none chosen, of some variant)."""
    problems = _key_problems(key, kind, root, sections)
    having = _having(problems)
    if chosen is None:
        if having or problems[""] is None:  # some variant's, to be decided by composing; or every variant's
            return None  # (_variant_setting_message words a refusal)
        return next((p for p in problems.values() if "did you mean" in p), problems[""])
    problem = problems.get(chosen, problems[""])  # a variant without its own schema has the base's settings
    if problem is None or not having:
        return problem
    return _setting_of(key, kind, having, f"not of {kind}={chosen}")


def _variant_setting_message(exc: BaseException) -> str | None:
    """One line for a plant's, controller's or backend's setting given to a run whose variant lacks it
    (the variant comes from a default or another group, so the overrides alone could not tell)."""
    import re

    from .composition import VARIANT_KINDS
    from .config import SlotConfig

    found = re.search(r"Could not override '([a-z_]+)\.([^']+)'", str(exc))
    if found is None or found.group(1) not in VARIANT_KINDS:
        return None
    kind, key = found.groups()
    having = _having(_key_problems(f"{kind}.{key}", kind, SlotConfig, {}))
    return _setting_of(f"{kind}.{key}", kind, having, "which this run does not use") if having else None


def _compose_message(exc: BaseException) -> str:
    """Hydra/OmegaConf errors are multi-line; keep the informative part on one line."""
    parts = [str(exc)]
    if exc.__cause__ is not None:
        parts.append(str(exc.__cause__))
    lines = [ln.strip() for p in parts for ln in p.splitlines() if ln.strip()]
    keep = [
        ln
        for ln in lines
        if not ln.startswith(("object_type", "full_key", "Set the environment", "Config search path", "provider="))
    ]
    text = "; ".join(dict.fromkeys(keep))
    return text.replace("Error merging override ", "bad override ")


def _fail_on_missing_extra(exc: ModuleNotFoundError) -> None:
    """One line naming the extra that installs a missing optional dependency; any other import error is a bug."""
    extra = missing_extra(exc)
    if extra is None:
        raise exc
    fail(str(extra))


def _hydra_task(cfg) -> None:
    """What Hydra runs for each job: check, run the experiment, print the output dir last."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from .controllers._gait import envelope_warning
    from .jobs import EXPERIMENTS, run_experiment
    from .rundir import finish, replaced
    from .signals import die_with_parent, is_sweep_worker

    if is_sweep_worker():
        die_with_parent()  # a sweep's job ends with its parent, SIGKILL included
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    aside = replaced(out_dir)
    if aside is not None:
        atexit.register(_kept_note, out_dir)  # says where they are, unless the run succeeds
    try:
        with _one_line_failures(out_dir):
            checked = load_config(cfg)
            experiment = EXPERIMENTS.get(checked.experiment.name)
            warning = envelope_warning(checked) if experiment.walks_gait else None
            if warning is not None:
                typer.echo(f"warning: {warning}", err=True)
            started = time.monotonic()
            run_experiment(checked, out_dir, OmegaConf.to_yaml(cfg))
            summary = []
            if experiment.summary is not None and (out_dir / experiment.summary).is_file():
                summary.append((out_dir / experiment.summary).read_text().rstrip())
            finish(out_dir)  # an overwritten run's outputs go only now
            _say(*summary, f"done in {time.monotonic() - started:.0f} s; outputs in:", str(out_dir), out_dir=out_dir)
            return
    except KeyboardInterrupt as exc:
        signum, word = _stopped_by(exc)
        typer.echo(f"{word}: the logs written so far are valid and readable in {out_dir}", err=True)
        typer.echo(str(out_dir))
        if is_sweep_worker():  # the log is closed: end the job process, which the sweep's parent waits for
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(128 + signum)
        raise SystemExit(128 + signum) from None


def _kept_note(out_dir: Path) -> None:
    """At exit: a run that overwrote another and did not succeed says where the earlier outputs are kept."""
    from .rundir import replaced

    aside = replaced(out_dir)
    if aside is not None:
        with contextlib.suppress(OSError):
            sys.stderr.write(f"note: the outputs this run was to replace are kept in {aside}\n")


@contextmanager
def _one_line_failures(out_dir: Path) -> Iterator[None]:
    """What a run's user can fix ends in one line and exit 2: bad input (:class:`UserError`), a missing
    optional dependency, a write the file system refused. Anything else keeps its traceback."""
    try:
        yield
    except UserError as exc:
        fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    except ModuleNotFoundError as exc:
        _fail_on_missing_extra(exc)
    except OSError as exc:
        _fail_on_storage(exc, out_dir)


# the file system refusing a write: full, over quota, read-only, not permitted
_STORAGE_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM}


def _fail_on_storage(exc: OSError, out_dir: Path | None) -> None:
    """One line for a write the file system refused (a full disk, a quota, a read-only mount); any other
    OSError is a bug and keeps its traceback. What was written before it (the logs first) stays."""
    if exc.errno not in _STORAGE_ERRORS:
        raise exc
    where = f"{exc.filename}: " if exc.filename else ""
    kept = (
        f"; what was written before it is in {out_dir} (slot figures rebuilds the rest from its logs)"
        if out_dir
        else ""
    )
    elsewhere = " (hydra.run.dir=...)" if out_dir else ""  # outside a run: the command's own output option
    fail(f"{where}{exc.strerror or exc}: free space or write elsewhere{elsewhere}{kept}")


def _say(*lines: str, out_dir: Path | None = None) -> None:
    """Print a command's result on stdout. A reader that closed it (``| head -1``) gets what it read; the
    rest is dropped, and one line on stderr says where the outputs are (they are complete)."""
    try:
        for line in lines:
            typer.echo(line)
        sys.stdout.flush()
    except BrokenPipeError:
        _closed_stdout(out_dir)


def _closed_stdout(out_dir: Path | None) -> None:
    # later writes (and the interpreter's last flush) go nowhere instead of raising again
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    where = f": its outputs are complete in {out_dir}" if out_dir is not None else ""
    fail(f"stdout was closed before the command's last lines{where}")


def _run_help() -> str:
    """``slot run --help``, its lists of choices read from the config tree itself (they follow the files)."""
    groups = sorted(p for p in CONF_DIR.iterdir() if p.is_dir() and not p.name.startswith(("_", ".")))

    def names(group: Path) -> str:
        return ", ".join(sorted(p.stem for p in group.glob("*.yaml")))

    keyed = {  # groups composed under a key of their own, and an override that reaches into one
        "scenario": "scenarios.<name> (e.g. scenarios.roll.offset.roll=0.2)",
        "schedule": "schedules.<name> (e.g. schedules.forward.step_s=0.5)",
    }
    hardware_only = ("hardware", "odometry")  # slot hardware's groups
    lines = [f"{g.name}: {names(g)}" for g in groups if g.name not in keyed and g.name not in hardware_only]
    lines += [f"{keyed[g.name]}: {names(g)}" for g in groups if g.name in keyed]
    return (
        "Run an experiment. Arguments are Hydra overrides, e.g. experiment=perturb gait=walk solver=scs.\n\n"
        + "Config groups and their choices (conf/):\n\n"
        + "\n\n".join(lines)
        + "\n\ncontroller=schedule plays one of the schedules (controller.schedule=<name>). Use -m for a "
        "multirun sweep (a,b,c values), --cfg job to print the composed config, hydra.run.dir=DIR to choose "
        "the output directory, live=true to stream the run to Foxglove as well (ws://127.0.0.1:8765; "
        "live_port=N to change it)."
    )


class _DropJoblibSettings(logging.Filter):
    """Drops the joblib launcher's line of pool settings (Joblib.Parallel(n_jobs=..., backend=..., ...)): the
    sweep's own lines (its output directory, one per job) say what a user needs."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Joblib.Parallel(")


def _quiet_joblib_settings() -> None:
    logging.getLogger("hydra_plugins.hydra_joblib_launcher._core").addFilter(_DropJoblibSettings())


@app.command(
    context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": ["--help"]},
    help=_run_help(),
)
def run(ctx: typer.Context) -> None:
    """Run an experiment (its help is built from the config tree: :func:`_run_help`)."""
    import hydra

    args = list(ctx.args)
    overrides, multirun, info = _split(args)
    if not info:
        precheck(overrides, multirun)
        _check_hydra_dirs(overrides)
        if not _prints_only(args):
            claimed = _claim_run_dir(overrides, multirun)
            args = [a for a in args if a not in overrides] + claimed
    if multirun:
        from .signals import become_sweep_parent

        become_sweep_parent()
        _quiet_joblib_settings()
    register_schemas()
    sys.argv = ["slot", *args]
    main_fn = hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")(_hydra_task)
    try:
        main_fn()
        if multirun and not info and not _prints_only(args):
            from .rundir import finish

            finish(Path(_override_value(claimed, "hydra.sweep.dir") or "."))
    except KeyboardInterrupt as exc:  # a sweep's parent (a single run reports from inside its job)
        signum, word = _stopped_by(exc)
        typer.echo(f"{word}: each running job closed its log; jobs not started were not run", err=True)
        raise SystemExit(128 + signum) from None


def _hardware_task(cfg) -> None:
    """What Hydra runs for `slot hardware`: check, run the loop, report, print the output dir last."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from .hardware.config import load_hardware_config
    from .hardware.run import run_hardware
    from .jobs._logged import git_commit
    from .rundir import drop_if_unused
    from .signals import STOP_SIGNALS

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        with _one_line_failures(out_dir):
            hw_cfg = load_hardware_config(cfg)
            result = run_hardware(hw_cfg, out_dir, OmegaConf.to_yaml(cfg), _to_stderr, git_commit())
    except SystemExit:  # failed before the loop (no port, a servo missing): no log, so no run directory either
        drop_if_unused(out_dir)
        raise
    try:
        if result.outcome is not None and result.outcome.steps >= 2:
            from .hardware.report import report

            try:
                report(out_dir, list(hw_cfg.gait.velocity), list(hw_cfg.robot.leg.names))
            except Exception as exc:  # the run's outcome matters more than its figures
                typer.echo(f"warning: metrics/figures not written: {exc}", err=True)
        if result.message:
            stopped = result.exit_code == 0 or result.exit_code - 128 in {int(s) for s in STOP_SIGNALS}
            typer.echo(f"{'' if stopped else 'error: '}{result.message}", err=True)
        _say(str(out_dir), out_dir=out_dir)
    except OSError:  # the terminal is gone (SIGHUP): the servos are off and the log closed; nobody to tell
        _silence_std_streams()
    if result.exit_code:
        raise SystemExit(result.exit_code)


def _to_stderr(message: str) -> None:
    typer.echo(message, err=True)


def _silence_std_streams() -> None:
    """Point stdout and stderr at /dev/null, so the interpreter's last flush to a closed terminal neither
    raises nor turns the exit status into 120."""
    null = os.open(os.devnull, os.O_WRONLY)
    for stream in (sys.stdout, sys.stderr):
        try:
            os.dup2(null, stream.fileno())
        except (OSError, ValueError):
            pass


@app.command(
    context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": ["--help"]}
)
def hardware(
    ctx: typer.Context,
    dry_run: bool = typer.Option(
        False,
        "--dry-run",
        help="Run the whole loop with torque off and never write Goal Position; log what would be sent.",
    ),
) -> None:
    """Run the MPC on the robot (four XL430 servos, VIO odometry). Arguments are Hydra overrides.

    Groups: hardware (xl430), odometry (zmq, replay, sim), and robot, gait, solver, actuation, plant as for `slot run`.

    Keys: hardware.port, hardware.baudrate, hardware.ids, odometry.endpoint, duration (s; default: until Ctrl-C),
    live (default true: stream to Foxglove on ws://127.0.0.1:8765), live_port.

    Writes logs/hardware.mcap to experiments/hardware/<timestamp>/ (or hydra.run.dir=DIR); prints it last.

    Try --dry-run first. odometry=sim runs the same loop against the simulator (hardware-in-the-loop).
    """
    import hydra

    from .hardware.config import load_hardware_config

    args = list(ctx.args)
    overrides, multirun, info = _split(args)
    if multirun:
        fail("slot hardware drives one robot: -m (multirun) is not supported")
    if dry_run:
        args.append("dry_run=true")
        overrides.append("dry_run=true")
    if not info:
        from .hardware.config import HardwareSlotConfig

        precheck(overrides, False, HARDWARE_CONFIG, HARDWARE_GROUPS, load_hardware_config, HardwareSlotConfig)
        _check_hydra_dirs(overrides)
        if not _prints_only(args):
            claimed = _claim_run_dir(overrides, False, HARDWARE_CONFIG)
            args = [a for a in args if a not in overrides] + claimed
    register_schemas()
    sys.argv = ["slot", *args]
    main_fn = hydra.main(config_path=str(CONF_DIR), config_name=HARDWARE_CONFIG, version_base="1.3")(_hardware_task)
    main_fn()


def compose_config(overrides: list[str]) -> SlotConfig:  # noqa: F821
    """The checked config for one set of overrides, outside any Hydra run (bench, tools)."""
    from hydra import compose, initialize_config_dir

    precheck(overrides, multirun=False)
    register_schemas()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return load_config(compose("config", overrides=overrides))


def _stoppable(command: Callable[..., None]) -> Callable[..., None]:
    """A command that runs outside a Hydra job ends on a stop signal as ``slot run`` does: one line naming the
    signal and exit 128 + its number. (Typer turns a KeyboardInterrupt into a silent exit 130 whatever the
    signal was; a SystemExit passes it.)"""

    @functools.wraps(command)
    def stoppable(*args, **kwargs) -> None:
        try:
            command(*args, **kwargs)
        except KeyboardInterrupt as exc:
            signum, word = _stopped_by(exc)
            typer.echo(word, err=True)
            raise SystemExit(128 + signum) from None

    return stoppable


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
@_stoppable
def bench(
    ctx: typer.Context,
    out: str = typer.Option(
        None, "--out", help="Output directory (default experiments/bench/<timestamp>; hydra.run.dir=DIR too)."
    ),
) -> None:
    """Benchmark components side by side in one process: slot bench mpc leg, plus any Hydra overrides.

    Writes bench.csv (component,variant,median_us,p99_us,ratio_vs_baseline) and
    bench.json, prints the table, and prints the output directory last.
    """
    import datetime as _dt

    from rich.console import Console
    from rich.table import Table

    from . import bench as bench_pkg
    from .rundir import claim, finish, unique

    components = bench_pkg.COMPONENTS
    args = list(ctx.args)
    names = [a for a in args if "=" not in a] or list(components.names())
    overrides = [a for a in args if "=" in a and not a.startswith("hydra.")]
    unknown = [n for n in names if n not in components.names()]
    if unknown:
        fail(f"unknown bench component {unknown[0]!r}: choose from {', '.join(components.names())}")
    configs = {name: compose_config([*components.get(name).overrides, *overrides]) for name in names}
    # the output directory under the same rules as a run's (slotexp/rundir.py), claimed before the measurements
    key = "--out" if out is not None else "hydra.run.dir"
    given = out if out is not None else _override_value(args, "hydra.run.dir")
    if given is not None:
        check_output_dir(given, key)
        out_dir = Path(given)
    else:
        out_dir = unique(Path("experiments") / "bench" / _dt.datetime.now().strftime("%Y-%m-%d_%H-%M-%S"))
    try:
        claim(out_dir, _overwrite(overrides), key)
    except UserError as exc:
        fail(str(exc))
    rows = []
    for name in names:
        rows += components.get(name).measure(configs[name], out_dir)
    bench_pkg.write(rows, out_dir)
    finish(out_dir)
    table = Table(*bench_pkg.CSV_COLUMNS)
    for r in rows:
        table.add_row(r.component, r.variant, f"{r.median_us:.4g}", f"{r.p99_us:.4g}", f"{r.ratio_vs_baseline:.3g}")
    Console(stderr=True).print(table)
    _say(str(out_dir.resolve()))


@app.command()
@_stoppable
def figures(
    run_dir: Path = typer.Argument(..., help="A run's output directory (holding logs/*.mcap)."),
    force: bool = typer.Option(
        False, "--force", help="Rebuild even where logs are truncated, replacing outputs built from complete logs."
    ),
) -> None:
    """Rebuild a run's tables and figures from its MCAP logs alone."""
    from .composition import config_from_yaml
    from .jobs import EXPERIMENTS
    from .jobs import validate as val
    from .record import is_closed, read_log
    from .runlog import find_logs

    if not run_dir.is_dir():
        fail(f"{run_dir}: not a directory: give a run's output directory")
    from .rundir import held_by_another

    if held_by_another(run_dir):
        fail(f"{run_dir} is in use by a run that is still writing it: wait for it to finish, then rebuild")
    check_output_dir(run_dir, "the run's directory")  # before reading its logs: the outputs go back into it
    try:
        if (run_dir / val.INPUTS_FILE).is_file():  # a comparison of given logs: its inputs are the record
            val.rebuild(run_dir)
        else:
            logs = find_logs(run_dir)
            if not logs:
                fail(f"{run_dir}: no logs/*.mcap found: is this a run's output directory?")
            truncated = [p.name for p in logs if not is_closed(p)]
            if truncated and not force:
                from .rundir import earlier_outputs

                built = [p.name for p in earlier_outputs(run_dir) if p.parent == run_dir]
                if built:
                    fail(
                        f"{', '.join(truncated)} in {run_dir / 'logs'} is truncated (the run was killed): rebuilding "
                        f"would replace {', '.join(built)} with numbers from the part it holds; add --force to do so"
                    )
            for name in truncated:
                typer.echo(f"warning: logs/{name} is truncated: its tables and figures cover what it holds", err=True)
            meta = read_log(logs[0], topics=()).metadata  # the metadata alone
            name = meta.get("run", {}).get("experiment")
            if name not in EXPERIMENTS.names():
                fail(f"{logs[0]}: log metadata names no known experiment ({name!r})")
            experiment = EXPERIMENTS.get(name)
            cfg = config_from_yaml(meta.get("config", {}).get("yaml", "{}"), experiment.schema, experiment.root_schema)
            try:
                experiment.report(run_dir, cfg)
            except (KeyError, TypeError, ValueError, IndexError) as exc:  # a topic without the fields it should hold
                detail = " ".join(str(exc).split())[:160]
                fail(
                    f"{run_dir / 'logs'}: the logs do not hold what a {name} run writes ({type(exc).__name__}: "
                    f"{detail}); rebuild only from logs a slot run wrote"
                )
    except UserError as exc:
        fail(str(exc))
    _say(str(run_dir))


@app.command()
@_stoppable
def layout(
    out: Path = typer.Argument(Path("slot_layout.json"), help="Where to write the layout (a .json file)."),
) -> None:
    """Write the Foxglove layout for slotexp runs: 3D scene, CoM vs reference, cost, tendon angles, MPC time.

    In Foxglove: Layouts -> Import from file, then open a run's logs/*.mcap (or a live
    run's ws://127.0.0.1:8765).
    """
    from .atomic import write_text
    from .layout import SHIPPED

    try:
        is_dir = out.is_dir()
    except OSError as exc:  # a name too long, a component that is not a directory
        fail(f"{out}: cannot write the layout ({exc.strerror or exc})")
    if is_dir:
        fail(f"{out} is a directory: give a file name, e.g. {out / 'slot_layout.json'}")
    check_output_dir(out.parent if str(out.parent) else Path("."), "the layout's directory")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_text(out, SHIPPED.read_text())
    except OSError as exc:
        fail(f"{out}: cannot write the layout ({exc.strerror or exc})")
    _say(str(out))


@app.command()
@_stoppable
def summarize(
    multirun_dir: Path = typer.Argument(..., help="A multirun's output directory (slot run -m ...)."),
) -> None:
    """Gather every job of a sweep into summary.csv, summary.md and summary.png in its directory."""
    from .summarize import summarize as summarize_sweep

    try:
        summarize_sweep(multirun_dir)
    except UserError as exc:
        fail(str(exc).splitlines()[0])
    _say(str(multirun_dir))


@app.command()
@_stoppable
def manual(
    check: bool = typer.Option(False, "--check", help="Render in memory and fail where a committed page differs."),
    pages: Path = typer.Option(Path("docs/results"), help="The results manual's pages."),
    results: Path = typer.Option(Path("results"), help="The result files the tables are made from."),
) -> None:
    """Render the results manual's tables (docs/results/*.md) from the files `make results` writes."""
    from . import manual as pages_of

    try:
        if check:
            stale = pages_of.check(pages, results)
            for r in stale:
                typer.echo(f"{r.page}: table {r.name!r} differs from its result files", err=True)
            if stale:  # a check that found differences, not bad input: exit 1
                typer.echo(f"error: {len(stale)} table(s) out of date: run `slot manual`, commit the pages", err=True)
                raise SystemExit(1)
            _say(f"{pages}: every table agrees with {results}")
        else:
            check_output_dir(pages, "--pages")  # before rendering: the tables are written back into the pages
            changed = pages_of.write(pages, results)
            _say(*(str(p) for p in changed) or [f"{pages}: every table already agrees with {results}"])
    except UserError as exc:
        fail(str(exc))


_received: list[int] = []  # stop signals this process has taken (a launcher may re-raise them as plain Ctrl-C)


def _terminate(signum, frame) -> None:
    """SIGTERM (timeout, SLURM, systemd) and SIGHUP (a closed terminal) as Ctrl-C: unwind, close what is open,
    exit 128 + the signal's number."""
    from .errors import Interrupted

    _received.append(signum)
    raise Interrupted(signum)


def _stopped_by(exc: BaseException) -> tuple[int, str]:
    """The signal behind a KeyboardInterrupt (its own, or the last one this process took, or SIGINT) and
    the word a message uses for it."""
    signum = getattr(exc, "signum", None) or (_received[-1] if _received else signal.SIGINT)
    return signum, {signal.SIGTERM: "terminated", signal.SIGHUP: "hung up"}.get(signum, "interrupted")


def main() -> None:
    for signum in (signal.SIGTERM, signal.SIGHUP):  # SIGINT already raises KeyboardInterrupt
        if signal.getsignal(signum) is signal.SIG_DFL:
            signal.signal(signum, _terminate)
    try:
        app()
    except ModuleNotFoundError as exc:  # outside a Hydra job (slot bench rigid, ...)
        _fail_on_missing_extra(exc)
    except BrokenPipeError:  # outside a Hydra job (slot figures, summarize, bench, ... | head)
        _closed_stdout(None)
    except OSError as exc:  # outside a Hydra job: a table or figure the file system refused
        _fail_on_storage(exc, None)
    except KeyboardInterrupt as exc:
        signum, word = _stopped_by(exc)
        typer.echo(word, err=True)
        raise SystemExit(128 + signum) from None


if __name__ == "__main__":  # pragma: no cover
    main()
