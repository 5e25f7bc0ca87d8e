"""Joint candidates: the top-M local maxima per heatmap channel (CrowdPose's SPPE), DARK sub-pixel step, in torch."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

_LOG_EPS = 1e-10


def find_candidates(
    heatmaps: torch.Tensor | np.ndarray, threshold: float = 0.1, top_m: int = 3, nms_kernel: int = 3
) -> tuple[torch.Tensor, torch.Tensor]:
    """Top-M local maxima per channel: heatmaps (B, J, h, w) -> xy (B, J, M, 2) heatmap px, scores (B, J, M) float64."""
    if nms_kernel < 1 or nms_kernel % 2 == 0:
        raise ValueError(f"nms_kernel must be a positive odd number, got {nms_kernel}")
    if threshold < 0 or top_m < 1:
        raise ValueError(f"need threshold >= 0 and top_m >= 1, got {threshold}, {top_m}")
    hm = torch.as_tensor(heatmaps).detach()
    hm = hm.float() if hm.dtype in (torch.float16, torch.bfloat16) else hm
    b, j, h, w = hm.shape
    # a peak equals its neighbourhood maximum and exceeds threshold: hm >= max(neighbourhood max, next value above it)
    floor = _next_above(threshold, hm.dtype)
    peak = hm >= F.max_pool2d(hm, nms_kernel, 1, nms_kernel // 2).clamp_(min=floor)
    flat = torch.where(peak, hm, 0.0).reshape(b, j, h * w)
    vals, idx = flat.topk(min(top_m, h * w), dim=-1)
    rows, cols = idx // w, idx % w
    dx = _parabola_offset(hm.reshape(b, j, h * w), rows, cols, w, axis_len=w, along_x=True)
    dy = _parabola_offset(hm.reshape(b, j, h * w), rows, cols, w, axis_len=h, along_x=False)
    found = vals > 0
    xy = torch.stack([cols + dx, rows + dy], dim=-1) * found[..., None]
    scores = vals.to(torch.float64) * found
    if vals.shape[-1] < top_m:
        xy = F.pad(xy, (0, 0, 0, top_m - vals.shape[-1]))
        scores = F.pad(scores, (0, top_m - vals.shape[-1]))
    return xy, scores


def _next_above(threshold: float, dtype: torch.dtype) -> float:
    """The smallest value of dtype strictly above threshold (so ``x >= it`` is exactly ``x > threshold``)."""
    info = np.finfo(torch.finfo(dtype).dtype)
    value = info.dtype.type(threshold)
    return float(value if value > threshold else np.nextafter(value, info.dtype.type(np.inf)))


def _parabola_offset(
    hm: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor, w: int, axis_len: int, along_x: bool
) -> torch.Tensor:
    """Log-parabola vertex offsets (B, J, K) float64 along one axis at rows, cols (B, J, K) of hm (B, J, h * w)."""
    pos = cols if along_x else rows

    def log_at(shift: int) -> torch.Tensor:
        p = (pos + shift).clamp(0, axis_len - 1)
        flat = rows * w + p if along_x else p * w + cols
        return hm.gather(-1, flat).to(torch.float64).clamp_min(_LOG_EPS).log()

    lm, l0, lp = log_at(-1), log_at(0), log_at(1)
    curvature = lm - 2 * l0 + lp
    inside = (pos > 0) & (pos < axis_len - 1) & (curvature < 0)
    safe = torch.where(inside, curvature, -torch.ones_like(curvature))
    offset = (0.5 * (lm - lp) / safe).clamp(-0.5, 0.5)
    return torch.where(inside, offset, torch.zeros_like(offset))


def candidates_to_image(
    xy: torch.Tensor, inverse_affines: torch.Tensor | np.ndarray, stride: float | Sequence[float]
) -> torch.Tensor:
    """Heatmap px xy (B, J, M, 2), inverse_affines (B, 2, 3) -> image px (B, J, M, 2) float64."""
    xy = torch.as_tensor(xy).to(torch.float64)
    affines = torch.as_tensor(inverse_affines, dtype=torch.float64, device=xy.device).reshape(-1, 2, 3)
    s = torch.as_tensor(np.broadcast_to(np.asarray(stride, dtype=np.float64), (2,)).copy(), device=xy.device)
    x_in = (xy + 0.5) * s - 0.5
    return torch.einsum("bik,bjmk->bjmi", affines[:, :, :2], x_in) + affines[:, None, None, :, 2]
