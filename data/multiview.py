"""In-memory containers of multi-view frames: what every dataset loader yields to the pipeline."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from data.geometry.camera import Rig


@dataclass
class ViewDetections:
    """The 2D detections of one camera in one frame, N persons, COCO-23 keypoints.

    keypoints (N, 23, 3): x, y in distorted pixels of the original image, score (0 = missing).
    bboxes (N, 4): x, y, w, h in pixels. scores (N,): detection confidence.
    person_ids (N,): ground-truth identity, -1 for a false positive or when unknown.
    occluded (N, 23): ground-truth "hidden behind another body" flags where known, else all False.
    """

    keypoints: np.ndarray
    bboxes: np.ndarray
    scores: np.ndarray
    person_ids: np.ndarray
    occluded: np.ndarray | None = None

    def __post_init__(self) -> None:
        keypoints = np.asarray(self.keypoints, dtype=np.float64)
        n = len(keypoints)
        self.keypoints = keypoints.reshape(n, keypoints.shape[1] if keypoints.ndim == 3 else -1, 3)
        self.bboxes = np.asarray(self.bboxes, dtype=np.float64).reshape(n, 4)
        self.scores = np.asarray(self.scores, dtype=np.float64).reshape(n)
        self.person_ids = np.asarray(self.person_ids, dtype=np.int64).reshape(n)
        if self.occluded is None:
            self.occluded = np.zeros(self.keypoints.shape[:2], dtype=bool)

    def __len__(self) -> int:
        return len(self.keypoints)

    @classmethod
    def empty(cls, num_joints: int = 23) -> "ViewDetections":
        """No detections."""
        return cls(np.zeros((0, num_joints, 3)), np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int64))


@dataclass
class Frame:
    """One multi-view frame: detections per view (rig order) and, where known, 3D ground truth.

    gt_poses (P, J, 4): x, y, z (m, world) and validity (1 = annotated); gt_ids (P,).
    images: where the cameras' images are known (dataset=images, dataset=synthetic with render=true), a
    callable returning them, per view in rig order (H, W, 3) uint8 BGR at the calibration's image size;
    read only when called, so a long sequence holds no pixels. ``views`` then holds the ground-truth 2D
    (render) or nothing (images) until a 2D stage fills it. image_ids: per view, the COCO image id of
    that image (the key of a detections file, detector=file).
    """

    index: int
    views: list[ViewDetections]
    gt_poses: np.ndarray | None = None
    gt_ids: np.ndarray | None = None
    images: Callable[[], list[np.ndarray]] | None = None
    image_ids: list[int] | None = None


@dataclass
class Sequence:
    """A rig, its frames, and the typed facts that change how they are run and scored.

    A loader lists the plain-data inputs of its benchmark protocols in ``protocol_inputs``
    (``[{"name": ..., **arguments}]``); :func:`evaluation.protocols.attach_protocols` builds them into
    ``protocols`` (datasets sit below evaluation). ``meta`` holds free-form descriptive extras only.
    """

    rig: Rig
    frames: list[Frame]
    meta: dict = field(default_factory=dict)
    protocols: list = field(default_factory=list)
    description: str = ""  # one line naming the data, shown in reports and picture titles
    persistent_ids: bool = False  # gt_ids name one person over the whole sequence: identity metrics apply
    views_are_ground_truth: bool = False  # views hold ground-truth 2D: a 2D stage's predictions are scored on them
    protocol_inputs: list[dict] = field(default_factory=list)
    stage_seconds: dict[str, float] = field(default_factory=dict)  # stages run while loading, e.g. 2D grouping
    coco_images: list[dict] = field(default_factory=list)  # COCO "images" entries of the frames' images
    area: tuple[float, float, float, float] | None = None  # the persons' ground area (xmin, xmax, ymin, ymax), m
