"""A self-contained HTML viewer of a sequence (sequence_view.html with the data as JSON; no network needed)."""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from data.formats.atomic_io import atomic_write_text
from data.geometry.camera import Camera, Rig
from data.keypoints import COCO23_NAMES, LIMBS
from evaluation.pictures.sequence_data import (
    SequenceFrame,
    hex_color,
    id_colors,
    pose_roots,
    sequence_frames,
    valid_joints,
)

TEMPLATE = Path(__file__).with_name("sequence_view.html")
DATA_MARK = "__SEQUENCE_DATA__"
TITLE_MARK = "__TITLE__"
DEFAULT_MAX_MB = 20.0
DECIMALS = 3  # metres rounded to the millimetre
FRUSTUM_FRACTION = 0.04  # frustum depth as a fraction of the scene's extent
GRID_STEPS_M = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
GRID_MAX_LINES = 40  # per direction: the finest step of GRID_STEPS_M that keeps below it
GRID_MARGIN_M = 1.0  # around people and cameras
PLAY_FPS = 10
UNTRACKED_NOTE = (
    "tracking off: ids are each person's index in its frame, so a colour does not follow a person across frames"
)


def _xyz(point: np.ndarray) -> list[float]:
    """(3,) -> [x, y, z] rounded to the millimetre."""
    return [round(float(v), DECIMALS) for v in point]


def _frame_entry(f: SequenceFrame) -> dict:
    """One frame's JSON: ids, poses as 23 [x, y, z] or null (score 0 or non-finite), roots [x, y, z] or null."""
    ok = valid_joints(f.poses)
    poses = [[_xyz(j[:3]) if good else None for j, good in zip(pose, valid)] for pose, valid in zip(f.poses, ok)]
    roots = [_xyz(r) if np.isfinite(r).all() else None for r in pose_roots(f.poses)]
    return {"frame": f.frame, "ids": [int(i) for i in f.ids], "poses": poses, "roots": roots}


def _scene_points(frames: list[SequenceFrame], rig: Rig) -> np.ndarray:
    """Every valid joint of every frame, the camera centres and the origin -> (N, 3)."""
    pts = [np.zeros((1, 3))] + [c.center[None] for c in rig]
    pts += [f.poses[valid_joints(f.poses)][:, :3] for f in frames]
    return np.concatenate(pts)


def grid_spec(points: np.ndarray) -> dict:
    """The ground grid on z = 0 under points (N, 3): {"min": [x, y], "max": [x, y], "step": s} (m)."""
    lo, hi = points[:, :2].min(axis=0) - GRID_MARGIN_M, points[:, :2].max(axis=0) + GRID_MARGIN_M
    span = float((hi - lo).max())
    step = next((s for s in GRID_STEPS_M if span / s <= GRID_MAX_LINES), GRID_STEPS_M[-1])
    lo, hi = np.floor(lo / step) * step, np.ceil(hi / step) * step
    return {"min": _xyz(lo[:2]), "max": _xyz(hi[:2]), "step": step}


def camera_glyph(camera: Camera, depth: float) -> dict:
    """A camera as drawn: name, centre and the four image corners' rays at ``depth`` m: corners (4, 3)."""
    w, h = camera.size
    pixels = np.array([[0.0, 0.0, 1.0], [w, 0.0, 1.0], [w, h, 1.0], [0.0, h, 1.0]])
    rays = pixels @ np.linalg.inv(camera.K).T  # camera frame, z = 1: depth along the optical axis
    corners = camera.center + depth * rays @ camera.R  # R^T ray per row
    return {"name": camera.name, "center": _xyz(camera.center), "corners": [_xyz(c) for c in corners]}


def sequence_document(
    frames: list[SequenceFrame], tracked: bool, rig: Rig, every: int = 1, id_note: str | None = None
) -> dict:
    """The JSON the page draws: frames (every k-th), limbs, cameras, grid, colours per id, initial view."""
    points = _scene_points(frames, rig)
    lo, hi = points.min(axis=0), points.max(axis=0)
    extent = float(np.linalg.norm(hi - lo))
    centre = (lo + hi) / 2
    target = [float(centre[0]), float(centre[1]), float(np.clip(centre[2], 0.0, 1.0))]  # about body height
    radius = float(np.linalg.norm(points - np.asarray(target), axis=1).max())
    shown = frames[::every]
    colors = id_colors(i for f in frames for i in f.ids)
    note = id_note if id_note is not None else ("" if tracked else UNTRACKED_NOTE)
    if every > 1:
        note = (note + "; " if note else "") + (
            f"one frame in {every} of {len(frames)} shown (the page's size cap: vis_sequence_max_mb, --max-mb)"
        )
    return {
        "units": "m",
        "keypoints": list(COCO23_NAMES),
        "limbs": [list(limb) for limb in LIMBS],
        "tracked": tracked,
        "note": note,
        "every": every,
        "num_frames": len(frames),
        "fps": PLAY_FPS,
        "colors": {str(i): hex_color(c) for i, c in colors.items()},
        "cameras": [camera_glyph(c, FRUSTUM_FRACTION * extent) for c in rig],
        "grid": grid_spec(points),
        "view": {"target": _xyz(target), "radius": round(radius, DECIMALS)},
        "frames": [_frame_entry(f) for f in shown],
    }


def _embed(doc: dict) -> str:
    """JSON safe inside a <script> element: every '<' escaped, so no '</script>' can close it."""
    return json.dumps(doc, separators=(",", ":")).replace("<", "\\u003c")


def sequence_html(
    frames: Iterable[tuple],
    rig: Rig,
    title: str = "sequence",
    max_mb: float = DEFAULT_MAX_MB,
    id_note: str | None = None,
) -> str:
    """The page of (frame, poses (P, 23, 4), ids (P,) or None) tuples; every k-th frame (smallest k) within max_mb."""
    seq, tracked = sequence_frames(frames)
    if not seq:
        raise ValueError("no frames to show")
    page = TEMPLATE.read_text(encoding="utf-8").replace(TITLE_MARK, html.escape(title))
    budget, every = max_mb * 1e6 - len(page), 1
    while True:
        data = _embed(sequence_document(seq, tracked, rig, every, id_note))
        if len(data) <= budget or every >= len(seq):
            return page.replace(DATA_MARK, data)
        every = max(every + 1, math.ceil(every * len(data) / max(budget, 1.0)))


def write_sequence_html(path: str | Path, frames: Iterable[tuple], rig: Rig, **options: Any) -> Path:
    """Write the viewer of (frame, poses (P, 23, 4), ids (P,) or None) tuples atomically (options: of sequence_html)."""
    atomic_write_text(path, sequence_html(frames, rig, **options))
    return Path(path)
