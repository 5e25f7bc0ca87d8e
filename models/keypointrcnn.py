"""Baseline 2D source: torchvision's Keypoint R-CNN (COCO-17) as COCO-23 poses, the 6 foot joints missing."""

from __future__ import annotations

import numpy as np
from scipy.special import expit

from data.config_checks import fail, is_int, is_number
from data.keypoints import COCO17_TO_COCO23, to_coco23
from data.multiview import ViewDetections
from models.detectors.boxes import xyxy_to_xywh
from models.devices import resolve_device
from models.tv_detection import build_detection_model, detect

MODEL = "keypointrcnn_resnet50_fpn"
PERSON_LABEL = 1  # torchvision's Keypoint R-CNN has two classes: background, person


def keypoint_scores(logits: np.ndarray, center: float, scale: float) -> np.ndarray:
    """(...) raw keypoint logits -> (...) scores in [0, 1]; center 2 gives 0.5 where Detectron draws a keypoint."""
    return expit((np.asarray(logits, np.float64) - center) / scale)


class KeypointRCNN:
    """``stage(images, boxes=None) -> list[ViewDetections]``: persons and COCO-23 keypoints per view (boxes ignored)."""

    needs_boxes = False

    def __init__(
        self,
        weights: str | None = "coco",
        score_threshold: float = 0.5,
        logit_center: float = 2.0,
        logit_scale: float = 1.0,
        batch_size: int = 2,
        device: str = "auto",
        model_kwargs: dict | None = None,
    ) -> None:
        if not is_number(score_threshold):
            fail("pose2d.score_threshold", score_threshold, "must be a finite number")
        if not is_number(logit_center):
            fail("pose2d.logit_center", logit_center, "must be a finite number")
        if not (is_number(logit_scale) and logit_scale > 0):
            fail("pose2d.logit_scale", logit_scale, "must be a number > 0")
        if not (is_int(batch_size) and batch_size >= 1):
            fail("pose2d.batch_size", batch_size, "must be an integer >= 1")
        self.device = resolve_device(device, "pose2d.device")
        self.model, _ = build_detection_model(MODEL, weights, "pose2d", **dict(model_kwargs or {}))
        self.model.to(self.device)
        self.score_threshold, self.batch_size = score_threshold, batch_size
        self.logit_center, self.logit_scale = logit_center, logit_scale

    def to_view(self, output: dict) -> ViewDetections:
        """One image's torchvision output (boxes (M, 4) xyxy, keypoints (M, 17, 3), ...) -> ViewDetections."""
        keep = (output["labels"].numpy() == PERSON_LABEL) & (output["scores"].numpy() >= self.score_threshold)
        xy = output["keypoints"].double().numpy()[keep][:, :, :2]
        score = keypoint_scores(output["keypoints_scores"].double().numpy()[keep], self.logit_center, self.logit_scale)
        keypoints = to_coco23(np.concatenate([xy, score[:, :, None]], axis=2), COCO17_TO_COCO23)
        n = len(keypoints)
        boxes = xyxy_to_xywh(output["boxes"].double().numpy()[keep])
        return ViewDetections(keypoints, boxes, output["scores"].double().numpy()[keep], np.full(n, -1))

    def __call__(self, images: list[np.ndarray], boxes: list[np.ndarray] | None = None) -> list[ViewDetections]:
        """Images (H, W, 3) uint8 BGR per view -> ViewDetections (keypoints (N, 23, 3), feet 0); boxes ignored."""
        return [self.to_view(out) for out in detect(self.model, images, self.batch_size, self.device)]
