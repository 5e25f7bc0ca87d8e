"""Top-down crop geometry and augmentation, pixel centres at integers (cv2's convention: flip x -> W - 1 - x)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from data.keypoints import flip_permutation


def box_to_center_scale(box_xywh: np.ndarray, aspect: float, padding: float = 1.25) -> tuple[np.ndarray, np.ndarray]:
    """Box (4,) xywh -> crop centre (2,), extent (2,) px: grown to aspect w / h, then times padding."""
    x, y, w, h = np.asarray(box_xywh, dtype=np.float64).reshape(4)
    center = np.array([x + w / 2, y + h / 2])
    if w > aspect * h:
        h = w / aspect
    else:
        w = h * aspect
    return center, np.array([w, h]) * padding


def crop_affine(
    center: np.ndarray, scale: np.ndarray, rotation_deg: float, out_size: tuple[int, int], inverse: bool = False
) -> np.ndarray:
    """(2, 3) affine image -> crop of out_size (w, h) (or back): S R (p - center) + crop centre, R as cv2's."""
    center = np.asarray(center, dtype=np.float64).reshape(2)
    scale = np.asarray(scale, dtype=np.float64).reshape(2)
    out_w, out_h = out_size
    theta = np.deg2rad(rotation_deg)
    c, s = np.cos(theta), np.sin(theta)
    rot = np.array([[c, s], [-s, c]])
    stretch = np.array([out_w / scale[0], out_h / scale[1]])
    out_center = np.array([(out_w - 1) / 2, (out_h - 1) / 2])
    if inverse:
        linear = rot.T * (1 / stretch)[None, :]  # R^T S^-1
        return np.hstack([linear, (center - linear @ out_center)[:, None]])
    linear = stretch[:, None] * rot  # S R
    return np.hstack([linear, (out_center - linear @ center)[:, None]])


def transform_points(points: np.ndarray, affine: np.ndarray) -> np.ndarray:
    """Apply a (2, 3) affine to points (..., 2) -> (..., 2)."""
    points = np.asarray(points, dtype=np.float64)
    affine = np.asarray(affine, dtype=np.float64)
    return points @ affine[:, :2].T + affine[:, 2]


def flip_points(points: np.ndarray, image_width: int) -> np.ndarray:
    """Mirror points (..., 2) of an image of width W horizontally: x -> W - 1 - x (crop centres too)."""
    out = np.array(points, dtype=np.float64)
    out[..., 0] = image_width - 1 - out[..., 0]
    return out


def flip_keypoints(keypoints: np.ndarray, image_width: int) -> np.ndarray:
    """Keypoints (N, 23, 3) of a horizontally flipped image: labelled x -> W - 1 - x, left and right swapped."""
    keypoints = np.asarray(keypoints, dtype=np.float64)
    out = keypoints[..., flip_permutation(), :].copy()
    labelled = out[..., 2] > 0
    out[..., 0] = np.where(labelled, image_width - 1 - out[..., 0], out[..., 0])
    return out


@dataclass(frozen=True)
class CropAugmentation:
    """Random crop augmentation settings (SimpleBaseline/HRNet style); 0 turns each off."""

    scale_factor: float = 0.25  # std of the scale multiplier around 1, clipped to 1 +- scale_factor
    rotation_factor: float = 30.0  # std of the rotation (deg), clipped to +- 2 rotation_factor
    rotation_prob: float = 0.6  # probability of rotating at all
    flip_prob: float = 0.5  # probability of a horizontal flip
    shift_factor: float = 0.0  # std of the box centre shift, fraction of the box w / h (a detector's error)
    colour_factor: float = 0.0  # brightness, contrast, saturation factors in 1 +- colour_factor (photometric.py)
    hue_deg: float = 0.0  # hue shift drawn in +- hue_deg


def sample_augmentation(
    rng: np.random.Generator, settings: CropAugmentation | None = None
) -> tuple[float, float, bool]:
    """Draw (scale multiplier, rotation in degrees, flip) for one crop; settings default to CropAugmentation()."""
    settings = settings or CropAugmentation()
    sf, rf = settings.scale_factor, settings.rotation_factor
    scale_mult = float(np.clip(1 + sf * rng.standard_normal(), 1 - sf, 1 + sf))
    rotation = float(np.clip(rf * rng.standard_normal(), -2 * rf, 2 * rf))
    if rng.random() >= settings.rotation_prob:
        rotation = 0.0
    flip = bool(rng.random() < settings.flip_prob)
    return scale_mult, rotation, flip
