"""Shared test helpers: compose the real config tree without the CLI."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from slotexp.config import SlotConfig, register_schemas, validate

CONF = Path(__file__).resolve().parents[1] / "conf"


def load(*overrides: str) -> SlotConfig:
    register_schemas()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return validate(OmegaConf.to_object(compose("config", overrides=list(overrides))))
