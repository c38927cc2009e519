"""Rigid quadrupeds (``plant=rigid``): where a robot's published model is, found without importing MuJoCo.

:func:`model_path` is what the config check needs; ``model.py`` loads the model into MuJoCo.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from ..config import RigidConfig
from ..errors import ConfigError


def model_path(cfg: RigidConfig) -> Path:
    """The MJCF file inside the installed package, found without importing the package."""
    spec = importlib.util.find_spec(cfg.package)
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError(
            f"robot.rigid.package = {cfg.package!r} is not installed: the robots of plant=rigid come with "
            "slotexp's [rigid] extra (pip install 'slotexp[rigid]'; make installs every extra)"
        )
    root = Path(list(spec.submodule_search_locations)[0]) / "robot_model"
    path = root / cfg.model
    if not path.is_file():
        raise ConfigError(f"robot.rigid.model = {cfg.model!r}: no such file under {root}")
    return path
