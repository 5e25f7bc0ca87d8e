"""Reading and writing the pose files users see (docs/formats.md): poses3d.json."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Iterable

import numpy as np

from data.formats.atomic_io import atomic_write_text
from data.keypoints import COCO23_NAMES

JOINT_SOURCES = ("none", "views", "prior", "motion")  # an output joint's provenance, by its code (joint_source)


def poses3d_document(
    frames: Iterable[tuple], camera_names: list[str], fill: bool = True, fps: float | None = None
) -> dict:
    """poses3d.json of (frame, poses (P, 23, 4), assignment (P, V)[, ids[, joint_views, joint_source]]) (formats.md);
    fps: the frame numbers' frames per second, written where it is a positive number (None: unknown, no key)."""
    out_frames = []
    for frame, poses, assignment, *rest in frames:
        ids, views, source = (*rest, None, None, None)[:3]
        ids = np.arange(len(poses)) if ids is None else np.asarray(ids)
        poses = np.asarray(poses, dtype=np.float64)
        if views is not None and not fill:
            poses = np.where((np.asarray(views) < 2)[..., None], 0.0, poses)
            source = np.where(np.asarray(views) < 2, 0, source)
        people = []
        for p, pose in enumerate(poses):
            kps = np.where(pose[:, 3:4] > 0, pose, 0.0)
            person = {"id": int(ids[p]), "keypoints": np.round(kps, 6).tolist()}
            person["views"] = {camera_names[v]: int(d) for v, d in enumerate(assignment[p]) if d >= 0}
            if views is not None:
                person["joint_views"] = [int(n) for n in views[p]]
                person["joint_source"] = [JOINT_SOURCES[c] for c in source[p]]
            people.append(person)
        out_frames.append({"frame": int(frame), "poses": people})
    rate = {"fps": float(fps)} if fps is not None and math.isfinite(fps) and fps > 0 else {}
    return {"keypoints": list(COCO23_NAMES), "units": "m", **rate, "frames": out_frames}


def write_poses3d(
    path: str | Path, frames: Iterable[tuple], camera_names: list[str], fill: bool = True, fps: float | None = None
) -> None:
    """Write poses3d.json atomically from poses3d_document's tuples (fill, fps: as there)."""
    atomic_write_text(path, json.dumps(poses3d_document(frames, camera_names, fill, fps)))


def read_poses3d_file(path: str | Path) -> tuple[list[tuple[int, np.ndarray, np.ndarray]], float | None]:
    """Read poses3d.json: (read_poses3d_frames' list, its "fps" or None for files without it)."""
    doc = json.loads(Path(path).read_text())
    if doc.get("units") != "m" or len(doc.get("keypoints", [])) != len(COCO23_NAMES):
        raise ValueError(f"{path}: not a poses3d.json with 23 keypoints in metres")
    fps = doc.get("fps")
    if fps is not None and not (type(fps) in (int, float) and math.isfinite(fps) and fps > 0):
        raise ValueError(f'{path}: "fps" is {fps!r}, not a positive number of frames per second')
    frames = [
        (
            int(f["frame"]),
            np.array([p["keypoints"] for p in f["poses"]], dtype=np.float64).reshape(-1, 23, 4),
            np.array([p["id"] for p in f["poses"]], dtype=np.int64),
        )
        for f in doc["frames"]
    ]
    return frames, fps


def read_poses3d_frames(path: str | Path) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Read poses3d.json keeping the ids, in file order: [(frame, poses (P, 23, 4) x, y, z, score, ids (P,))]."""
    return read_poses3d_file(path)[0]


def read_poses3d(path: str | Path) -> dict[int, np.ndarray]:
    """Read poses3d.json: {frame: (P, 23, 4) x, y, z, score}."""
    return {frame: poses for frame, poses, _ in read_poses3d_frames(path)}


def read_joint_provenance(path: str | Path) -> dict[int, tuple[np.ndarray, list[list[str]]]]:
    """{frame: (joint_views (P, 23) int, joint_source P x 23 names)} of poses3d.json; older files: -1, "unknown"."""
    doc = json.loads(Path(path).read_text())
    out = {}
    for f in doc["frames"]:
        views = [p.get("joint_views", [-1] * len(COCO23_NAMES)) for p in f["poses"]]
        source = [p.get("joint_source", ["unknown"] * len(COCO23_NAMES)) for p in f["poses"]]
        out[int(f["frame"])] = (np.array(views, dtype=np.int64).reshape(-1, len(COCO23_NAMES)), source)
    return out
