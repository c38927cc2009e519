"""A non-editable install works: the wheel ships the config tree and `slot run` finds it.

The wheel is built from this checkout and installed with ``--no-deps`` into a fresh
virtual environment whose dependencies come from the test's own environment (a
``.pth`` line, which adds the directory without running the editable install's
hooks), then its ``slot`` runs a short Table I from a directory outside the repo.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

from tests.helpers import last_line, ok

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("install")
    dist = root / "dist"
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(REPO)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    if build.returncode != 0:
        pytest.fail(f"building the wheel failed:\n{build.stderr[-3000:]}")
    env_dir = root / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    (Path(site) / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    wheel = next(dist.glob("slotexp-*.whl"))
    ok(
        subprocess.run(
            [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q", str(wheel)],
            capture_output=True,
            text=True,
            timeout=600,
        )
    )
    return env_dir


def test_wheel_install_runs_table1_outside_the_repo(installed: Path, tmp_path: Path) -> None:
    python = installed / "bin" / "python"
    where = subprocess.run(
        [str(python), "-c", "import slotexp, pathlib; print(pathlib.Path(slotexp.__file__).parent)"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        check=True,
    ).stdout.strip()
    assert Path(where).is_relative_to(installed), f"slotexp imported from {where}, not the installed wheel"
    assert (Path(where) / "conf" / "config.yaml").is_file()
    assert (Path(where) / "layouts" / "slot.json").is_file()  # what `slot layout` writes
    out = tmp_path / "run"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = ok(
        subprocess.run(
            [
                str(installed / "bin" / "slot"),
                "run",
                "experiment=perturb",
                "solver=clarabel",
                "experiment.scenarios=[baseline]",
                "experiment.duration=0.5",
                f"hydra.run.dir={out}",
            ],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )
    )
    assert last_line(proc.stdout) == str(out)
    table = json.loads((out / "metrics.json").read_text())["table1"]
    assert [row["scenario"] for row in table] == ["baseline"] and table[0]["infeasible_steps"] == 0


def test_the_wheel_lists_every_package_and_maps_the_config_tree() -> None:
    # pyproject.toml names the packages one by one (slotexp.conf comes from conf/ at the top of the repo): a new
    # subpackage left out of the list would be missing from the wheel
    import tomllib

    tool = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "slotexp").rglob("__init__.py")}
    groups = {f"slotexp.conf.{d.name}" for d in (REPO / "conf").iterdir() if d.is_dir()}
    assert set(tool["packages"]) == found | {"slotexp.conf"} | groups
    assert tool["package-dir"] == {"slotexp.conf": "conf"} and (REPO / "conf" / "config.yaml").is_file()
    assert not (REPO / "slotexp" / "conf").exists()  # one config tree, at the top
