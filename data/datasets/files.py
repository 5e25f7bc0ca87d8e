"""Your own rig: a calibration (any load_rig format) and a poses2d.json as a Sequence without ground truth, checked."""

from __future__ import annotations

import sys
from bisect import bisect_left, bisect_right
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from data.formats.poses2d_io import read_poses2d
from data.geometry.calibration import load_rig
from data.geometry.check_rig import check_rig
from data.multiview import Frame, Sequence, ViewDetections

FRAMES_EXPECTED = "expected a list of frame numbers or 'start:stop[:step]'"


def load_files(
    cameras: str | Path,
    poses2d: str | Path,
    frames: list[int] | str | None = None,
    offsets: Mapping[str, int] | None = None,
) -> Sequence:
    """The rig of ``cameras`` and one Frame, V ViewDetections (N, 23, 3), per frame of poses2d or of ``frames``;
    camera c's detections of frame f + offsets[c] are its view of frame f."""
    rig = load_rig(cameras, check=False)
    shifts = camera_shifts(rig.names, offsets)
    if not Path(poses2d).is_file():
        raise FileNotFoundError(f"{poses2d}: poses2d.json not found")
    views = shifted(read_poses2d(poses2d, rig.names, [c.size for c in rig]), shifts)
    given = {name: s for name, s in zip(rig.names, shifts) if s}
    check_rig(rig, cameras, views, offsets=given)  # load_rig ran the geometric checks; this adds the 2D poses
    first, last = (min(views), max(views)) if views else (0, -1)
    if frames is None:
        numbers = sorted(views)
    elif isinstance(frames, str):
        numbers = list(clamped(frame_range(frames), first, last))
    else:
        numbers = sorted(set(frame_list(frames)))
    if not numbers:
        raise ValueError(f"frames={frames!r}: selects no frame ({poses2d} holds frames {first}..{last})")
    empty = [f for f in numbers if f not in views]
    out = [Frame(f, views.get(f) or [ViewDetections.empty() for _ in rig.names]) for f in numbers]
    detections = sum(len(v) for f in numbers for v in views.get(f, []))
    meta = {
        "dataset": "files",
        "cameras": str(cameras),
        "poses2d": str(poses2d),
        "frames_without_detections": len(empty),
        "frames_not_selected": len(set(views) - set(numbers)),
        "offsets": dict(zip(rig.names, shifts)),
    }
    description = f"{poses2d} ({detections} detections; {len(empty)} frames without any) on {cameras}, no ground truth"
    return Sequence(rig, out, meta, description=description)


def camera_shifts(names: list[str], offsets: Mapping[str, int] | None) -> list[int]:
    """Each camera's frame offset (V,), 0 where not given; a one-line ValueError for an unknown camera or a non-int."""
    if not isinstance(offsets, (Mapping, type(None))):
        raise ValueError(f"offsets={offsets!r}: a mapping camera -> frames (e.g. {{{names[-1]}: 3}}), or null")
    given = {str(name): shift for name, shift in (offsets or {}).items()}
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise ValueError(f"offsets: camera {unknown[0]!r} is not in the calibration (cameras {names})")
    for name, shift in given.items():
        if isinstance(shift, bool) or not isinstance(shift, (int, np.integer)):
            raise ValueError(f"offsets: camera {name!r}: {shift!r} is not an int number of frames")
    return [int(given.get(name, 0)) for name in names]


def shifted(views: dict[int, list[ViewDetections]], shifts: list[int]) -> dict[int, list[ViewDetections]]:
    """{frame f: V ViewDetections}, camera v's of frame f + shifts[v] as its view of frame f (empty without one)."""
    if not any(shifts):
        return views
    frames = sorted({f - s for f in views for v, s in enumerate(shifts) if len(views[f][v])})
    return {
        f: [views[f + s][v] if f + s in views else ViewDetections.empty() for v, s in enumerate(shifts)] for f in frames
    }


# --- the frames setting of the dataset loaders --------------------------------------------------------
def frame_range(frames: str, end: int | None = None) -> range:
    """The frame numbers of "start:stop[:step]"; with ``end``, an empty start, stop or step means 0, end or 1."""
    try:
        parts = [int(p) if p or end is None else None for p in frames.split(":")]
        if len(parts) not in (2, 3):
            raise ValueError
        return range(*(default if p is None else p for p, default in zip(parts, (0, end, 1))))
    except (TypeError, ValueError):
        raise ValueError(f"frames={frames!r}: {FRAMES_EXPECTED}") from None


def clamped(wanted: range, first: int, last: int) -> range:
    """The numbers of wanted within first..last (past them a range would run on empty frames); a line says so."""
    up = wanted if wanted.step > 0 else wanted[::-1]
    inside = up[bisect_left(up, first) : bisect_right(up, last)][:: 1 if wanted.step > 0 else -1]
    if 0 < len(inside) < len(wanted):
        print(f"warning: dataset.frames: {len(wanted)} frames clamped to the file's {first}..{last}", file=sys.stderr)
    return inside


def frame_list(frames: Iterable) -> list[int]:
    """A list of frame numbers as ints, in its order."""
    try:
        return [int(f) for f in frames]
    except (TypeError, ValueError):
        raise ValueError(f"frames={frames!r}: {FRAMES_EXPECTED}") from None


def position_slice(frames: str) -> slice:
    """The positions "start:stop[:step]" selects among the frames found (empty parts: the slice's defaults)."""
    try:
        positions = slice(*(int(p) if p.strip() else None for p in frames.split(":")))
        if positions.step == 0:
            raise ValueError
        return positions
    except (TypeError, ValueError):
        raise ValueError(f"frames={frames!r}: {FRAMES_EXPECTED}") from None
