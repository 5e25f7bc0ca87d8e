"""JSON objects read strictly: a key given twice is an error (json keeps the last one silently)."""

from __future__ import annotations

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
