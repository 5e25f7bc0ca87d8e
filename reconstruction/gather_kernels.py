"""The compiled gather of matched detections (:func:`reconstruction.pipeline.gather_views`): one pass that copies
each person's detection per view and zeroes a detector's non-finite joints and box entries, where numpy took a
fancy-indexed copy per view and two passes over the result (a 100-person 7-view frame, timed alone: 98 -> 48 us
with the stacking in gather_views)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def gather_detections(
    keypoints: np.ndarray, boxes: np.ndarray, offsets: np.ndarray, assignment: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Detections stacked over V views (view v: rows offsets[v]:offsets[v + 1]) of keypoints (N, J, 3) and boxes
    (N, 4), a (P, V) assignment (-1 absent) -> poses2d (V, P, J, 3), bboxes (V, P, 4): zeros where absent, a joint
    with a non-finite entry all zeros, a non-finite box entry 0."""
    P, V = assignment.shape
    J = keypoints.shape[1]
    poses2d, bboxes = np.zeros((V, P, J, 3)), np.zeros((V, P, 4))
    for v in range(V):
        for p in range(P):
            d = assignment[p, v]
            if d < 0:
                continue
            row = offsets[v] + d
            for j in range(J):
                x, y, s = keypoints[row, j, 0], keypoints[row, j, 1], keypoints[row, j, 2]
                if np.isfinite(x) and np.isfinite(y) and np.isfinite(s):
                    poses2d[v, p, j, 0], poses2d[v, p, j, 1], poses2d[v, p, j, 2] = x, y, s
            for k in range(4):
                b = boxes[row, k]
                bboxes[v, p, k] = b if np.isfinite(b) else 0.0
    return poses2d, bboxes
