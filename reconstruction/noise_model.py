"""The 2D detector's pixel noise model, one source for the matcher's gates and the MLE / MAP weights.

sigma = max(sigma_min, sqrt(sigma_px^2 + (c sqrt(box_w box_h))^2) / score^score_power) per joint; configured by the
``noise_model`` group (``configs/noise_model/*.yaml``), which the stages that weigh 2D joints share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np


class AnyNoiseModel(Protocol):
    """What the stages read: NoiseModel here, or the self-calibrating one (reconstruction/noise_calibration.py)."""

    def sigma(self, poses2d: np.ndarray, bboxes: np.ndarray, views: np.ndarray | None = None) -> np.ndarray: ...


@dataclass(frozen=True)
class NoiseModel:
    """Pixel SD of a detected 2D joint as a function of its score and its person's box size."""

    c: float = 0.016  # share of the box size sqrt(w h) in the SD
    sigma_px: float = 5.2  # px, the SD's floor in quadrature (box-size independent)
    score_power: float = 1.27  # the SD grows as score^-score_power
    sigma_min: float = 1.0  # px, the least SD

    def __post_init__(self) -> None:
        for name in ("c", "sigma_px", "score_power", "sigma_min"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise ValueError(f"noise_model.{name}={value!r}: must be a finite number >= 0")
            object.__setattr__(self, name, float(value))
        if self.c == self.sigma_px == self.sigma_min == 0:
            raise ValueError("noise_model: c, sigma_px and sigma_min are all 0 (every joint would have SD 0)")

    def sigma(self, poses2d: np.ndarray, bboxes: np.ndarray, views: np.ndarray | None = None) -> np.ndarray:
        """Pixel SD of every joint: (..., J, 3), (..., 4) x, y, w, h, the view indices (...,) (unused here) -> (..., J);
        unseen joints (score <= 0 or a non-finite pixel) get inf. A box with no area: the box of the seen joints."""
        poses2d = np.asarray(poses2d, dtype=np.float64)
        score = poses2d[..., 2]
        seen = (score > 0) & np.isfinite(poses2d[..., 0]) & np.isfinite(poses2d[..., 1])
        spread = np.hypot(self.sigma_px, self.c * box_size(poses2d, np.asarray(bboxes, np.float64), seen))
        powed = np.where(score > 0, score, 1.0) ** self.score_power
        with np.errstate(divide="ignore", invalid="ignore"):
            sigma = np.maximum(spread[..., None] / powed, self.sigma_min)
        return np.where(seen, sigma, np.inf)


def box_size(poses2d: np.ndarray, bboxes: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """sqrt(w h) of each box (...,), the extent of the person's seen joints where the box has no area (0 if none)."""
    size = np.sqrt(np.maximum(bboxes[..., 2], 0.0) * np.maximum(bboxes[..., 3], 0.0))  # np.clip: slow dispatch
    missing = ~(size > 0)
    if np.any(seen & missing[..., None]):
        pts, ok = poses2d[missing][..., :2], seen[missing][..., None]
        lo = np.where(ok, pts, np.inf).min(axis=-2)
        hi = np.where(ok, pts, -np.inf).max(axis=-2)
        extent = np.where(np.any(ok, axis=-2), hi - lo, 0.0)
        size[missing] = np.sqrt(extent[..., 0] * extent[..., 1])
    return size
