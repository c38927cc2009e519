"""Shared test helpers: compose the real config tree without the CLI, run the CLI as a user would."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from slotexp.cli import CONF_DIR, register_schemas
from slotexp.composition import validate
from slotexp.config import SlotConfig

CONF = CONF_DIR
SLOT = Path(sys.executable).parent / "slot"
SLOT_CMD = [str(SLOT)] if SLOT.exists() else [sys.executable, "-m", "slotexp.cli"]
PLAN_TOL = 1e-4  # N, constraint tolerance of the CVXPY solutions


def as_from_a_terminal() -> None:
    """``preexec_fn`` for a ``slot`` process that a test signals: SIGINT and SIGHUP at their defaults, as from a
    terminal. A test run in the background ignores SIGINT, and under nohup SIGHUP; ignored signals are
    inherited, and slot rightly leaves an ignored SIGHUP ignored (nohup asks a run to outlive its terminal)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


def turned_off_after_on(torque_writes: list[int]) -> bool:
    """The host turned a servo's torque on and, after the last time it did, off again (retries allowed)."""
    return 1 in torque_writes and torque_writes[-1] == 0


def load(*overrides: str) -> SlotConfig:
    register_schemas()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return validate(OmegaConf.to_object(compose("config", overrides=list(overrides))))


def load_hardware(*overrides: str):
    """The checked ``slot hardware`` config for ``overrides``."""
    from slotexp.hardware.config import load_hardware_config

    register_schemas()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return load_hardware_config(compose("hardware_config", overrides=list(overrides)))


def run_on_emulator(emu, pub, tmp: Path, *overrides: str):
    """``slot hardware``'s loop in this process against a servo emulator (and odometry publisher)."""
    from slotexp.hardware.run import run_hardware

    notes: list[str] = []
    args = [f"hardware.port={emu.port}"] + ([f"odometry.endpoint={pub.endpoint}"] if pub else []) + list(overrides)
    result = run_hardware(load_hardware(*args), tmp, "{}", notes.append)
    return result, notes


def slot(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    """``slot <args>`` in a subprocess, as a user would run it."""
    return subprocess.run(
        [*SLOT_CMD, *map(str, args)], cwd=cwd, env=dict(os.environ), capture_output=True, text=True, timeout=timeout
    )


def slot_after(prelude: str, *args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    """``slot <args>`` in a subprocess whose Python runs ``prelude`` first (to make a module unimportable or a
    write fail, as a machine without an extra or with a full disk would)."""
    code = f"{prelude}\nimport sys\nsys.argv = ['slot', *sys.argv[1:]]\nfrom slotexp.cli import main\nmain()\n"
    return subprocess.run(
        [sys.executable, "-c", code, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=timeout
    )


def last_line(text: str) -> str:
    lines = [ln for ln in text.splitlines() if ln.strip()]
    assert lines, "nothing on stdout"
    return lines[-1].strip()


def ok(proc: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    assert proc.returncode == 0, f"exit {proc.returncode}\nstdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def assert_one_line_error(proc: subprocess.CompletedProcess, *names: str) -> str:
    assert proc.returncode == 2, f"exit {proc.returncode}\nstdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, f"expected exactly one line on stderr, got:\n{proc.stderr}"
    line = lines[0]
    assert line.startswith("error: ") and len(line) > len("error: "), line
    for name in names:
        assert name in line, f"{name!r} not named in: {line}"
    return line


def assert_png(path: Path) -> None:
    assert path.is_file(), f"{path} missing"
    data = path.read_bytes()
    assert len(data) > 1000 and data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a real PNG"


def check_plan_constraints(cfg, robot, sol, x, plan) -> None:
    """A solution's plan satisfies every constraint, and its prediction starts at ``x``."""
    mpc_forces = sol.plan_fz
    assert np.all(mpc_forces <= plan.fz_max + PLAN_TOL)
    assert np.all(mpc_forces >= plan.fz_min - PLAN_TOL)
    weight = robot.mass * cfg.sim.gravity
    assert np.all(np.abs(mpc_forces.sum(axis=1) - weight) <= cfg.mpc.force_balance_band + PLAN_TOL)
    fx, fy, fz = sol.forces[:, 0], sol.forces[:, 1], sol.forces[:, 2]
    assert np.all(np.abs(fx) <= plan.mu[0] * fz + PLAN_TOL)
    assert np.all(np.abs(fy) <= plan.mu[0] * fz + PLAN_TOL)
    np.testing.assert_allclose(sol.predicted[0], x, atol=1e-6)
