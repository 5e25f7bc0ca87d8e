"""Pairing predicted 3D persons with ground-truth persons, and the per-joint errors (MPJPE) of the pairs."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment


def mean_joint_distance(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Mean distance over joints valid in both (m): (P, J, 4), (G, J, 4) -> (P, G); inf if none shared."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    dist = np.linalg.norm(pred[:, None, :, :3] - gt[None, :, :, :3], axis=-1)
    both = (pred[:, None, :, 3] > 0) & (gt[None, :, :, 3] > 0)
    count = both.sum(-1)
    total = np.where(both, dist, 0.0).sum(-1)
    return np.where(count > 0, total / np.maximum(count, 1), np.inf)


def match_to_ground_truth(pred: np.ndarray, gt: np.ndarray, max_dist_m: float = 0.5) -> np.ndarray:
    """One-to-one matching by mean joint distance: (P, J, 4), (G, J, 4) -> pairs (K, 2) within max_dist_m."""
    if len(pred) == 0 or len(gt) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    cost = mean_joint_distance(pred, gt)
    rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e6))
    keep = cost[rows, cols] <= max_dist_m
    return np.stack([rows[keep], cols[keep]], axis=1).astype(np.int64)


def joint_errors(pred: np.ndarray, gt: np.ndarray, root: tuple[int, ...] | None = None) -> np.ndarray:
    """Per-joint errors (m) of paired poses (K, J, 4), (K, J, 4) -> (K, J), NaN if not both valid; root: align first."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    p, g = pred[..., :3], gt[..., :3]
    if root is not None:
        p = p - p[:, list(root)].mean(axis=1, keepdims=True)
        g = g - g[:, list(root)].mean(axis=1, keepdims=True)
    err = np.linalg.norm(p - g, axis=-1)
    valid = (pred[..., 3] > 0) & (gt[..., 3] > 0)
    if root is not None:
        rooted = np.all(pred[:, list(root), 3] > 0, axis=1) & np.all(gt[:, list(root), 3] > 0, axis=1)
        valid &= rooted[:, None]
    return np.where(valid, err, np.nan)


def mpjpe(errors: np.ndarray) -> float:
    """Mean of the finite values (errors): (K, J) -> scalar (NaN when none is finite)."""
    errors = np.asarray(errors, dtype=np.float64)
    return float(np.nanmean(errors)) if np.any(np.isfinite(errors)) else float("nan")


class PairedEvaluator:
    """Base of the evaluators that pair predictions one-to-one with GT persons within max_dist_m, frame by frame."""

    def __init__(self, max_dist_m: float = 0.5, alpha: float = 0.5) -> None:
        self.max_dist_m, self.alpha = max_dist_m, alpha
        self.errors: list[np.ndarray] = []
        self.parts: list[np.ndarray] = []
        self.num_gt = self.num_matched = 0

    def pair(self, pred: np.ndarray, gt: np.ndarray, root: tuple[int, ...] | None = None) -> np.ndarray:
        """Pair one frame, count it and keep the pairs' joint errors: (P, J, 4), (G, J, 4) -> pairs (K, 2)."""
        pairs = match_to_ground_truth(pred, gt, self.max_dist_m)
        self.num_gt += len(gt)
        self.num_matched += len(pairs)
        self.errors.append(joint_errors(pred[pairs[:, 0]], gt[pairs[:, 1]], root=root))
        return pairs
