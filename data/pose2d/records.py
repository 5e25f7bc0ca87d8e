"""Plain records of top-down 2D keypoint datasets: what every COCO-format loader yields to training."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from data.keypoints import NUM_JOINTS


@dataclass
class ImageRecord:
    """One image and every annotated person in it, keypoints in COCO-23 order."""

    image_id: int
    file: Path
    width: int
    height: int
    keypoints: np.ndarray  # (N, 23, 3) x, y px, v (0 = unlabelled, > 0 labelled; COCO's 1/2 kept)
    boxes: np.ndarray  # (N, 4) x, y, w, h
    areas: np.ndarray  # (N,) COCO area (OKS scale), else w * h
    # (23,) the joints this dataset annotates at all (CrowdPose-14: no eyes, ears, feet)
    labelled: np.ndarray = field(default_factory=lambda: np.ones(NUM_JOINTS, dtype=bool))
    # detector boxes (M, 4) and scores (M,) for top-down evaluation (empty: the ground-truth boxes, score 1)
    det_boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    det_scores: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        self.file = Path(self.file)
        self.keypoints = np.asarray(self.keypoints, dtype=np.float64).reshape(-1, NUM_JOINTS, 3)
        n = len(self.keypoints)
        self.boxes = np.asarray(self.boxes, dtype=np.float64).reshape(n, 4)
        self.areas = np.asarray(self.areas, dtype=np.float64).reshape(n)
        self.labelled = np.asarray(self.labelled, dtype=bool).reshape(NUM_JOINTS)
        self.det_boxes = np.asarray(self.det_boxes, dtype=np.float64).reshape(-1, 4)
        self.det_scores = np.asarray(self.det_scores, dtype=np.float64).reshape(len(self.det_boxes))

    def __len__(self) -> int:
        return len(self.keypoints)
