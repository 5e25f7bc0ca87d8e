"""Per-view COCO keypoint ground truth and results of multi-view frames, keyed by image_ids, for coco_eval."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from data.geometry.camera import Rig
from data.keypoints import NUM_JOINTS
from data.multiview import Frame, ViewDetections
from data.pose2d.coco_keypoints import coco23_document
from data.pose2d.records import ImageRecord


def ground_truth_records(frames: Sequence[Frame], rig: Rig) -> list[ImageRecord]:
    """One ImageRecord per frame and view of ground-truth views: v = 2 seen, 1 hidden, 0 unlabelled; area w * h."""
    records = []
    for frame in frames:
        for v, (cam, view) in enumerate(zip(rig, _views(frame, rig))):
            flags = np.where(view.keypoints[..., 2] > 0, np.where(view.occluded, 1.0, 2.0), 0.0)
            xy = np.where(flags[..., None] > 0, view.keypoints[..., :2], 0.0)
            name = f"{int(frame.index):06d}_{cam.name}.jpg"  # as coco_images
            keypoints = np.concatenate([xy, flags[..., None]], axis=-1)
            areas = view.bboxes[:, 2] * view.bboxes[:, 3]
            records.append(ImageRecord(frame.image_ids[v], name, *cam.size, keypoints, view.bboxes, areas))
    return records


def ground_truth_document(frames: Sequence[Frame], rig: Rig) -> dict:
    """The COCO-23 keypoint document of :func:`ground_truth_records`, its images those of :func:`coco_images`."""
    return {**coco23_document(ground_truth_records(frames, rig)), "images": coco_images(frames, rig)}


def coco_images(frames: list[Frame], rig: Rig) -> list[dict]:
    """The COCO "images" entries (id, frame, camera, file_name, width, height) of rendered frames."""
    out = []
    for frame in frames:
        for v, cam in enumerate(rig):
            entry = {"id": frame.image_ids[v], "frame": int(frame.index), "camera": cam.name}
            entry["file_name"] = f"{int(frame.index):06d}_{cam.name}.jpg"
            out.append(entry | {"width": cam.size[0], "height": cam.size[1]})
    return out


def results(frames: Sequence[Frame], rig: Rig, views: Sequence[Sequence[ViewDetections]] | None = None) -> list[dict]:
    """COCO keypoint results of per frame V ViewDetections (N, 23, 3); ``views`` None = the frames' own views."""
    out = []
    for f, frame in enumerate(frames):
        predicted = _views(frame, rig) if views is None else list(views[f])
        if len(predicted) != len(rig):
            raise ValueError(f"frame {frame.index}: {len(predicted)} predicted views for {len(rig)} cameras")
        for v, view in enumerate(predicted):
            for n in range(len(view)):
                entry = {"image_id": int(frame.image_ids[v]), "category_id": 1}
                entry["keypoints"] = view.keypoints[n].reshape(NUM_JOINTS * 3).tolist()
                out.append(entry | {"score": float(view.scores[n]), "bbox": [float(b) for b in view.bboxes[n]]})
    return out


def _views(frame: Frame, rig: Rig) -> list[ViewDetections]:
    """The frame's views, checked against the rig and its image ids."""
    if frame.image_ids is None or len(frame.image_ids) != len(rig) or len(frame.views) != len(rig):
        raise ValueError(f"frame {frame.index}: needs one view and one image id per camera of the rig ({len(rig)})")
    for v, view in enumerate(frame.views):
        if view.keypoints.shape[1:] != (NUM_JOINTS, 3):
            raise ValueError(f"frame {frame.index}, camera {rig[v].name!r}: keypoints must be COCO-23 (N, 23, 3)")
    return list(frame.views)
