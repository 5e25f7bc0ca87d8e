"""The images-to-2D front of the pipeline: a frame's camera images -> person boxes -> 2D poses per view."""

from __future__ import annotations

import time
from typing import Any, Callable, Protocol

import numpy as np
from hydra.utils import instantiate

from data.config_checks import ConfigError
from data.multiview import Frame, Sequence, ViewDetections
from models.view_completion import ViewCompletion
from reconstruction.pipeline import MultiViewPipeline

PersonDetector = Callable[[list[np.ndarray], Frame], list[np.ndarray]]


class Pose2DSource(Protocol):
    """Images (V of (H, W, 3) uint8 BGR) and boxes (V of (N, 5), or None) -> V ViewDetections."""

    needs_boxes: bool

    def __call__(self, images: list[np.ndarray], boxes: list[np.ndarray] | None) -> list[ViewDetections]: ...


class Pose2DFrontEnd:
    """Frame with images -> V ViewDetections (person_ids -1), timing each stage."""

    def __init__(
        self, pose2d: Pose2DSource, detector: PersonDetector | None = None, completion: ViewCompletion | None = None
    ) -> None:
        if pose2d.needs_boxes and detector is None:
            raise ValueError(f"{type(pose2d).__name__} needs person boxes: give it a detector")
        self.pose2d, self.detector = pose2d, detector if pose2d.needs_boxes else None
        self.completion = completion if pose2d.needs_boxes else None
        stages = ("images", "pose2d", "detector") if self.detector is not None else ("images", "pose2d")
        self.timings = dict.fromkeys(stages + (("view completion",) if self.completion else ()), 0.0)

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
        if self.completion is not None:
            views = self.completion(frame, images, views, self.pose2d)
            self.timings["view completion"] += time.perf_counter() - t3
        return views

    @classmethod
    def from_config(cls, cfg: Any, sequence: Sequence) -> "Pose2DFrontEnd | None":
        """The front end of an eval.yaml config for ``sequence``; None for pose2d=none; a mismatch is a ConfigError."""
        has_images = bool(sequence.frames) and sequence.frames[0].images is not None
        if not cfg.pose2d.get("_target_"):
            if has_images and not any(len(v) for f in sequence.frames for v in f.views):
                raise ConfigError(
                    "pose2d=none: the dataset gives images, not 2D poses; choose a 2D stage: pose2d=blazepose "
                    "detector=blazepose (offline: pip install --no-deps -r requirements-models.txt), pose2d=sppe "
                    "pose2d.checkpoint=<train.py checkpoint> [detector=gt|file|torchvision|blazepose], or pose2d=keypointrcnn"
                )
            return None
        if not has_images:
            raise ConfigError(
                "pose2d: a 2D stage reads camera images; this dataset has none (dataset=images, or dataset=synthetic "
                "dataset.render=true)"
            )
        pose2d = instantiate(cfg.pose2d)
        detector = instantiate(cfg.detector) if pose2d.needs_boxes else None
        if getattr(detector, "reads_ground_truth", False) and not any(len(v) for f in sequence.frames for v in f.views):
            raise ConfigError(
                "detector=gt: this dataset's frames carry no ground-truth persons (real images); choose a detector "
                "that reads the images: detector=blazepose (offline), detector=torchvision, or detector=file"
            )
        if hasattr(detector, "check_image_ids"):  # detector=file: every entry names an image of the dataset
            detector.check_image_ids({i for f in sequence.frames for i in (f.image_ids or [])})
        if hasattr(detector, "set_file_sizes") and sequence.coco_images:
            detector.set_file_sizes({im["id"]: (im["width"], im["height"]) for im in sequence.coco_images})
        completion = None
        if pose2d.needs_boxes and cfg.complete_views.enabled:  # a first 3D pass of each frame, without tracking
            first_pass = MultiViewPipeline(
                sequence.rig, instantiate(cfg.matching), instantiate(cfg.reconstruction), None, cfg.coincident_m
            )
            completion = ViewCompletion(first_pass, cfg.complete_views.min_oks, cfg.complete_views.min_joints)
        return cls(pose2d, detector, completion)
