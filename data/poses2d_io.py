"""poses2d.json (DESIGN.md): one entry per person per camera per frame, COCO-23 keypoints in pixels.

Entry: {"frame": int, "camera": str, "bbox": [x, y, w, h], "score": float, "keypoints": 69 numbers
(23 x, y, score)} and optionally "id" (ground-truth person id).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from data.keypoints import NUM_JOINTS
from data.multiview import ViewDetections
from data.atomic_io import atomic_write_text

KEYPOINT_VALUES = NUM_JOINTS * 3  # 69
WRITE_DECIMALS = 4  # pixels and scores are written rounded to 1e-4


class Poses2DError(ValueError):
    """A poses2d.json file that is missing, malformed or inconsistent with the calibration."""


def _numbers(path: Path, i: int, entry: dict, key: str, count: int | None, what: str) -> np.ndarray:
    """entry[key] as finite floats, (count,) or a scalar (count None)."""
    value = entry[key]
    if count is None:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    else:
        ok = isinstance(value, list) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        if ok and len(value) != count:
            raise Poses2DError(f"{path}: entry {i}: {key} has {len(value)} numbers, expected {count} ({what})")
    if not ok:
        raise Poses2DError(f"{path}: entry {i}: {key} must be {what}")
    out = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(out)):
        raise Poses2DError(f"{path}: entry {i}: {key} has a non-finite value")
    return out


def _entry(path: Path, i: int, entry: Any, cameras: dict[str, int]) -> tuple[int, int, tuple]:
    """Check entry i -> (frame, camera index, (keypoints (23, 3), bbox (4,), score, id))."""
    if not isinstance(entry, dict):
        raise Poses2DError(f"{path}: entry {i} is not an object")
    missing = [k for k in ("frame", "camera", "bbox", "score", "keypoints") if k not in entry]
    if missing:
        raise Poses2DError(f"{path}: entry {i} lacks {', '.join(repr(k) for k in missing)}")
    frame, camera, pid = entry["frame"], entry["camera"], entry.get("id", -1)
    if not isinstance(frame, int) or isinstance(frame, bool):
        raise Poses2DError(f"{path}: entry {i}: frame must be an integer, got {frame!r}")
    if not isinstance(pid, int) or isinstance(pid, bool):
        raise Poses2DError(f"{path}: entry {i}: id must be an integer, got {pid!r}")
    if str(camera) not in cameras:
        raise Poses2DError(f"{path}: entry {i}: camera {str(camera)!r} is not in the calibration "
                           f"(known cameras: {', '.join(cameras)})")
    keypoints = _numbers(path, i, entry, "keypoints", KEYPOINT_VALUES, "23 keypoints x, y, score")
    bbox = _numbers(path, i, entry, "bbox", 4, "x, y, w, h")
    score = float(_numbers(path, i, entry, "score", None, "a number"))
    return frame, cameras[str(camera)], (keypoints.reshape(NUM_JOINTS, 3), bbox, score, pid)


def _load(path: Path) -> list:
    """The top-level list of a poses2d.json file."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise Poses2DError(f"{path}: cannot read poses2d.json ({exc})") from None
    if not isinstance(doc, list):
        raise Poses2DError(f"{path}: expected a list of detections, got {type(doc).__name__}")
    return doc


def read_poses2d(path: str | Path, camera_names: list[str]) -> dict[int, list[ViewDetections]]:
    """Read poses2d.json -> {frame: one ViewDetections per camera in camera_names order (empty where none)}."""
    path = Path(path)
    cameras = {str(name): v for v, name in enumerate(camera_names)}
    grouped: dict[int, list[list[tuple]]] = {}
    for i, raw in enumerate(_load(path)):
        frame, v, det = _entry(path, i, raw, cameras)
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
            for n in range(len(dets)):
                entries.append(_entry_dict(int(frame), str(name), dets, n))
    return entries


def _entry_dict(frame: int, camera: str, dets: ViewDetections, n: int) -> dict:
    """Detection n of a view as a poses2d.json entry."""
    kps = np.asarray(dets.keypoints[n], dtype=np.float64)
    if kps.shape != (NUM_JOINTS, 3):
        raise ValueError(f"poses2d: frame {frame}, camera {camera}: keypoints {kps.shape}, expected (23, 3)")
    values = np.concatenate([kps.ravel(), dets.bboxes[n], [dets.scores[n]]])
    if not np.all(np.isfinite(values)):
        raise ValueError(f"poses2d: frame {frame}, camera {camera}, detection {n} has a non-finite value")
    entry = {"frame": frame, "camera": camera,
             "bbox": [round(float(v), WRITE_DECIMALS) for v in dets.bboxes[n]],
             "score": round(float(dets.scores[n]), WRITE_DECIMALS),
             "keypoints": [round(float(v), WRITE_DECIMALS) for v in kps.ravel()]}
    if dets.person_ids[n] >= 0:
        entry["id"] = int(dets.person_ids[n])
    return entry


def write_poses2d(path: str | Path, frames: dict[int, list[ViewDetections]], camera_names: list[str]) -> None:
    """Write {frame: V ViewDetections (N, 23, 3)} as poses2d.json atomically; values rounded to 1e-4."""
    atomic_write_text(path, json.dumps(poses2d_entries(frames, camera_names)))
