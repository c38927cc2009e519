"""Where the Hydra config tree is: ``conf/`` at the top of a source checkout, shipped inside the package by
the wheel (``pyproject.toml`` maps the package ``slotexp.conf`` to ``conf/``)."""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def _find() -> Path:
    for where in (_PACKAGE / "conf", _PACKAGE.parent / "conf"):  # an installed wheel, then a checkout
        if (where / "config.yaml").is_file():
            return where
    raise FileNotFoundError(f"no config tree (conf/config.yaml) in {_PACKAGE} or beside it: reinstall slotexp")


CONF_DIR = _find()
