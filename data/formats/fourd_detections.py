"""Ungrouped OpenPose BODY_25 detections as stored by 4D Association (shelf/4d_association/detection/*.txt)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

BODY25_NUM_JOINTS = 25
BODY25_SKELETON_TYPE = 4  # the header's skeleton id for BODY_25 in 4D Association's files

# The 26 BODY_25 part-affinity limbs (joint a, joint b) in the order of the file (and of OpenPose).
# fmt: off
BODY25_PAF_LIMBS: tuple[tuple[int, int], ...] = (
    (1, 8), (9, 10), (10, 11), (8, 9), (8, 12), (12, 13), (13, 14), (1, 2), (2, 3), (3, 4), (2, 17), (1, 5), (5, 6),
    (6, 7), (5, 18), (1, 0), (0, 15), (0, 16), (15, 17), (16, 18), (14, 19), (19, 20), (14, 21), (11, 22), (22, 23),
    (11, 24),
)
# fmt: on
BODY25_LIMB_ARRAY = np.array(BODY25_PAF_LIMBS, dtype=np.int64)  # the limbs as (26, 2) joint pairs


@dataclass
class PackedCandidates:
    """A frame's candidates and PAFs as four flat arrays (what the compiled grouping reads)."""

    points: np.ndarray  # (M, 3): joint j's candidates at points[joint_start[j]:joint_start[j + 1]]
    joint_start: np.ndarray  # (J + 1,)
    paf_values: np.ndarray  # (K,): limb k's PAF matrix, row-major, at paf_values[paf_start[k]:paf_start[k + 1]]
    paf_start: np.ndarray  # (L + 1,)


@dataclass
class FrameCandidates:
    """One camera frame of ungrouped detections."""

    candidates: list[np.ndarray]  # 25 arrays (n_j, 3): x, y px, score, one per BODY_25 joint
    pafs: list[np.ndarray]  # 26 arrays (n_a, n_b): PAF scores between the candidates of limb (a, b)
    packed: PackedCandidates | None = field(default=None, repr=False)  # the same numbers (None: built on use)


