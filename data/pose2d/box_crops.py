"""Person crops of one image for inference: TopDownDataset's crops without augmentation, as a batch (same
geometry and normalisation, so a crop here is the one the network was validated on)."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from data.pose2d.crop_transforms import box_to_center_scale, crop_affine
from data.pose2d.topdown_dataset import IMAGENET_MEAN, IMAGENET_STD


def crop_boxes(
    image_bgr: np.ndarray, boxes: np.ndarray, input_size: tuple[int, int], padding: float = 1.25
) -> tuple[np.ndarray, np.ndarray]:
    """Image (H, W, 3) uint8 BGR, boxes (N, 4) x, y, w, h -> RGB crops (N, h, w, 3) uint8 of input_size (w, h)
    and their crop-to-image affines (N, 2, 3)."""
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
    """RGB uint8 crops (N, h, w, 3) -> ImageNet-normalised float32 (N, 3, h, w) on the same device, the batched
    data.pose2d.topdown_dataset.normalize_image (the same float32 operations, so the same values)."""
    mean = torch.as_tensor(IMAGENET_MEAN, device=crops.device)
    std = torch.as_tensor(IMAGENET_STD, device=crops.device)
    return ((crops.float() / 255.0 - mean) / std).permute(0, 3, 1, 2).contiguous()
