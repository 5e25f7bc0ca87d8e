"""COCO detection-results files (``[{"image_id", "category_id", "bbox": [x, y, w, h], "score"}]``), checked."""

from __future__ import annotations

import json
import math
import reprlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from data.formats.strict_json import unique_keys

KEYS = ("image_id", "category_id", "bbox", "score")


@dataclass(frozen=True)
class CocoDetections:
    """The M entries of a detections file, in file order: ids (M,) int64, boxes (M, 4) x, y, w, h, scores (M,)."""

    path: Path
    image_ids: np.ndarray
    category_ids: np.ndarray
    boxes: np.ndarray
    scores: np.ndarray


def _is_int64(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and -(2**63) <= value < 2**63


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def entry_problem(entry: Any) -> str | None:
    """What is wrong with one detection entry (a short phrase), None when it is well formed."""
    if not isinstance(entry, dict):
        return f"is not an object: {reprlib.repr(entry)}"
    missing = [k for k in KEYS if k not in entry]
    if missing:
        return f"lacks the key(s) {missing} (needs {list(KEYS)})"
    for key in ("image_id", "category_id"):
        if not _is_int64(entry[key]):
            return f"{key} must be a 64-bit integer, got {reprlib.repr(entry[key])}"
    box = entry["bbox"]
    if not (isinstance(box, list) and len(box) == 4 and all(_is_number(v) for v in box)):
        return f"bbox must be 4 finite numbers [x, y, w, h], got {reprlib.repr(box)}"
    if box[2] <= 0 or box[3] <= 0:
        return f"bbox width and height must be > 0, got {box}"
    if not _is_number(entry["score"]):
        return f"score must be a finite number, got {reprlib.repr(entry['score'])}"
    return None


def read_coco_detections(path: str | Path) -> CocoDetections:
    """Read and check a detection-results file; a ValueError names the file and the first bad entry's index."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(), object_pairs_hook=unique_keys)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the detections file ({exc.strerror or exc})") from None
    except ValueError as exc:  # JSONDecodeError, DuplicateKey
        raise ValueError(f"{path}: not a valid JSON detections file ({exc})") from None
    if not isinstance(doc, list):
        raise ValueError(f"{path}: a detections file is a JSON list of {{{', '.join(KEYS)}}} objects")
    for i, entry in enumerate(doc):
        problem = entry_problem(entry)
        if problem:
            raise ValueError(f"{path}: entry {i} {problem}")
    image_ids, category_ids = (np.array([e[key] for e in doc], dtype=np.int64) for key in ("image_id", "category_id"))
    boxes, scores = (np.array([e[key] for e in doc], dtype=np.float64) for key in ("bbox", "score"))
    return CocoDetections(path, image_ids, category_ids, boxes.reshape(-1, 4), scores)
