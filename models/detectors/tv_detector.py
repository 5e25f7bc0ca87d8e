"""Person boxes from a torchvision detection model (Faster R-CNN, RetinaNet, SSD, FCOS) run on the images."""

from __future__ import annotations

import numpy as np

from data.config_checks import fail, is_int, is_number
from data.multiview import Frame
from models.detectors.boxes import person_boxes
from models.devices import resolve_device
from models.tv_detection import build_detection_model, detect


class TorchvisionDetector:
    """A torchvision detection model (e.g. fasterrcnn_resnet50_fpn_v2), persons only; weights coco | file | None."""

    needs_images = True

    def __init__(
        self,
        model: str = "fasterrcnn_resnet50_fpn_v2",
        weights: str | None = "coco",
        score_threshold: float = 0.5,
        nms_iou: float = 0.5,
        batch_size: int = 4,
        device: str = "auto",
        person_label: int = 1,
        model_kwargs: dict | None = None,
    ) -> None:
        if not is_number(score_threshold):
            fail("detector.score_threshold", score_threshold, "must be a finite number")
        if not (is_number(nms_iou) and 0 < nms_iou <= 1):
            fail("detector.nms_iou", nms_iou, "must be in (0, 1] (1: no suppression)")
        if not (is_int(batch_size) and batch_size >= 1):
            fail("detector.batch_size", batch_size, "must be an integer >= 1")
        if not (is_int(person_label) and person_label >= 0):
            fail("detector.person_label", person_label, "must be an integer >= 0")
        self.device = resolve_device(device, "detector.device")
        self.model, categories = build_detection_model(model, weights, "detector", **dict(model_kwargs or {}))
        if categories is not None and (person_label >= len(categories) or categories[person_label] != "person"):
            fail("detector.person_label", person_label, f"is not 'person' in the {model} weights' categories")
        self.model.to(self.device)
        self.name, self.person_label = model, person_label
        self.score_threshold, self.nms_iou, self.batch_size = score_threshold, nms_iou, batch_size

    def __call__(self, images: list[np.ndarray], frame: Frame | None = None) -> list[np.ndarray]:
        """Per view (N, 5) x, y, w, h, score of the persons found in (H, W, 3) uint8 BGR ``images``."""
        return [
            person_boxes(
                out["boxes"].double().numpy(),
                out["labels"].numpy(),
                out["scores"].double().numpy(),
                self.person_label,
                self.score_threshold,
                self.nms_iou,
            )
            for out in detect(self.model, images, self.batch_size, self.device)
        ]
