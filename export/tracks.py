"""Each track of a poses3d.json on the file's frame grid, the shared conventions of the exporters, and --fill.

Grid: every frame number from the file's first to its last at the file's step (the greatest common divisor of
its frame-number differences, usually 1), so the files of all tracks of one run stay in step; time = frame / fps,
fps: --fps, else the file's "fps" (written by runs on videos), else 30.
Missing (score 0, or the track absent from the frame) is NaN. ``--fill`` interpolates each joint linearly over
the frames between two of its observations (a track absent from a frame included), never before its first or
after its last; the filled joints keep score 0. Y-up files (BVH, TRC) take OpenSim's / Pose2Sim's rotation of
our z-up world: (X, Y, Z) = (y, z, x).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from functools import reduce
from pathlib import Path

import numpy as np

from data.formats.poses_io import read_poses3d_file
from data.keypoints import NUM_JOINTS

MAX_GRID_FRAMES = 1_000_000  # frame numbers spread wider than this are refused (the grid would not fit in memory)


@dataclass(frozen=True)
class Track:
    """One track id: frames (T,), xyz (T, 23, 3) m world z up (NaN: missing), score (T, 23), present (T,) bool;
    step and fps (the file's "fps", None without it) are the file's."""

    id: int
    frames: np.ndarray
    xyz: np.ndarray
    score: np.ndarray
    present: np.ndarray
    step: int
    fps: float | None = None


def read_tracks(path: str | Path, track: int | None = None) -> list[Track]:
    """The tracks (or the one id) of poses3d.json on the grid; ValueError with one line for bad input."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    try:
        frames, fps = read_poses3d_file(path)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"{path}: not a poses3d.json ({str(e).removeprefix(f'{path}: ')})") from None
    ids = sorted({int(i) for _, _, frame_ids in frames for i in frame_ids})
    if not ids:
        raise ValueError(f"{path}: no poses to export")
    if track is not None and track not in ids:
        raise ValueError(f"{path}: no track id {track} (ids: {', '.join(map(str, ids))})")
    numbers = sorted({f for f, _, _ in frames})
    step = reduce(math.gcd, np.diff(numbers).tolist(), 0) or 1
    grid = np.arange(numbers[0], numbers[-1] + 1, step)
    if len(grid) > MAX_GRID_FRAMES:
        raise ValueError(f"{path}: frame numbers {numbers[0]}..{numbers[-1]} span over {MAX_GRID_FRAMES} frames")
    return [replace(_track(frames, grid, tid, step), fps=fps) for tid in (ids if track is None else [track])]


def _track(frames: list, grid: np.ndarray, tid: int, step: int) -> Track:
    """One id's arrays from read_poses3d_frames' [(frame, (P, 23, 4), ids (P,))]."""
    xyz, score, present = np.full((len(grid), NUM_JOINTS, 3), np.nan), np.zeros((len(grid), NUM_JOINTS)), []
    for frame, poses, ids in frames:
        for pose in poses[ids == tid][:1]:
            k, seen = (frame - grid[0]) // step, pose[:, 3] > 0
            xyz[k, seen], score[k] = pose[seen, :3], np.where(seen, pose[:, 3], 0.0)
            present.append(k)
    return Track(tid, grid, xyz, score, np.isin(np.arange(len(grid)), present), step)


def fill_gaps(track: Track) -> Track:
    """--fill: each joint linearly interpolated over the frames between two of its observations (T, 23, 3)."""
    xyz, k = track.xyz.copy(), np.arange(len(track.frames))
    for j in range(NUM_JOINTS):
        seen = np.isfinite(xyz[:, j]).all(axis=1)
        if seen.any():
            inside = ~seen & (k > k[seen][0]) & (k < k[seen][-1])
            xyz[inside, j] = np.stack([np.interp(k[inside], k[seen], xyz[seen, j, c]) for c in range(3)], axis=1)
    return replace(track, xyz=xyz)


def to_y_up(xyz: np.ndarray) -> np.ndarray:
    """Our z-up world to the Y-up axes of BVH and TRC, (X, Y, Z) = (y, z, x): (..., 3) -> (..., 3)."""
    return np.asarray(xyz)[..., [1, 2, 0]]


def track_path(base: Path, track: Track, suffix: str) -> Path:
    """<base>_id<k>.<suffix>, one file per track."""
    return base.with_name(f"{base.name}_id{track.id}.{suffix}")
