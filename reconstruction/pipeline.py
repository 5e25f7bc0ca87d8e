"""The multi-view pipeline of one frame: matching -> gathering -> reconstruction [-> tracking], with stage timings."""

from __future__ import annotations

import time
from collections import Counter, defaultdict
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Callable, Protocol

import numpy as np
from hydra.utils import instantiate

from data.geometry.camera import Rig
from data.multiview import Frame, ViewDetections
from reconstruction.gather_kernels import gather_detections
from reconstruction.results import Matches, Reconstruction, SkeletonPrior

Matcher = Callable[[list[ViewDetections], Rig], Matches]
Reconstructor = Callable[[np.ndarray, np.ndarray, Rig], Reconstruction]


class Tracker(Protocol):
    """What the pipeline needs of a tracker (tracking.Tracker): frame number, poses (P, J, 4), per-joint
    variances (P, J) or None -> (ids (P,), poses (P, J, 4))."""

    def update(
        self,
        frame: int,
        poses3d: np.ndarray,
        variance: np.ndarray | None = None,
        bone_lengths: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass
class FrameResult:
    """poses3d (P, J, 4): x, y, z (m) and confidence; assignment (P, V): detection index per view or -1;
    ids (P,): the persons' track ids with a tracker, else None (the index in the frame is the id)."""

    frame: int
    poses3d: np.ndarray
    assignment: np.ndarray
    ids: np.ndarray | None = None


def gather_views(views: list[ViewDetections], assignment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stack the matched detections: V views, (P, V) -> poses2d (V, P, J, 3), bboxes (V, P, 4).

    Views where a person has no detection get score 0 and an all-zero box; a joint with a non-finite
    coordinate or score (a detector's NaN) is missing too (x, y, score 0).
    """
    J = next((v.keypoints.shape[1] for v in views if len(v)), 23)
    counts = [len(v) for v in views]
    keypoints = np.concatenate([np.asarray(v.keypoints, dtype=np.float64).reshape(-1, J, 3) for v in views])
    boxes = np.concatenate([np.asarray(v.bboxes, dtype=np.float64).reshape(-1, 4) for v in views])
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return gather_detections(keypoints, boxes, offsets, np.ascontiguousarray(assignment, dtype=np.int64))


@lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile (or load from numba's cache) the gather's kernel once per process, before a first frame is timed."""
    gather_detections(np.ones((1, 2, 3)), np.ones((1, 4)), np.array([0, 1]), np.zeros((1, 1), dtype=np.int64))


class MultiViewPipeline:
    """Match persons across views, reconstruct them, then (with a tracker) give them track ids; accumulates
    seconds per stage. One pipeline serves one sequence: a tracker expects increasing frame numbers."""

    def __init__(
        self, rig: Rig, matcher: Matcher, reconstructor: Reconstructor, tracker: Tracker | None = None
    ) -> None:
        self.rig = rig
        self.matcher = matcher
        self.reconstructor = reconstructor
        self.tracker = tracker
        self.timings: dict[str, float] = defaultdict(float)
        self.unmatched: Counter[str] = Counter()  # detections the matcher left out of every person, by reason

    @classmethod
    def from_config(cls, cfg: Any, rig: Rig) -> "MultiViewPipeline":
        """The pipeline of an eval.yaml config: cfg.matching, cfg.reconstruction and, unless tracking=off (a
        group entry without ``_target_``), cfg.tracking, each built by Hydra's instantiate."""
        tracker = instantiate(cfg.tracking) if cfg.tracking.get("_target_") else None
        return cls(rig, instantiate(cfg.matching), instantiate(cfg.reconstruction), tracker)

    def _reconstruct(self, frame: int, poses2d: np.ndarray, bboxes: np.ndarray) -> Reconstruction:
        """The reconstruction of a frame: (V, P, J, 3), (V, P, 4) -> Reconstruction; one that takes a skeleton prior
        (the adaptive MAP) gets the tracker's bone lengths of the tracks its persons would join."""
        if self.tracker is not None and getattr(self.reconstructor, "takes_skeleton_prior", False):
            first = self.reconstructor.first_pass(poses2d, bboxes, self.rig)
            prior = SkeletonPrior(*self.tracker.skeletons(frame, first.poses)) if len(first.poses) else None
            return self.reconstructor.finish(first, prior)
        return self.reconstructor(poses2d, bboxes, self.rig)

    def __call__(self, frame: Frame) -> FrameResult:
        """Reconstruct one frame: Frame with V views -> FrameResult."""
        if len(frame.views) != len(self.rig):
            raise ValueError(f"frame {frame.index} has {len(frame.views)} views, the rig {len(self.rig)}")
        t0 = time.perf_counter()
        matches = self.matcher(frame.views, self.rig)
        self.unmatched += matches.unmatched
        assignment = matches.assignment
        t1 = time.perf_counter()
        poses2d, bboxes = gather_views(frame.views, assignment)
        if len(assignment):
            result = self._reconstruct(frame.index, poses2d, bboxes)
        else:
            result = Reconstruction(np.zeros((0, poses2d.shape[2], 4)))
        poses3d = result.poses
        t2 = time.perf_counter()
        ids = None
        if self.tracker is not None:
            ids, poses3d = self.tracker.update(frame.index, poses3d, result.joint_variance, result.bone_lengths)
        self.timings["matching"] += t1 - t0
        self.timings["reconstruction"] += t2 - t1
        if self.tracker is not None:
            self.timings["tracking"] += time.perf_counter() - t2
        return FrameResult(frame.index, poses3d, assignment, ids)
