"""Shared test configuration: the ``slow`` mark (``pytest -m "not slow"`` runs the quick subset), the
``serial`` mark (real-time tests that must not share the machine: ``make test`` runs them alone) and the
``mujoco`` mark (tests of the rigid plant, skipped where the [rigid] extra is not installed)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SLOW_LIST = Path(__file__).with_name("slow_tests.txt")
# real time: a servo emulator on a pseudo-terminal answering at the bus's pace, the live view's pacing and lingering
SERIAL_MODULES = ("test_hardware_cli.py", "test_hardware_emulator.py", "test_hardware_loop.py", "test_scene.py")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: takes a second or more (listed in tests/slow_tests.txt)")
    config.addinivalue_line("markers", "serial: runs in real time, alone (tests/conftest.py SERIAL_MODULES)")
    config.addinivalue_line("markers", "mujoco: needs MuJoCo (pip install 'slotexp[rigid]'); skipped without it")


def _have(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ValueError:  # a module set to None in sys.modules (a test's way of hiding it)
        return False


HAVE_MUJOCO = _have("mujoco")
# modules that import MuJoCo to be collected at all (their tests carry the mujoco mark)
collect_ignore = [] if HAVE_MUJOCO else ["test_rigid.py"]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark the listed tests slow, and every test that shares a module- or session-scoped fixture of ours with
    one of them (the fixture's set-up is the slow part, and the first test left in would pay for it)."""
    listed = {line.strip() for line in SLOW_LIST.read_text().splitlines() if line.strip() and not line.startswith("#")}

    def shared_fixtures(item: pytest.Item) -> set[tuple[str, str]]:
        info = getattr(item, "_fixtureinfo", None)
        if info is None:
            return set()
        out = set()
        for name, defs in info.name2fixturedefs.items():
            last = defs[-1]
            if last.scope != "function" and last.baseid:  # ours (pytest's own have no baseid)
                out.add((last.baseid, name))
        return out

    slow_fixtures = set().union(*(shared_fixtures(i) for i in items if i.nodeid in listed))
    for item in items:
        if item.nodeid in listed or shared_fixtures(item) & slow_fixtures:
            item.add_marker(pytest.mark.slow)
        if item.path.name in SERIAL_MODULES:
            item.add_marker(pytest.mark.serial)
        if not HAVE_MUJOCO and item.get_closest_marker("mujoco"):
            item.add_marker(pytest.mark.skip(reason="needs MuJoCo: pip install 'slotexp[rigid]'"))
