"""Associating predicted 3D persons with ground-truth persons for the 3D metrics."""

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
    finite = np.where(np.isfinite(cost), cost, 1e6)
    rows, cols = linear_sum_assignment(finite)
    keep = cost[rows, cols] <= max_dist_m
    return np.stack([rows[keep], cols[keep]], axis=1).astype(np.int64)
