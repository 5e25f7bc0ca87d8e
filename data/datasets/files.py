"""Your own rig: a calibration (any format :func:`data.geometry.calibration.load_rig` reads) and a poses2d.json
turned into a Sequence without ground truth, checked by :mod:`data.geometry.check_rig` with the 2D poses.
A selected frame without any detection stays a frame, so a detector's output can be scored over a fixed range.
"""

from __future__ import annotations

from pathlib import Path

from data.formats.poses2d_io import read_poses2d
from data.geometry.calibration import load_rig
from data.geometry.check_rig import check_rig
from data.multiview import Frame, Sequence, ViewDetections


def load_files(cameras: str | Path, poses2d: str | Path, frames: list[int] | str | None = None) -> Sequence:
    """The rig of ``cameras`` and one Frame per frame number with V ViewDetections (N, 23, 3).

    ``frames``: None = those of the file, a list, or "start:stop[:step]"; frames outside it are counted in
    ``meta["frames_not_selected"]``.
    """
    rig = load_rig(cameras, check=False)
    if not Path(poses2d).is_file():
        raise FileNotFoundError(f"{poses2d}: poses2d.json not found")
    views = read_poses2d(poses2d, rig.names, [c.size for c in rig])
    check_rig(rig, cameras, views)  # load_rig ran the geometric checks; this adds the 2D poses against the rig
    numbers = sorted(views) if frames is None else _frame_numbers(frames)
    empty = [f for f in numbers if f not in views]
    out = [Frame(f, views.get(f) or [ViewDetections.empty() for _ in rig.names]) for f in numbers]
    detections = sum(len(v) for f in numbers for v in views.get(f, []))
    meta = {
        "dataset": "files",
        "cameras": str(cameras),
        "poses2d": str(poses2d),
        "frames_without_detections": len(empty),
        "frames_not_selected": len(set(views) - set(numbers)),
    }
    description = f"{poses2d} ({detections} detections; {len(empty)} frames without any) on {cameras}, no ground truth"
    return Sequence(rig, out, meta, description=description)


def _frame_numbers(frames: list[int] | str) -> list[int]:
    """Frame numbers of a list, or of a "start:stop[:step]" range string."""
    if isinstance(frames, str):
        try:
            parts = [int(p) for p in frames.split(":")]
            if len(parts) not in (2, 3):
                raise ValueError
            return list(range(*parts))
        except ValueError:
            raise ValueError(f"frames={frames!r}: expected a list of frame numbers or 'start:stop[:step]'") from None
    try:
        return sorted({int(f) for f in frames})
    except (TypeError, ValueError):
        raise ValueError(f"frames={frames!r}: expected a list of frame numbers or 'start:stop[:step]'") from None
