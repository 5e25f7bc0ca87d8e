"""The multi-view pipeline of one frame: matching -> gathering -> reconstruction [-> tracking], with stage timings."""

from __future__ import annotations

import time
from collections import Counter, defaultdict
from dataclasses import dataclass
from typing import Any, Callable, Protocol

import numpy as np
from hydra.utils import instantiate

from data.geometry.camera import Rig
from data.multiview import Frame, ViewDetections
from reconstruction.coincident import merge_coincident
from reconstruction.noise_calibration import CalibratedNoiseModel, calibrate, describe
from reconstruction.results import Matches, Reconstruction, joint_sources
from tracking.tracker import Association, Tracker

Matcher = Callable[[list[ViewDetections], Rig], Matches]


class Reconstructor(Protocol):
    """A reconstruction stage: (V, P, J, 3), (V, P, 4), rig -> Reconstruction; one with ``takes_skeleton_prior``
    (the adaptive MAP) also offers ``first_pass`` and ``finish(first, prior)`` (reconstruction/solver/map_solver.py)."""

    takes_skeleton_prior: bool

    def __call__(self, poses2d: np.ndarray, bboxes: np.ndarray, rig: Rig) -> Reconstruction: ...


@dataclass
class FrameResult:
    """poses3d (P, J, 4): x, y, z (m) and confidence; assignment (P, V): detection index per view or -1;
    ids (P,): the persons' track ids with a tracker, else None (the index in the frame is the id); joint_views (P, J)
    int: the matched views that saw each joint; joint_source (P, J) int8: its provenance, codes into JOINT_SOURCES."""

    frame: int
    poses3d: np.ndarray
    assignment: np.ndarray
    ids: np.ndarray | None = None
    joint_views: np.ndarray | None = None
    joint_source: np.ndarray | None = None


