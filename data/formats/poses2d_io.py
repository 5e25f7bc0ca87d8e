"""poses2d.json (docs/formats.md) read and written; bad entries are a one-line Poses2DError, repeats are kept."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from data.formats.atomic_io import atomic_write_text
from data.formats.strict_json import unique_keys
from data.keypoints import COCO23_NAMES, NUM_JOINTS
from data.multiview import ViewDetections

KEYPOINT_VALUES = NUM_JOINTS * 3  # 69
WRITE_DECIMALS = 4  # pixels and scores are written rounded to 1e-4
SCORE_SLACK = 0.05  # scores in (1, 1 + SCORE_SLACK] are clipped to 1; beyond, and below 0, they are an error
# A scored keypoint (or a box corner) may lie this many image widths/heights outside the image (a joint of
# a person cut by the border is guessed outside it); farther is a unit or format mistake (e.g. 1e15 px).
OUTSIDE_IMAGE_TOLERANCE = 1.0
INT64_RANGE = (-(2**63), 2**63 - 1)  # frame numbers and ids must fit numpy's int64


class Poses2DError(ValueError):
    """A poses2d.json file that is missing, malformed or inconsistent with the calibration."""


def _numbers(path: Path, i: int, entry: dict, key: str, count: int | None, what: str) -> np.ndarray:
    """entry[key] as finite floats, (count,) or a scalar (count None)."""
    value = entry[key]
    items = [value] if count is None else value if isinstance(value, list) else None
    bad = [v for v in items if isinstance(v, bool) or not isinstance(v, (int, float))] if items is not None else [value]
    if bad:
        raise Poses2DError(f"{path}: entry {i}: {key} must be {what}, got {_short(bad[0])} ({type(bad[0]).__name__})")
    if count is not None and len(value) != count:
        raise Poses2DError(f"{path}: entry {i}: {key} has {len(value)} numbers, expected {count} ({what})")
    try:
        out = np.asarray(value, dtype=np.float64)
    except OverflowError:  # a JSON integer beyond float64
        out = np.array([np.inf])
    if not np.all(np.isfinite(out)):
        raise Poses2DError(f"{path}: entry {i}: {key} has a non-finite value")
    return out


def _short(value: Any, limit: int = 40) -> str:
    """repr of a value cut to `limit` characters, for one-line messages."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _integer(path: Path, i: int, key: str, value: Any) -> int:
    """A JSON integer that fits int64 (frame numbers, ids); Poses2DError naming the entry otherwise."""
    if not isinstance(value, int) or isinstance(value, bool):
        raise Poses2DError(f"{path}: entry {i}: {key} must be an integer, got {_short(value)} ({type(value).__name__})")
    if not INT64_RANGE[0] <= value <= INT64_RANGE[1]:
        raise Poses2DError(f"{path}: entry {i}: {key} {_short(value)} does not fit a 64-bit integer")
    return value


def _entry(path: Path, i: int, entry: Any, cameras: dict[str, int]) -> tuple[int, int, tuple]:
    """Check entry i -> (frame, camera index, (keypoints (23, 3), bbox (4,), score, id))."""
    if not isinstance(entry, dict):
        raise Poses2DError(f"{path}: entry {i} is not an object")
    missing = [k for k in ("frame", "camera", "bbox", "score", "keypoints") if k not in entry]
    if missing:
        raise Poses2DError(f"{path}: entry {i} lacks {', '.join(repr(k) for k in missing)}")
    frame = _integer(path, i, "frame", entry["frame"])
    pid = _integer(path, i, "id", entry.get("id", -1))
    camera = entry["camera"]
    if isinstance(camera, bool) or not isinstance(camera, (str, int)):
        raise Poses2DError(
            f"{path}: entry {i}: camera must be a camera name (a string), got {_short(camera)} "
            f"({type(camera).__name__})"
        )
    if str(camera) not in cameras:
        raise Poses2DError(
            f"{path}: entry {i}: camera {str(camera)!r} is not in the calibration (known cameras: {', '.join(cameras)})"
        )
    keypoints = _numbers(path, i, entry, "keypoints", KEYPOINT_VALUES, "23 keypoints x, y, score")
    bbox = _numbers(path, i, entry, "bbox", 4, "x, y, w, h")
    score = float(_numbers(path, i, entry, "score", None, "a number"))
    return frame, cameras[str(camera)], (keypoints.reshape(NUM_JOINTS, 3), bbox, score, pid)


