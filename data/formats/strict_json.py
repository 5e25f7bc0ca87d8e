"""JSON read strictly (a key twice is an error, json keeps the last) and written strictly (null for NaN, inf)."""

from __future__ import annotations

import math
from typing import Any


class DuplicateKey(ValueError):
    """A key that appears twice in one JSON object; args[0] is the key."""

    def __str__(self) -> str:
        return f"key {self.args[0]!r} appears twice in one object"


def unique_keys(pairs: list[tuple[str, Any]]) -> dict:
    """object_pairs_hook for json.load / json.loads: the object as a dict; DuplicateKey naming a repeated key."""
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise DuplicateKey(key)
        out[key] = value
    return out


def finite(value: Any) -> Any:
    """value (dicts, lists, numbers) with every NaN or infinite float replaced by None."""
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(v) for v in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value
