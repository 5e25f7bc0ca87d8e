"""Person crops of one image for inference, as TopDownDataset crops them without augmentation."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from data.pose2d.crop_transforms import box_to_center_scale, crop_affine
from data.pose2d.topdown_dataset import IMAGENET_MEAN, IMAGENET_STD


def crop_boxes(
    image_bgr: np.ndarray, boxes: np.ndarray, input_size: tuple[int, int], padding: float = 1.25
) -> tuple[np.ndarray, np.ndarray]:
    """Image (H, W, 3) BGR, boxes (N, 4) xywh -> RGB crops (N, h, w, 3) uint8 and affines (N, 2, 3) crop -> image."""
    w, h = int(input_size[0]), int(input_size[1])
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    crops = np.zeros((len(boxes), h, w, 3), dtype=np.uint8)
    inverse = np.zeros((len(boxes), 2, 3))
    for i, box in enumerate(boxes):
        center, scale = box_to_center_scale(box, w / h, padding)
        affine = crop_affine(center, scale, 0.0, (w, h))
        crop = cv2.warpAffine(image_bgr, affine, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        crops[i] = crop[..., ::-1]
        inverse[i] = crop_affine(center, scale, 0.0, (w, h), inverse=True)
    return crops, inverse


def normalize_crops(crops: torch.Tensor) -> torch.Tensor:
    """RGB uint8 crops (N, h, w, 3) -> float32 (N, 3, h, w), the batched topdown_dataset.normalize_image."""
    mean = torch.as_tensor(IMAGENET_MEAN, device=crops.device)
    std = torch.as_tensor(IMAGENET_STD, device=crops.device)
    return ((crops.float() / 255.0 - mean) / std).permute(0, 3, 1, 2).contiguous()
