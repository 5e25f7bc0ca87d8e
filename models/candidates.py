"""Multi-peak heatmap decoding: several joint candidates per joint channel (CrowdPose's joint-candidate SPPE).

Coordinates. A candidate ``xy`` is in *heatmap pixels*, integer values at pixel centres (the peak pixel
``(col, row)`` is ``(col, row)``), plus a sub-pixel offset. The crop-input pixel is obtained with the
pixel-centre convention ``x_in = (x_hm + 0.5) * stride - 0.5`` (heatmap pixel ``i`` covers input pixels
``[i * stride, (i + 1) * stride)``, whose centre is ``(i + 0.5) * stride - 0.5``), then the inverse crop
affine takes input pixels to image pixels.

Sub-pixel refinement. Along each axis a parabola is fitted to the *log* heatmap at the peak and its two
neighbours and the peak moves to its vertex, ``dx = (l[-1] - l[+1]) / (2 (l[-1] - 2 l[0] + l[+1]))``,
clamped to half a pixel. This is the Taylor (Newton) step on the log heatmap with a diagonal Hessian
(DARK, Zhang et al. CVPR 2020) and is exact for an axis-aligned Gaussian peak. A peak on the heatmap
border, or one that is not strictly concave in the log along an axis, is not moved along that axis.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

_LOG_EPS = 1e-10


def find_candidates(
    heatmaps: torch.Tensor | np.ndarray, threshold: float = 0.1, top_m: int = 3, nms_kernel: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """Top-M local maxima per channel: heatmaps (B, J, h, w) -> xy (B, J, M, 2) heatmap px, scores (B, J, M).

    A candidate is a pixel equal to the maximum of its ``nms_kernel`` neighbourhood and above
    ``threshold``; candidates are sorted by score (the heatmap value at the peak pixel), best first.
    Unused slots have score 0 and xy 0. Two equal adjacent maxima (a plateau) both survive.
    """
    if nms_kernel < 1 or nms_kernel % 2 == 0:
        raise ValueError(f"nms_kernel must be a positive odd number, got {nms_kernel}")
    if threshold < 0 or top_m < 1:
        raise ValueError(f"need threshold >= 0 and top_m >= 1, got {threshold}, {top_m}")
    hm = torch.as_tensor(heatmaps).detach().to(torch.float64)
    b, j, h, w = hm.shape
    pooled = F.max_pool2d(hm.reshape(b * j, 1, h, w), nms_kernel, stride=1, padding=nms_kernel // 2)
    peaks = (hm == pooled.reshape(b, j, h, w)) & (hm > threshold)
    flat = torch.where(peaks, hm, torch.zeros_like(hm)).reshape(b, j, h * w)
    k = min(top_m, h * w)
    vals, idx = flat.topk(k, dim=-1)
    rows, cols = idx // w, idx % w
    log_hm = hm.clamp_min(_LOG_EPS).log().reshape(b, j, h * w)
    dx = _parabola_offset(log_hm, rows, cols, w, axis_len=w, along_x=True)
    dy = _parabola_offset(log_hm, rows, cols, w, axis_len=h, along_x=False)
    xy = torch.stack([cols + dx, rows + dy], dim=-1)
    found = vals > 0
    xy = torch.where(found[..., None], xy, torch.zeros_like(xy))
    scores = torch.where(found, vals, torch.zeros_like(vals))
    xy_np, scores_np = xy.cpu().numpy(), scores.cpu().numpy()
    if k < top_m:
        xy_np = np.concatenate([xy_np, np.zeros((b, j, top_m - k, 2))], axis=2)
        scores_np = np.concatenate([scores_np, np.zeros((b, j, top_m - k))], axis=2)
    return xy_np, scores_np


def _parabola_offset(
    log_hm: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor, w: int, axis_len: int, along_x: bool
) -> torch.Tensor:
    """Vertex offset of the log-parabola through a peak and its two neighbours along one axis: (B, J, K)."""
    pos = cols if along_x else rows

    def log_at(shift: int) -> torch.Tensor:
        p = (pos + shift).clamp(0, axis_len - 1)
        flat = rows * w + p if along_x else p * w + cols
        return log_hm.gather(-1, flat)

    lm, l0, lp = log_at(-1), log_at(0), log_at(1)
    curvature = lm - 2 * l0 + lp
    inside = (pos > 0) & (pos < axis_len - 1) & (curvature < 0)
    safe = torch.where(inside, curvature, -torch.ones_like(curvature))
    offset = (0.5 * (lm - lp) / safe).clamp(-0.5, 0.5)
    return torch.where(inside, offset, torch.zeros_like(offset))


def candidates_to_image(xy: np.ndarray, inverse_affines: np.ndarray, stride: float | Sequence[float]) -> np.ndarray:
    """Heatmap pixels to image pixels: xy (B, J, M, 2), inverse_affines (B, 2, 3) -> (B, J, M, 2).

    ``stride`` is the input-to-heatmap size ratio (a number, or (sx, sy)); ``inverse_affines[b]`` maps
    crop-input pixels to image pixels. Uses ``x_in = (x_hm + 0.5) * stride - 0.5`` (module docstring).
    Slots with score 0 are transformed too and stay meaningless.
    """
    xy = np.asarray(xy, dtype=np.float64)
    affines = np.asarray(inverse_affines, dtype=np.float64).reshape(-1, 2, 3)
    s = np.broadcast_to(np.asarray(stride, dtype=np.float64), (2,))
    x_in = (xy + 0.5) * s - 0.5
    return np.einsum("bik,bjmk->bjmi", affines[:, :, :2], x_in) + affines[:, None, None, :, 2]
