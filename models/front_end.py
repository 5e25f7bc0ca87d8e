"""The images-to-2D front of the pipeline: a frame's camera images -> person boxes -> 2D poses per view.

``detector`` (configs/detector/) gives each view's person boxes (N, 5) x, y, w, h, score; ``pose2d``
(configs/pose2d/) turns images and boxes into ViewDetections. A 2D source that finds the persons itself
(``needs_boxes = False``, e.g. Keypoint R-CNN) is run without a detector. The seconds spent reading images,
detecting and estimating 2D poses add up in ``timings`` (the same stage names eval.py prints).
"""

from __future__ import annotations

import time
from typing import Callable, Protocol

import numpy as np

from data.multiview import Frame, ViewDetections

PersonDetector = Callable[[list[np.ndarray], Frame], list[np.ndarray]]


class Pose2DSource(Protocol):
    """Images (V of (H, W, 3) uint8 BGR) and boxes (V of (N, 5), or None) -> V ViewDetections."""

    needs_boxes: bool

    def __call__(self, images: list[np.ndarray], boxes: list[np.ndarray] | None) -> list[ViewDetections]: ...


class Pose2DFrontEnd:
    """Frame with images -> V ViewDetections (person_ids -1), timing each stage."""

    def __init__(self, pose2d: Pose2DSource, detector: PersonDetector | None = None) -> None:
        if pose2d.needs_boxes and detector is None:
            raise ValueError(f"{type(pose2d).__name__} needs person boxes: give it a detector")
        self.pose2d, self.detector = pose2d, detector if pose2d.needs_boxes else None
        self.timings: dict[str, float] = {"images": 0.0, "pose2d": 0.0}
        if self.detector is not None:
            self.timings["detector"] = 0.0

    def __call__(self, frame: Frame) -> list[ViewDetections]:
        """The 2D poses of every view of ``frame`` (rig order); the frame must carry images."""
        if frame.images is None:
            raise ValueError(f"frame {frame.index} has no images: a 2D stage needs dataset=images or render=true")
        t0 = time.perf_counter()
        images = frame.images()
        t1 = time.perf_counter()
        boxes = self.detector(images, frame) if self.detector is not None else None
        t2 = time.perf_counter()
        views = self.pose2d(images, boxes)
        t3 = time.perf_counter()
        self.timings["images"] += t1 - t0
        self.timings["pose2d"] += t3 - t2
        if self.detector is not None:
            self.timings["detector"] += t2 - t1
        return views
