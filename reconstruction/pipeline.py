"""The multi-view pipeline of one frame: matching -> gathering -> reconstruction, with stage timings."""
from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass
from typing import Callable

import numpy as np

from data.multiview import Frame, ViewDetections
from reconstruction.camera import Rig

Matcher = Callable[[list[ViewDetections], Rig], np.ndarray]
Reconstructor = Callable[[np.ndarray, np.ndarray, Rig], np.ndarray]


@dataclass
class FrameResult:
    """poses3d (P, J, 4): x, y, z (m) and confidence; assignment (P, V): detection index per view or -1."""

    frame: int
    poses3d: np.ndarray
    assignment: np.ndarray


def gather_views(views: list[ViewDetections], assignment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stack the matched detections: V views, (P, V) -> poses2d (V, P, J, 3), bboxes (V, P, 4).

    Views where a person has no detection get score 0 and an all-zero box; a joint with a non-finite
    coordinate or score (a detector's NaN) is missing too (x, y, score 0).
    """
    P, V = assignment.shape
    J = next((v.keypoints.shape[1] for v in views if len(v)), 23)
    poses2d = np.zeros((V, P, J, 3))
    bboxes = np.zeros((V, P, 4))
    for v, dets in enumerate(views):
        have = assignment[:, v] >= 0
        poses2d[v, have] = dets.keypoints[assignment[have, v]]
        bboxes[v, have] = dets.bboxes[assignment[have, v]]
    poses2d = np.where(np.isfinite(poses2d).all(axis=-1, keepdims=True), poses2d, 0.0)
    return poses2d, np.nan_to_num(bboxes, nan=0.0, posinf=0.0, neginf=0.0)


class MultiViewPipeline:
    """Match persons across views, then reconstruct them; accumulates seconds per stage."""

    def __init__(self, rig: Rig, matcher: Matcher, reconstructor: Reconstructor) -> None:
        self.rig = rig
        self.matcher = matcher
        self.reconstructor = reconstructor
        self.timings: dict[str, float] = defaultdict(float)

    def __call__(self, frame: Frame) -> FrameResult:
        """Reconstruct one frame: Frame with V views -> FrameResult."""
        if len(frame.views) != len(self.rig):
            raise ValueError(f"frame {frame.index} has {len(frame.views)} views, the rig {len(self.rig)}")
        t0 = time.perf_counter()
        assignment = self.matcher(frame.views, self.rig)
        t1 = time.perf_counter()
        poses2d, bboxes = gather_views(frame.views, assignment)
        poses3d = self.reconstructor(poses2d, bboxes, self.rig) if len(assignment) else np.zeros((0, poses2d.shape[2], 4))
        t2 = time.perf_counter()
        self.timings["matching"] += t1 - t0
        self.timings["reconstruction"] += t2 - t1
        return FrameResult(frame.index, poses3d, assignment)
