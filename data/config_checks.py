"""Type and range checks of Hydra config values: a bad one stops the run before any work, in one line naming the key."""

from __future__ import annotations

import inspect
import math
from typing import Any

from hydra.utils import get_object
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


KINDS = {
    "float": (is_number, "a finite number"),
    "int": (is_int, "an integer"),
    "bool": (lambda v: isinstance(v, bool), "true or false"),
}


def target_hints(target: str) -> dict[str, str]:
    """The named parameters of a ``_target_`` and their annotations as written (a class's **kwargs: its bases')."""
    hints: dict[str, str] = {}
    obj = get_object(target)
    for owner in obj.__mro__[:-1] if isinstance(obj, type) else (obj,):  # [:-1]: not object's signature
        params = inspect.signature(owner).parameters.values()
        hints.update({p.name: str(p.annotation) for p in params if p.kind != p.VAR_KEYWORD and p.name not in hints})
        if all(p.kind != p.VAR_KEYWORD for p in params):
            break
    return hints


def check_target(cfg: DictConfig, group: str) -> None:
    """cfg[group]'s keys have their _target_'s annotated types: float finite, int, bool; a *score in [0, 1]."""
    target = OmegaConf.select(cfg, f"{group}._target_", default=None)
    for name, hint in target_hints(target).items() if target else ():
        kind, _, rest = hint.partition(" | ")
        key, nullable = f"{group}.{name}", rest == "None"
        if name not in cfg[group] or kind not in KINDS or (nullable and value_of(cfg, key) is None):
            continue
        value = value_of(cfg, key)
        if not KINDS[kind][0](value):
            fail(key, value, f"must be {KINDS[kind][1]}" + (" or null" if nullable else ""))
        if name.endswith("score") and not 0 <= value <= 1:  # scores are in [0, 1] (docs/formats.md)
            fail(key, value, "must be a score in [0, 1]")
