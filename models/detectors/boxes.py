"""Person boxes as they pass between stages: per view an (N, 5) float64 array x, y, w, h, score (pixels)."""

from __future__ import annotations

import numpy as np
import torch
import torchvision


def no_boxes() -> np.ndarray:
    """(0, 5): a view without persons."""
    return np.zeros((0, 5))


def with_scores(xywh: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """(N, 4) x, y, w, h and (N,) scores -> (N, 5) float64."""
    return np.column_stack([np.asarray(xywh, np.float64).reshape(-1, 4), np.asarray(scores, np.float64)])


def xyxy_to_xywh(boxes: np.ndarray) -> np.ndarray:
    """(N, 4) x1, y1, x2, y2 -> (N, 4) x, y, w, h."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    return np.column_stack([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]])


def clip_xywh(boxes: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N, 4) x, y, w, h clipped to the image [0, width] x [0, height]; a box outside it gets w or h 0."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    x1 = np.clip(boxes[:, 0], 0, width)
    y1 = np.clip(boxes[:, 1], 0, height)
    x2 = np.clip(boxes[:, 0] + boxes[:, 2], 0, width)
    y2 = np.clip(boxes[:, 1] + boxes[:, 3], 0, height)
    return np.column_stack([x1, y1, x2 - x1, y2 - y1])


def person_boxes(
    boxes_xyxy: np.ndarray,
    labels: np.ndarray,
    scores: np.ndarray,
    person_label: int,
    score_threshold: float,
    nms_iou: float,
) -> np.ndarray:
    """Boxes (M, 4) x1 y1 x2 y2, labels (M,), scores (M,) -> person boxes (N, 5) xywh, score, after NMS."""
    boxes_xyxy = np.asarray(boxes_xyxy, np.float64).reshape(-1, 4)
    keep = (np.asarray(labels) == person_label) & (np.asarray(scores) >= score_threshold)
    boxes, kept_scores = boxes_xyxy[keep], np.asarray(scores, np.float64)[keep]
    order = torchvision.ops.nms(torch.from_numpy(boxes), torch.from_numpy(kept_scores), nms_iou).numpy()
    return with_scores(xyxy_to_xywh(boxes[order]), kept_scores[order])
