"""Reading and writing the pose files users see (docs/formats.md): poses3d.json."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

import numpy as np

from data.formats.atomic_io import atomic_write_text
from data.keypoints import COCO23_NAMES


def poses3d_document(frames: Iterable[tuple], camera_names: list[str]) -> dict:
    """The poses3d.json document of (frame, poses (P, 23, 4), assignment (P, V)[, ids (P,)]) tuples; without
    ids a person's id is its index in the frame (docs/formats.md: with tracking, the track id)."""
    out_frames = []
    for frame, poses, assignment, *rest in frames:
        ids = np.arange(len(poses)) if not rest or rest[0] is None else np.asarray(rest[0])
        people = []
        for p, pose in enumerate(np.asarray(poses, dtype=np.float64)):
            kps = np.where(pose[:, 3:4] > 0, pose, 0.0)
            views = {camera_names[v]: int(d) for v, d in enumerate(assignment[p]) if d >= 0}
            people.append({"id": int(ids[p]), "keypoints": np.round(kps, 6).tolist(), "views": views})
        out_frames.append({"frame": int(frame), "poses": people})
    return {"keypoints": list(COCO23_NAMES), "units": "m", "frames": out_frames}


def write_poses3d(path: str | Path, frames: Iterable[tuple], camera_names: list[str]) -> None:
    """Write poses3d.json atomically from (frame, poses (P, 23, 4), assignment (P, V)[, ids (P,)]) tuples."""
    atomic_write_text(path, json.dumps(poses3d_document(frames, camera_names)))


def read_poses3d_frames(path: str | Path) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Read poses3d.json keeping the ids, in file order: [(frame, poses (P, 23, 4) x, y, z, score, ids (P,))]."""
    doc = json.loads(Path(path).read_text())
    if doc.get("units") != "m" or len(doc.get("keypoints", [])) != len(COCO23_NAMES):
        raise ValueError(f"{path}: not a poses3d.json with 23 keypoints in metres")
    return [
        (
            int(f["frame"]),
            np.array([p["keypoints"] for p in f["poses"]], dtype=np.float64).reshape(-1, 23, 4),
            np.array([p["id"] for p in f["poses"]], dtype=np.int64),
        )
        for f in doc["frames"]
    ]


def read_poses3d(path: str | Path) -> dict[int, np.ndarray]:
    """Read poses3d.json: {frame: (P, 23, 4) x, y, z, score}."""
    return {frame: poses for frame, poses, _ in read_poses3d_frames(path)}
