"""Ungrouped OpenPose BODY_25 detections as stored by 4D Association (shelf/4d_association/detection/*.txt).

Each frame holds, per BODY_25 joint, its candidates (x, y, score) and, per part-affinity limb, the
matrix of PAF scores between the candidates of the limb's two joints. See ../shared/data/PROVENANCE.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

BODY25_NUM_JOINTS = 25
BODY25_SKELETON_TYPE = 4  # the header's skeleton id for BODY_25 in 4D Association's files

# The 26 BODY_25 part-affinity limbs (joint a, joint b) in the order of the file (and of OpenPose).
BODY25_PAF_LIMBS: tuple[tuple[int, int], ...] = (
    (1, 8),
    (9, 10),
    (10, 11),
    (8, 9),
    (8, 12),
    (12, 13),
    (13, 14),
    (1, 2),
    (2, 3),
    (3, 4),
    (2, 17),
    (1, 5),
    (5, 6),
    (6, 7),
    (5, 18),
    (1, 0),
    (0, 15),
    (0, 16),
    (15, 17),
    (16, 18),
    (14, 19),
    (19, 20),
    (14, 21),
    (11, 22),
    (22, 23),
    (11, 24),
)


@dataclass
class FrameCandidates:
    """One camera frame of ungrouped detections.

    candidates: 25 arrays (n_j, 3), x, y in pixels and score, one per BODY_25 joint.
    pafs: 26 arrays (n_a, n_b), PAF scores between the candidates of limb (a, b) of BODY25_PAF_LIMBS.
    """

    candidates: list[np.ndarray]
    pafs: list[np.ndarray]


class _Reader:
    """Walks the numbers of one file; NaN marks a token that was not a number."""

    def __init__(self, path: Path, values: np.ndarray) -> None:
        self.path, self.values, self.pos = path, values, 0
        bad = np.flatnonzero(~np.isfinite(values))
        self.first_bad = int(bad[0]) if len(bad) else len(values)  # one check per take, not a scan

    def take(self, n: int, where: str) -> np.ndarray:
        """The next n numbers (n,), checked to exist and be finite; `where` names them in errors."""
        if self.pos + n > len(self.values):
            raise ValueError(f"{self.path}: file ends while reading {where}")
        if self.first_bad < self.pos + n:
            raise ValueError(f"{self.path}: non-numeric or non-finite value in {where}")
        out = self.values[self.pos : self.pos + n]
        self.pos += n
        return out

    def count(self, where: str) -> int:
        """The next number as a non-negative integer count."""
        value = self.take(1, where)[0]
        if value < 0 or value != int(value):
            raise ValueError(f"{self.path}: {where} is {value:g}, expected a non-negative integer")
        return int(value)


def _numbers(path: Path) -> np.ndarray:
    """All whitespace-separated tokens of a file as floats (T,); non-numbers become NaN."""
    try:
        tokens = path.read_text().split()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read detection file ({exc})") from None
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        return np.array([_float_or_nan(t) for t in tokens], dtype=np.float64)


def _float_or_nan(token: str) -> float:
    """float(token), NaN where it is not a number."""
    try:
        return float(token)
    except ValueError:
        return float("nan")


def _read_frame(reader: _Reader, frame: int, scale: np.ndarray) -> FrameCandidates:
    """One frame: 25 candidate blocks then 26 PAF matrices."""
    candidates, sizes = [], []
    for j in range(BODY25_NUM_JOINTS):
        where = f"frame {frame}, joint {j}"
        n = reader.count(f"the candidate count of {where}")
        xys = reader.take(3 * n, f"the candidates of {where}").reshape(3, n).T * scale
        candidates.append(xys)
        sizes.append(n)
    pafs = []
    for k, (a, b) in enumerate(BODY25_PAF_LIMBS):
        where = f"frame {frame}, PAF limb {k} ({a}, {b})"
        pafs.append(reader.take(sizes[a] * sizes[b], where).reshape(sizes[a], sizes[b]).copy())
    return FrameCandidates(candidates, pafs)


def load_4dassoc_detections(path: str | Path, image_size: tuple[int, int] = (1032, 776)) -> list[FrameCandidates]:
    """Read a 4D Association detection file: per frame 25 candidate arrays (n_j, 3) px and 26 PAFs (n_a, n_b).

    image_size (w, h) converts the file's normalised coordinates: pixel = x * (w - 1), y * (h - 1).
    """
    path = Path(path)
    reader = _Reader(path, _numbers(path))
    skeleton = reader.count("the header's skeleton type")
    if skeleton != BODY25_SKELETON_TYPE:
        raise ValueError(f"{path}: header skeleton type is {skeleton}, expected {BODY25_SKELETON_TYPE} (BODY_25)")
    num_frames = reader.count("the header's frame count")
    scale = np.array([image_size[0] - 1, image_size[1] - 1, 1.0])
    frames = [_read_frame(reader, f, scale) for f in range(num_frames)]
    if reader.pos != len(reader.values):
        raise ValueError(
            f"{path}: {len(reader.values) - reader.pos} numbers left after the {num_frames} frames of the header"
        )
    return frames
