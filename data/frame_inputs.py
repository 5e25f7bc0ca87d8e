"""Each frame's detections checked against each other before matching (``inputs``): caps, repeats, near-duplicates."""

from __future__ import annotations

import warnings
from collections import Counter
from dataclasses import replace

import numpy as np

from data.config_checks import ConfigError
from data.multiview import Sequence, ViewDetections

EXACT = "exact duplicates dropped"
NEAR = "near-duplicates merged"


class InputWarning(UserWarning):
    """2D input repaired on the way in; the message (one line) names what and how often."""


def person_size(keypoints: np.ndarray) -> np.ndarray:
    """Diagonal (px) of the box around each detection's scored joints, 0 without any: (N, J, 3) -> (N,)."""
    scored = keypoints[..., 2:] > 0
    lo = np.where(scored, keypoints[..., :2], np.inf).min(axis=1)
    hi = np.where(scored, keypoints[..., :2], -np.inf).max(axis=1)
    return np.sqrt((np.maximum(hi - lo, 0.0) ** 2).sum(axis=-1))  # -inf without any: 0


def near_pairs(keypoints: np.ndarray, near: float) -> np.ndarray:
    """Whether i's mean joint distance to j is within near x j's person_size: (N, J, 3) -> (N, N), diagonal False."""
    size, rows = person_size(keypoints), []
    for start in range(0, len(keypoints), 64):  # row blocks bound the (rows, N, J) distances' memory
        a, b = keypoints[start : start + 64, None], keypoints[None]
        both = (a[..., 2] > 0) & (b[..., 2] > 0)
        dist = np.where(both, np.sqrt(((a[..., :2] - b[..., :2]) ** 2).sum(axis=-1)), 0.0).sum(axis=-1)
        rows.append(both.any(axis=-1) & (dist <= near * size * both.sum(axis=-1)))
    same = np.concatenate(rows) if rows else np.zeros((0, 0), dtype=bool)
    return same & ~np.eye(len(same), dtype=bool)


def merge_duplicates(view: ViewDetections, near: float) -> tuple[ViewDetections, int, int]:
    """One view's detections (N, J, 3) without repeats -> (M, J, 3), exact and near counts; the kept keep order."""
    kp, same = view.keypoints, near_pairs(view.keypoints, near)
    if not same.any():
        return view, 0, 0
    merged, keep, exact = kp.copy(), [], 0  # a copy: the caller's arrays stay as they are
    for i in np.argsort(-view.scores, kind="stable"):
        j = next((j for j in keep if same[i, j]), None)
        if j is None:
            keep.append(i)
            continue
        exact += np.array_equal(kp[i], kp[j])
        merged[j] = np.where(kp[i, :, 2:] > merged[j, :, 2:], kp[i], merged[j])
    keep = sorted(keep)
    out = ViewDetections(merged[keep], view.bboxes[keep], view.scores[keep], view.person_ids[keep], view.occluded[keep])
    return out, exact, len(kp) - len(keep) - exact


def clean_frames(sequence: Sequence, max_detections: int, near: float) -> tuple[Sequence, Counter]:
    """The sequence with each view's repeats merged, and their counts; ConfigError for a frame over max_detections."""
    counts: Counter = Counter()
    frames, first = [], None
    for frame in sequence.frames:
        total = sum(len(v) for v in frame.views)
        if total > max_detections:
            raise ConfigError(
                f"frame {frame.index} has {total} detections over {len(frame.views)} views, more than "
                f"inputs.max_detections_per_frame={max_detections} (a detector without non-maximum suppression?)"
            )
        views = []
        for name, view in zip(sequence.rig.names, frame.views):
            view, exact, close = merge_duplicates(view, near)
            counts.update({EXACT: exact, NEAR: close})
            first = first or (exact and f"frame {frame.index}, camera {name!r}")
            views.append(view)
        frames.append(replace(frame, views=views))
    if first:
        warnings.warn(
            f"exact repeats of a detection dropped: {counts[EXACT]} (same frame, camera and keypoints: a detector "
            f"or an export run twice?), the first in {first}",
            InputWarning,
            stacklevel=2,
        )
    return replace(sequence, frames=frames), +counts