class _Layout:
    """Where each frame's blocks lie in a file's numbers, found in one pass over the counts; errors name the block."""

    def __init__(self, path: Path, values: np.ndarray) -> None:
        self.path, self.values, self.pos = path, values, 0
        self.numbers = values.tolist()  # Python floats: the per-count walk indexes a list, not numpy scalars
        bad = np.flatnonzero(~np.isfinite(values))
        self.first_bad = int(bad[0]) if len(bad) else len(values)

    def skip(self, n: int, where: str, *args: object) -> int:
        """Skip the next n numbers, checked to exist and be finite -> their start; errors name where.format(*args)."""
        start, self.pos = self.pos, self.pos + n
        if self.pos > len(self.numbers):
            raise ValueError(f"{self.path}: file ends while reading {where.format(*args)}")
        if self.first_bad < self.pos:
            raise ValueError(f"{self.path}: non-numeric or non-finite value in {where.format(*args)}")
        return start

    def count(self, where: str, *args: object) -> int:
        """The next number as a non-negative integer count."""
        value = self.numbers[self.skip(1, where, *args)]
        if value < 0 or value != int(value):
            raise ValueError(f"{self.path}: {where.format(*args)} is {value:g}, expected a non-negative integer")
        return int(value)

    def frames(self, num_frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Walk num_frames frames: cand_pos (F, 25) of each x block (then y, score), counts (F, 25), paf_pos (F, 26)."""
        return self._frames_unchecked(num_frames) or self._frames_checked(num_frames)

    def _frames_unchecked(self, num_frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """:meth:`frames` of a well-formed file in one tight loop; None at the first problem, for _frames_checked."""
        numbers, pos, end = self.numbers, self.pos, min(len(self.numbers), self.first_bad)
        J, limbs = BODY25_NUM_JOINTS, BODY25_PAF_LIMBS
        cand_pos, counts, paf_pos = [0] * (num_frames * J), [0] * (num_frames * J), [0] * (num_frames * len(limbs))
        for f in range(num_frames):
            base, paf_base = f * J, f * len(limbs)
            for j in range(J):
                if pos >= end:
                    return None
                value = numbers[pos]
                n = int(value)
                if n < 0 or n != value:
                    return None
                cand_pos[base + j], counts[base + j] = pos + 1, n
                pos += 1 + 3 * n
            for k, (a, b) in enumerate(limbs):
                paf_pos[paf_base + k] = pos
                pos += counts[base + a] * counts[base + b]
            if pos > end:
                return None
        self.pos = pos
        shape = (num_frames, J)
        return (
            np.array(cand_pos, dtype=np.int64).reshape(shape),
            np.array(counts, dtype=np.int64).reshape(shape),
            np.array(paf_pos, dtype=np.int64).reshape(num_frames, len(limbs)),
        )

    def _frames_checked(self, num_frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`frames` block by block, each checked: an error names the first bad block."""
        cand_pos = np.zeros((num_frames, BODY25_NUM_JOINTS), dtype=np.int64)
        counts = np.zeros_like(cand_pos)
        paf_pos = np.zeros((num_frames, len(BODY25_PAF_LIMBS)), dtype=np.int64)
        for f in range(num_frames):
            sizes = []
            for j in range(BODY25_NUM_JOINTS):
                n = self.count("the candidate count of frame {}, joint {}", f, j)
                cand_pos[f, j] = self.skip(3 * n, "the candidates of frame {}, joint {}", f, j)
                sizes.append(n)
            counts[f] = sizes
            for k, (a, b) in enumerate(BODY25_PAF_LIMBS):
                paf_pos[f, k] = self.skip(sizes[a] * sizes[b], "frame {}, PAF limb {} ({}, {})", f, k, a, b)
        return cand_pos, counts, paf_pos


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


def load_4dassoc_detections(path: str | Path, image_size: tuple[int, int] = (1032, 776)) -> list[FrameCandidates]:
    """A 4D Association detection file -> per frame 25 candidates (n_j, 3) px (x (w - 1), y (h - 1)), 26 PAFs."""
    path = Path(path)
    layout = _Layout(path, _numbers(path))
    skeleton = layout.count("the header's skeleton type")
    if skeleton != BODY25_SKELETON_TYPE:
        raise ValueError(f"{path}: header skeleton type is {skeleton}, expected {BODY25_SKELETON_TYPE} (BODY_25)")
    num_frames = layout.count("the header's frame count")
    cand_pos, counts, paf_pos = layout.frames(num_frames)
    left = len(layout.values) - layout.pos
    if left:
        raise ValueError(f"{path}: {left} numbers left after the {num_frames} frames of the header")
    points = _candidate_points(layout.values, cand_pos.ravel(), counts.ravel(), image_size)
    ends = np.cumsum(counts, axis=1)
    first = np.concatenate([[0], ends[:-1, -1].cumsum()]) if num_frames else np.zeros(0, dtype=np.int64)
    frames = []
    paf_sizes = counts[:, BODY25_LIMB_ARRAY[:, 0]] * counts[:, BODY25_LIMB_ARRAY[:, 1]]
    for f in range(num_frames):
        joint_start = np.concatenate([[0], ends[f]])
        paf_start = np.concatenate([[0], np.cumsum(paf_sizes[f])])
        frame_points = points[first[f] : first[f] + joint_start[-1]]
        paf_values = layout.values[paf_pos[f, 0] : paf_pos[f, 0] + paf_start[-1]]  # a frame's PAFs lie in a row
        bounds, sizes, paf_bounds = joint_start.tolist(), counts[f].tolist(), paf_start.tolist()
        candidates = [frame_points[bounds[j] : bounds[j + 1]] for j in range(BODY25_NUM_JOINTS)]
        limbs = enumerate(BODY25_PAF_LIMBS)
        pafs = [paf_values[paf_bounds[k] : paf_bounds[k + 1]].reshape(sizes[a], sizes[b]) for k, (a, b) in limbs]
        frames.append(
            FrameCandidates(candidates, pafs, PackedCandidates(frame_points, joint_start, paf_values, paf_start))
        )
    return frames


def _candidate_points(
    values: np.ndarray, pos: np.ndarray, counts: np.ndarray, image_size: tuple[int, int]
) -> np.ndarray:
    """Every candidate of the file in block order: x, y, score blocks at pos (B,) of counts (B,) -> (sum counts, 3) px."""
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    x = np.repeat(pos, counts) + local
    n = np.repeat(counts, counts)
    scale = np.array([image_size[0] - 1, image_size[1] - 1, 1.0])
    return np.column_stack([values[x], values[x + n], values[x + 2 * n]]) * scale