def gather_views(views: list[ViewDetections], assignment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stack the matched detections of V views, (P, V) -> poses2d (V, P, J, 3), bboxes (V, P, 4): zeros where a person
    has no detection, and for a joint with a non-finite entry or a non-finite box entry (a detector's NaN)."""
    (P, V), J = assignment.shape, next((v.keypoints.shape[1] for v in views if len(v)), 23)
    counts = [len(v) for v in views]
    if not sum(counts) or not P:
        return np.zeros((V, P, J, 3)), np.zeros((V, P, 4))
    first = np.cumsum([0, *counts[:-1]])  # row of each view's first detection in the stacked arrays
    row = np.where(assignment >= 0, assignment + first, 0).T  # (V, P)
    have = (assignment >= 0).T[..., None]
    keypoints = np.concatenate([v.keypoints for v in views])[row]
    bboxes = np.concatenate([v.bboxes for v in views])[row]
    finite = np.isfinite(keypoints[..., 0]) & np.isfinite(keypoints[..., 1]) & np.isfinite(keypoints[..., 2])
    poses2d = np.where(have[..., None] & finite[..., None], keypoints, 0.0)  # not .all(-1): slow on an axis of 3
    return poses2d, np.where(have & np.isfinite(bboxes), bboxes, 0.0)


class MultiViewPipeline:
    """Match persons across views, reconstruct them, then (with a tracker) give them track ids; accumulates seconds
    per stage and the detections left unmatched by reason. One pipeline serves one sequence (frames increasing)."""

    def __init__(
        self,
        rig: Rig,
        matcher: Matcher,
        reconstructor: Reconstructor,
        tracker: Tracker | None = None,
        coincident_m: float = 0.3,
    ) -> None:
        self.rig, self.matcher, self.reconstructor, self.tracker = rig, matcher, reconstructor, tracker
        self.coincident_m = coincident_m  # reconstruction/coincident.py; 0: off
        self.timings: dict[str, float] = defaultdict(float)
        self.unmatched: Counter[str] = Counter()

    @classmethod
    def from_config(cls, cfg: Any, rig: Rig) -> MultiViewPipeline:
        """The pipeline of an eval.yaml config: cfg.matching, cfg.reconstruction and, unless tracking=off (a
        group entry without ``_target_``), cfg.tracking, each built by Hydra's instantiate; cfg.coincident_m."""
        tracker = instantiate(cfg.tracking) if cfg.tracking.get("_target_") else None
        coincident_m = cfg.get("coincident_m", 0.3)
        return cls(rig, instantiate(cfg.matching), instantiate(cfg.reconstruction), tracker, coincident_m)

    def calibrated_model(self) -> CalibratedNoiseModel | None:
        """The stages' self-calibrating noise model (noise_model=calibrated), None where it is fixed."""
        models = [getattr(stage, "noise_model", None) for stage in (self.matcher, self.reconstructor)]
        return next((m for m in models if isinstance(m, CalibratedNoiseModel)), None)

    def calibrate_noise(self, frames: list[Frame]) -> str | None:
        """Fit a self-calibrating 2D noise model (the stages', noise_model=calibrated) to the first frames and give
        it to both stages -> the report's line on it; None where the stages' model is fixed."""
        readers = [s for s in (self.matcher, self.reconstructor) if hasattr(s, "noise_model")]
        model = self.calibrated_model()
        if model is None:
            return None
        model, blocks, proj = model.fitted(None), None, self.rig.projection_matrices()  # a refit starts afresh
        fitted = model
        for _ in range(model.iterations):  # match with the last fit (the start model first), then fit again
            for stage in readers:
                stage.noise_model = fitted
            fitted, blocks = calibrate(model, [self._matched(frame) for frame in frames[: model.frames]], proj)
        for stage in readers:
            stage.noise_model = fitted
        return describe(fitted, self.rig.names, blocks, len(frames[: model.frames]))

    def _matched(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """The frame's matched persons: undistorted poses (V, P, J, 3) and boxes (V, P, 4)."""
        poses2d, bboxes = gather_views(frame.views, self.matcher(frame.views, self.rig).assignment)
        return self.rig.undistort(poses2d), bboxes

    def __call__(self, frame: Frame) -> FrameResult:
        """Reconstruct one frame: Frame with V views -> FrameResult."""
        if len(frame.views) != len(self.rig):
            raise ValueError(f"frame {frame.index} has {len(frame.views)} views, the rig {len(self.rig)}")
        t0 = time.perf_counter()
        matches = self.matcher(frame.views, self.rig)
        self.unmatched += matches.unmatched
        t1 = time.perf_counter()
        assignment, views, result, association = self._reconstruct_once(frame, matches.assignment)
        t2 = time.perf_counter()
        self.timings["matching"] += t1 - t0
        self.timings["reconstruction"] += t2 - t1
        if self.tracker is None:
            source = joint_sources(result.poses[..., 3], views, np.zeros(len(views), dtype=bool))
            return FrameResult(frame.index, result.poses, assignment, None, views, source)
        # the pairing the skeleton prior came from (on the first pass's poses) is kept, else the final poses decide
        if association is None or not self.tracker.skeleton_min_frames or association.count != len(result.poses):
            association = self.tracker.associate(frame.index, result.poses)
        tracked = self.tracker.update(association, result)
        self.timings["tracking"] += time.perf_counter() - t2
        source = joint_sources(tracked.poses3d[..., 3], views, tracked.smoothed)
        return FrameResult(frame.index, tracked.poses3d, assignment, tracked.ids, views, source)

    def _reconstruct_once(
        self, frame: Frame, assignment: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, Reconstruction, Association | None]:
        """Gather and reconstruct a frame's matched persons; where two coincide, join them and reconstruct again ->
        the final assignment (P, V), the views that saw each joint (P, J), Reconstruction and association (as
        _reconstruct)."""
        poses2d, bboxes = gather_views(frame.views, assignment)
        views = (poses2d[..., 2] > 0).sum(axis=0)  # gather_views zeroed the non-finite joints
        if not len(assignment):
            return assignment, views, Reconstruction(np.zeros((0, poses2d.shape[2], 4))), None
        result, association = self._reconstruct(frame.index, poses2d, bboxes)
        merged = merge_coincident(result.poses, views, assignment, self.coincident_m)
        if merged is assignment:
            return assignment, views, result, association
        poses2d, bboxes = gather_views(frame.views, merged)
        return merged, (poses2d[..., 2] > 0).sum(axis=0), *self._reconstruct(frame.index, poses2d, bboxes)

    def _reconstruct(
        self, frame: int, poses2d: np.ndarray, bboxes: np.ndarray
    ) -> tuple[Reconstruction, Association | None]:
        """(V, P, J, 3), (V, P, 4) -> the frame's Reconstruction and the association its tracker's skeleton prior came
        from (None where none was asked: no tracker, a stage without the adaptive prior, or nobody placed)."""
        if self.tracker is None or not self.reconstructor.takes_skeleton_prior:
            return self.reconstructor(poses2d, bboxes, self.rig), None
        first = self.reconstructor.first_pass(poses2d, bboxes, self.rig)
        if not len(first.poses):
            return self.reconstructor.finish(first, None), None
        association = self.tracker.associate(frame, first.poses)
        return self.reconstructor.finish(first, self.tracker.skeleton_prior(association)), association
