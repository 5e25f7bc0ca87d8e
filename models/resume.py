"""The config of a resumed training run: the checkpoint's, changed only by overrides listed in resume_may_change."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, ListConfig, OmegaConf

from data.config_checks import ConfigError

RUN_KEYS = ("resume", "overwrite", "resume_may_change")  # of the resume command itself, never stored


def _plain(value: Any) -> Any:
    """Containers as plain python, for comparing."""
    return OmegaConf.to_container(value, resolve=True) if isinstance(value, (DictConfig, ListConfig)) else value


def _group_unchanged(
    key: str, cfg: DictConfig, stored: DictConfig, choices: dict[str, str], stored_choices: dict[str, str] | None
) -> bool:
    """Whether a config-group override selects what the stored run used (by its recorded choice, else its node)."""
    if stored_choices is not None:
        return stored_choices.get(key) == choices.get(key)
    return key in stored and _plain(cfg.get(key)) == _plain(stored[key])


def resume_config(
    cfg: DictConfig, checkpoint: dict, overrides: list[str], choices: dict[str, str], path: str | Path
) -> DictConfig:
    """The checkpoint's stored config with this command's safe overrides (hydra.overrides.task) applied."""
    stored = OmegaConf.create(checkpoint["config"])
    safe = set(cfg.resume_may_change)
    updates: dict[str, Any] = {}
    for override in OverridesParser.create().parse_overrides(overrides):
        key = override.key_or_group
        if key in RUN_KEYS or key.split(".")[0] == "hydra":
            continue
        if key in choices:
            if _group_unchanged(key, cfg, stored, choices, checkpoint.get("choices")):
                continue
            old = (checkpoint.get("choices") or {}).get(key, "the stored one")
        else:
            new, old = _plain(OmegaConf.select(cfg, key)), _plain(OmegaConf.select(stored, key))
            if new == old and not override.is_delete():
                continue
            if key in safe:
                updates[key] = new
                continue
        raise ConfigError(
            f"resume: {override.input_line} would change {key} ({old!r} in {path}); a resumed run keeps "
            f"its stored config, only {', '.join(sorted(safe))} may change"
        )
    merged = OmegaConf.merge(OmegaConf.create(_plain(cfg)), stored)
    for key, value in updates.items():
        OmegaConf.update(merged, key, value, merge=False)
    for key in RUN_KEYS:
        merged[key] = _plain(cfg[key])
    return merged
