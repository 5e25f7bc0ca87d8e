"""The numpy decoding that models/candidates.py and models/joint_association.py replaced, kept as the reference.

tests/test_pose_decoding.py checks the batched decoding against it (same candidates, same association): float64
candidates with a max-pool suppression and a log-parabola refinement by numpy indexing, then one cdist,
connected-components and Hungarian problem per joint type in a python loop. Nothing in the pipeline imports it.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial.distance import cdist

from data.keypoints import OKS_SIGMAS

_LOG_EPS = 1e-10


def find_candidates(
    heatmaps: torch.Tensor | np.ndarray, threshold: float = 0.1, top_m: int = 3, nms_kernel: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """The candidates of models.candidates.find_candidates: (B, J, h, w) -> xy (B, J, M, 2), scores (B, J, M)."""
    hm = torch.as_tensor(heatmaps).detach().to(torch.float64)
    b, j, h, w = hm.shape
    pooled = F.max_pool2d(hm.reshape(b * j, 1, h, w), nms_kernel, stride=1, padding=nms_kernel // 2)
    peaks = (hm == pooled.reshape(b, j, h, w)) & (hm > threshold)
    flat = torch.where(peaks, hm, torch.zeros_like(hm)).reshape(b, j, h * w)
    k = min(top_m, h * w)
    vals, idx = flat.topk(k, dim=-1)
    rows, cols = (idx // w).numpy(), (idx % w).numpy()
    log_hm = hm.clamp_min(_LOG_EPS).log().numpy()
    dx = _parabola_offset(log_hm, rows, cols, along_x=True)
    dy = _parabola_offset(log_hm, rows, cols, along_x=False)
    found = vals.numpy() > 0
    xy_np = np.where(found[..., None], np.stack([cols + dx, rows + dy], axis=-1), 0.0)
    scores_np = np.where(found, vals.numpy(), 0.0)
    if k < top_m:
        xy_np = np.concatenate([xy_np, np.zeros((b, j, top_m - k, 2))], axis=2)
        scores_np = np.concatenate([scores_np, np.zeros((b, j, top_m - k))], axis=2)
    return xy_np, scores_np


def _parabola_offset(log_hm: np.ndarray, rows: np.ndarray, cols: np.ndarray, along_x: bool) -> np.ndarray:
    """Vertex offset of the log-parabola through each peak and its two neighbours along one axis.

    log_hm (B, J, h, w), rows and cols (B, J, K) -> (B, J, K); 0 at the border and where the log is not concave.
    """
    size = log_hm.shape[3] if along_x else log_hm.shape[2]
    pos = cols if along_x else rows
    bi, ji = np.arange(log_hm.shape[0])[:, None, None], np.arange(log_hm.shape[1])[None, :, None]
    neighbours = [np.clip(pos + shift, 0, size - 1) for shift in (-1, 0, 1)]
    lm, l0, lp = (log_hm[bi, ji, rows, p] if along_x else log_hm[bi, ji, p, cols] for p in neighbours)
    curvature = lm - 2 * l0 + lp
    inside = (pos > 0) & (pos < size - 1) & (curvature < 0)
    offset = np.clip(0.5 * (lm - lp) / np.where(inside, curvature, -1.0), -0.5, 0.5)
    return np.where(inside, offset, 0.0)


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


def associate_joints(
    xy: np.ndarray, scores: np.ndarray, boxes: np.ndarray, dist_thresh: float = 1.0, sigmas: np.ndarray | None = None
) -> np.ndarray:
    """The keypoints of models.joint_association.associate_joints: (P, J, M, 2), (P, J, M), (P, 4) -> (P, J, 3)."""
    xy, scores = np.asarray(xy, dtype=np.float64), np.asarray(scores, dtype=np.float64)
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    n_persons, n_joints, _ = scores.shape
    sigmas = np.asarray(OKS_SIGMAS if sigmas is None else sigmas, dtype=np.float64)
    box_scale = np.sqrt(np.clip(boxes[:, 2] * boxes[:, 3], 0.0, None))
    out = np.zeros((n_persons, n_joints, 3))
    for j in range(n_joints):
        out[:, j] = associate_joint(xy[:, j], scores[:, j], dist_thresh * sigmas[j] * box_scale)
    return out


def joint_nodes(points: np.ndarray, owners: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Cluster candidates into joint nodes: points (C, 2), owners (C,) person ids, radii (C,) -> labels (C,).

    Two candidates of different owners are linked when their distance is at most the mean of their radii;
    the nodes are the connected components of the links.
    """
    if len(points) == 0:
        return np.zeros(0, dtype=int)
    dist = cdist(points, points)
    linked = (dist <= (radii[:, None] + radii[None, :]) / 2) & (owners[:, None] != owners[None, :])
    _, labels = connected_components(csr_matrix(linked), directed=False)
    return labels


def associate_joint(xy: np.ndarray, scores: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """One joint type: xy (P, M, 2), scores (P, M), per-person node radii (P,) -> (P, 3) x, y, score."""
    n_persons = len(scores)
    out = np.zeros((n_persons, 3))
    owners, slots = np.nonzero(scores > 0)
    if len(owners) == 0:
        return out
    labels = joint_nodes(xy[owners, slots], owners, radii[owners])
    weight = np.zeros((n_persons, labels.max() + 1))
    best = np.full(weight.shape, -1)
    for c, (p, node) in enumerate(zip(owners, labels)):
        if scores[p, slots[c]] > weight[p, node]:
            weight[p, node], best[p, node] = scores[p, slots[c]], slots[c]
    own_best = scores.argmax(axis=1)
    has_any = scores.max(axis=1) > 0
    out[has_any, :2] = xy[has_any, own_best[has_any]]
    for p, node in zip(*linear_sum_assignment(weight, maximize=True)):
        if weight[p, node] > 0:
            out[p] = (*xy[p, best[p, node]], weight[p, node])
    return out
