"""Training-time box shift and colour jitter, from their own random stream (geometric draws unchanged)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class JitterDraw:
    """One crop's draw: centre shift (fraction of box w, h), brightness, contrast, saturation, hue shift (deg)."""

    shift: tuple[float, float] = (0.0, 0.0)
    brightness: float = 1.0
    contrast: float = 1.0
    saturation: float = 1.0
    hue_deg: float = 0.0


def sample_jitter(rng: np.random.Generator, shift_factor: float, colour_factor: float, hue_deg: float) -> JitterDraw:
    """Box shift ~ N(0, shift_factor) per axis clipped to +-2 sd; colour factors ~ U[1 - c, 1 + c]; hue ~ U[-h, h]."""
    shift = np.clip(shift_factor * rng.standard_normal(2), -2 * shift_factor, 2 * shift_factor)
    b, c, s = rng.uniform(1 - colour_factor, 1 + colour_factor, 3)
    hue = float(rng.uniform(-hue_deg, hue_deg))
    return JitterDraw((float(shift[0]), float(shift[1])), float(b), float(c), float(s), hue)


def shift_box(box_xywh: np.ndarray, draw: JitterDraw) -> np.ndarray:
    """(4,) x, y, w, h -> the same box moved by draw.shift times its (w, h); a new array."""
    box = np.asarray(box_xywh, dtype=np.float64).copy()
    box[:2] += np.asarray(draw.shift) * box[2:]
    return box


def jitter_colour(rgb: np.ndarray, draw: JitterDraw) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> a new jittered image: brightness, contrast about the mean grey, saturation, hue."""
    image = rgb.astype(np.float32) * draw.brightness
    grey = image @ np.float32([0.299, 0.587, 0.114])
    image = (image - grey.mean()) * draw.contrast + grey.mean()
    grey = (image @ np.float32([0.299, 0.587, 0.114]))[..., None]
    image = grey + (image - grey) * draw.saturation
    out = np.clip(image, 0, 255).astype(np.uint8)
    if draw.hue_deg:
        hsv = cv2.cvtColor(out, cv2.COLOR_RGB2HSV)  # OpenCV's 8-bit hue runs 0..179 (2 degrees a step)
        hsv[..., 0] = ((hsv[..., 0].astype(np.int32) + round(draw.hue_deg / 2)) % 180).astype(np.uint8)
        out = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    return out
