"""Views a person was missed in, filled by the 2D model on the box of their projected first-pass 3D pose."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from data.config_checks import fail, is_int, is_number
from data.keypoints import OKS_SIGMAS
from data.multiview import Frame, ViewDetections
from models.pose_nms import joint_similarity
from reconstruction.pipeline import MultiViewPipeline

Pose2D = Callable[[list[np.ndarray], list[np.ndarray]], list[ViewDetections]]  # images, boxes (N, 5) -> views


class ViewCompletion:
    """``completion(frame, images, views, pose2d) -> views``: a first 3D pass (``pipeline``, no tracker) of the frame;
    each person's pose projected into every view where nobody was matched to them; the 2D model run on the box of the
    projection; its pose added to that view where it agrees with the projection (OKS >= min_oks)."""

    def __init__(self, pipeline: MultiViewPipeline, min_oks: float = 0.5, min_joints: int = 8) -> None:
        if not (is_number(min_oks) and 0 < min_oks <= 1):
            fail("complete_views.min_oks", min_oks, "must be a number in (0, 1]")
        if not (is_int(min_joints) and min_joints >= 1):
            fail("complete_views.min_joints", min_joints, "must be an integer >= 1")
        self.pipeline, self.min_oks, self.min_joints = pipeline, min_oks, min_joints
        self.added = 0  # views filled over the run

    def proposals(self, frame: Frame) -> list[list[tuple[np.ndarray, np.ndarray]]]:
        """Per view, the (projected pose (23, 3) x, y, inside, box (5,) x, y, w, h, 1) of every person it misses."""
        result = self.pipeline(frame)
        out: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in self.pipeline.rig]
        for p, pose in enumerate(np.asarray(result.poses3d)):
            for v, camera in enumerate(self.pipeline.rig):
                if result.assignment[p, v] >= 0 or not np.any(pose[:, 3] > 0):
                    continue
                xyz = np.where(pose[:, 3:] > 0, pose[:, :3], 0.0)
                uv, inside = camera.project(xyz), (pose[:, 3] > 0) & camera.in_view(xyz)  # images at the camera size
                if inside.sum() >= self.min_joints:
                    low, high = uv[inside].min(axis=0), uv[inside].max(axis=0)
                    out[v].append((np.column_stack([uv, inside]), np.array([*low, *(high - low), 1.0])))
        return out

    def __call__(
        self, frame: Frame, images: list[np.ndarray], views: list[ViewDetections], pose2d: Pose2D
    ) -> list[ViewDetections]:
        """The frame's V views (N, 23, 3) with the poses found in the boxes of the persons each view missed."""
        views = list(views)
        for v, found in enumerate(self.proposals(replace(frame, views=views))):
            if not found:
                continue
            detected = pose2d([images[v]] * len(found), [box[None] for _, box in found])
            kept = [
                best(d)
                for (ref, box), d in zip(found, detected)
                if len(d) and self.agrees(ref, box, d.keypoints[0]) and not self.repeats(views[v], d.keypoints[0])
            ]
            if kept:
                views[v] = concatenate([views[v], *kept])
                self.added += len(kept)
        return views

    def agrees(self, projected: np.ndarray, box: np.ndarray, pose: np.ndarray) -> bool:
        """Whether a 2D pose (23, 3) is the projected person (23, 3) x, y, inside: OKS over their joints >= min_oks."""
        inside = projected[:, 2] > 0
        similarity = joint_similarity(projected, pose[None], float(box[2] * box[3]), OKS_SIGMAS)[0]
        return float(similarity[inside].mean()) >= self.min_oks

    def repeats(self, view: ViewDetections, pose: np.ndarray) -> bool:
        """Whether a 2D pose (23, 3) is a detection the view holds already (OKS >= min_oks): someone else, or one the
        first pass left unmatched."""
        for other in view.keypoints:
            seen = (other[:, 2] > 0) & (pose[:, 2] > 0)
            if not seen.any():
                continue
            extent = np.ptp(other[seen, :2], axis=0) if seen.sum() > 1 else np.ones(2)
            similarity = joint_similarity(other, pose[None], float(max(np.prod(extent), 1.0)), OKS_SIGMAS)[0]
            if float(similarity[seen].mean()) >= self.min_oks:
                return True
        return False


def best(view: ViewDetections) -> ViewDetections:
    """The first (highest-scoring) detection of a view: (1, 23, 3)."""
    return ViewDetections(view.keypoints[:1], view.bboxes[:1], view.scores[:1], view.person_ids[:1])


def concatenate(parts: list[ViewDetections]) -> ViewDetections:
    """One view's detections joined: (N1 + N2 + ..., 23, 3)."""
    return ViewDetections(
        np.concatenate([p.keypoints for p in parts]),
        np.concatenate([p.bboxes for p in parts]),
        np.concatenate([p.scores for p in parts]),
        np.concatenate([p.person_ids for p in parts]),
    )