def _check_values(where: str, det: tuple, size: tuple[int, int] | None) -> tuple:
    """Scores in [0, 1] (clipped up to 1 + SCORE_SLACK), scored keypoints and box near the image of size (w, h)."""
    keypoints, bbox, score, pid = det
    if not 0.0 <= score <= 1.0 + SCORE_SLACK:
        raise Poses2DError(f"{where}: score {score:g} is outside [0, 1]")
    scores = keypoints[:, 2]
    bad = np.flatnonzero((scores < 0) | (scores > 1.0 + SCORE_SLACK))
    if len(bad):
        j = int(bad[0])
        raise Poses2DError(
            f"{where}: keypoint {j} ({COCO23_NAMES[j]}) has score {scores[j]:g}, outside [0, 1] "
            f"(0 = missing){f'; {len(bad)} keypoints in all' if len(bad) > 1 else ''}"
        )
    if bbox[2] < 0 or bbox[3] < 0:
        raise Poses2DError(f"{where}: bbox [x, y, w, h] has a negative width or height: {bbox.tolist()}")
    if size is not None:
        w, h = size
        lo, hi = -OUTSIDE_IMAGE_TOLERANCE * np.array([w, h]), (1 + OUTSIDE_IMAGE_TOLERANCE) * np.array([w, h])
        far = np.flatnonzero((scores > 0) & np.any((keypoints[:, :2] < lo) | (keypoints[:, :2] > hi), axis=1))
        if len(far):
            j = int(far[0])
            raise Poses2DError(
                f"{where}: keypoint {j} ({COCO23_NAMES[j]}) at ({keypoints[j, 0]:.6g}, "
                f"{keypoints[j, 1]:.6g}) px is far outside the {w}x{h} image (more than "
                f"{OUTSIDE_IMAGE_TOLERANCE:g} image sizes: pixels of the original image expected)"
            )
        corners = np.array([bbox[:2], bbox[:2] + bbox[2:]])
        if np.any((corners < lo) | (corners > hi)):
            raise Poses2DError(
                f"{where}: bbox {bbox.tolist()} is far outside the {w}x{h} image (more than "
                f"{OUTSIDE_IMAGE_TOLERANCE:g} image sizes)"
            )
    return np.concatenate([keypoints[:, :2], np.minimum(scores, 1.0)[:, None]], axis=1), bbox, min(score, 1.0), pid


def _load(path: Path) -> list:
    """The top-level, non-empty list of a poses2d.json file."""
    try:
        doc = json.loads(path.read_text(), object_pairs_hook=unique_keys)
    except FileNotFoundError:
        raise Poses2DError(f"{path}: poses2d.json not found") from None
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise Poses2DError(f"{path}: cannot read poses2d.json ({exc})") from None
    if not isinstance(doc, list):
        raise Poses2DError(f"{path}: expected a list of detections, got {type(doc).__name__}")
    if not doc:
        raise Poses2DError(f"{path}: the list of detections is empty (nothing to reconstruct)")
    return doc


def read_poses2d(
    path: str | Path, camera_names: list[str], image_sizes: list[tuple[int, int]] | None = None
) -> dict[int, list[ViewDetections]]:
    """Read poses2d.json -> {frame: ViewDetections (N, 23, 3) per camera}; image_sizes (w, h): check the pixels."""
    path = Path(path)
    cameras = {str(name): v for v, name in enumerate(camera_names)}
    grouped: dict[int, list[list[tuple]]] = {}
    for i, raw in enumerate(_load(path)):
        frame, v, det = _entry(path, i, raw, cameras)
        where = f"{path}: entry {i}: frame {frame}, camera {camera_names[v]!r}"
        det = _check_values(where, det, None if image_sizes is None else tuple(image_sizes[v]))
        grouped.setdefault(frame, [[] for _ in camera_names])[v].append(det)
    return {frame: [_view(dets) for dets in views] for frame, views in sorted(grouped.items())}


def _view(dets: list[tuple]) -> ViewDetections:
    """(keypoints (23, 3), bbox (4,), score, id) tuples -> ViewDetections."""
    if not dets:
        return ViewDetections.empty(NUM_JOINTS)
    keypoints, bboxes, scores, ids = zip(*dets)
    return ViewDetections(np.stack(keypoints), np.stack(bboxes), np.array(scores), np.array(ids))


def poses2d_entries(frames: dict[int, list[ViewDetections]], camera_names: list[str]) -> list[dict]:
    """The poses2d.json entries of {frame: V ViewDetections (N, 23, 3)}, frame then camera order."""
    entries = []
    for frame in sorted(frames):
        views = frames[frame]
        if len(views) != len(camera_names):
            raise ValueError(f"poses2d: frame {frame} has {len(views)} views for {len(camera_names)} cameras")
        for name, dets in zip(camera_names, views):
            entries += _view_entries(int(frame), str(name), dets)
    return entries


def _view_entries(frame: int, camera: str, dets: ViewDetections) -> list[dict]:
    """The detections of one view as poses2d.json entries, values rounded to WRITE_DECIMALS."""
    if len(dets) == 0:
        return []
    kps = np.asarray(dets.keypoints, dtype=np.float64)
    if kps.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(f"poses2d: frame {frame}, camera {camera}: keypoints {kps.shape[1:]}, expected (23, 3)")
    values = np.concatenate([kps.reshape(len(kps), -1), dets.bboxes, np.reshape(dets.scores, (-1, 1))], axis=1)
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if len(bad):
        raise ValueError(f"poses2d: frame {frame}, camera {camera}, detection {bad[0]} has a non-finite value")
    rounded = np.round(values, WRITE_DECIMALS).tolist()  # k / 10^4 as the nearest double: short reprs in the JSON
    ids = np.asarray(dets.person_ids).tolist()
    entries = []
    for row, person in zip(rounded, ids):
        entry = {"frame": frame, "camera": camera, "bbox": row[-5:-1], "score": row[-1], "keypoints": row[:-5]}
        if person >= 0:
            entry["id"] = int(person)
        entries.append(entry)
    return entries


def write_poses2d(path: str | Path, frames: dict[int, list[ViewDetections]], camera_names: list[str]) -> None:
    """Write {frame: V ViewDetections (N, 23, 3)} as poses2d.json atomically; values rounded to 1e-4."""
    atomic_write_text(path, json.dumps(poses2d_entries(frames, camera_names)))
