"""Type and range checks of Hydra config values for the entry points: a bad value stops the run with one
line that names the key (``trainer.batch_size=0: must be an integer >= 1``), before any work is done."""

from __future__ import annotations

import math
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf


class ConfigError(ValueError):
    """A config value of the wrong type or range; the message names the key."""


def value_of(cfg: DictConfig, key: str) -> Any:
    """The value at a dotted key (None when absent)."""
    return OmegaConf.select(cfg, key, default=None)


def fail(key: str, value: Any, what: str) -> None:
    """Raise ConfigError 'key=value: what'."""
    shown = OmegaConf.to_container(value) if isinstance(value, (DictConfig, ListConfig)) else value
    raise ConfigError(f"{key}={shown!r}: {what}")


def is_int(value: Any) -> bool:
    """An integer, not a bool."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_number(value: Any) -> bool:
    """A finite int or float, not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_int(cfg: DictConfig, key: str, minimum: int, nullable: bool = False) -> None:
    """cfg[key] is an integer >= minimum (or null when nullable)."""
    value = value_of(cfg, key)
    if value is None and nullable:
        return
    if not is_int(value) or value < minimum:
        fail(key, value, f"must be an integer >= {minimum}" + (" or null" if nullable else ""))


def check_number(cfg: DictConfig, key: str, minimum: float = 0.0, strict: bool = True) -> None:
    """cfg[key] is a finite number > minimum (>= when not strict)."""
    value = value_of(cfg, key)
    if not is_number(value) or value < minimum or (strict and value == minimum):
        fail(key, value, f"must be a number {'>' if strict else '>='} {minimum:g}")


def check_bool(cfg: DictConfig, key: str) -> None:
    """cfg[key] is true or false."""
    value = value_of(cfg, key)
    if not isinstance(value, bool):
        fail(key, value, "must be true or false")
