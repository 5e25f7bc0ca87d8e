"""In-memory containers of multi-view frames: what every dataset loader yields to the pipeline."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from data.geometry.camera import Rig


@dataclass
class ViewDetections:
    """The 2D detections of one camera in one frame: N persons, COCO-23 keypoints in distorted original pixels."""

    keypoints: np.ndarray  # (N, 23, 3) x, y, score (0 = missing)
    bboxes: np.ndarray  # (N, 4) x, y, w, h px
    scores: np.ndarray  # (N,) detection confidence
    person_ids: np.ndarray  # (N,) ground-truth identity, -1 for a false positive or when unknown
    occluded: np.ndarray | None = None  # (N, 23) ground-truth "hidden behind another body" flags, else all False

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
    """One multi-view frame: detections per view (rig order) and, where known, 3D ground truth and images."""

    index: int
    views: list[ViewDetections]  # with images: the render's ground-truth 2D, or empty until a 2D stage fills it
    gt_poses: np.ndarray | None = None  # (P, J, 4) x, y, z (m, world), validity (1 = annotated)
    gt_ids: np.ndarray | None = None  # (P,)
    # per view (H, W, 3) uint8 BGR at the calibration's size, read only when called (a sequence holds no pixels)
    images: Callable[[], list[np.ndarray]] | None = None
    image_ids: list[int] | None = None  # per view, the COCO image id (the key of a detections file)


@dataclass
class Sequence:
    """A rig, its frames, and the typed facts that change how they are run and scored; ``meta``: free-form extras."""

    rig: Rig
    frames: list[Frame]
    meta: dict = field(default_factory=dict)
    protocols: list = field(default_factory=list)
    description: str = ""  # one line naming the data, shown in reports and picture titles
    persistent_ids: bool = False  # gt_ids name one person over the whole sequence: identity metrics apply
    views_are_ground_truth: bool = False  # views hold ground-truth 2D: a 2D stage's predictions are scored on them
    protocol_inputs: list[dict] = field(default_factory=list)  # [{"name": ..., **arguments}] -> evaluation.protocols
    stage_seconds: dict[str, float] = field(default_factory=dict)  # stages run while loading, e.g. 2D grouping
    coco_images: list[dict] = field(default_factory=list)  # COCO "images" entries of the frames' images
    area: tuple[float, float, float, float] | None = None  # the persons' ground area (xmin, xmax, ymin, ymax), m
