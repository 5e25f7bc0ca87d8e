"""Persons reconstructed twice: two persons of different views closer than two bodies can be are one person."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.spatial import cKDTree

BODY_SPAN_M = 1.0  # the centroids of two joint subsets of one body lie closer than this: the pairs worth comparing
ALL_PAIRS_UP_TO = 24  # persons in a frame up to which every pair is compared (a k-d tree of centroids above)


def near_pairs(poses3d: np.ndarray, placed: np.ndarray, within_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs i < j whose centroids of placed joints lie within within_m + BODY_SPAN_M: (P, J, 3+), (P, J) -> (K,) x2."""
    weight = placed.astype(np.float64)
    count = weight.sum(1)
    some = np.flatnonzero(count > 0)
    centroid = np.einsum("pj,pjk->pk", weight[some], poses3d[some, :, :3]) / count[some, None]
    near = cKDTree(centroid).query_pairs(within_m + BODY_SPAN_M, output_type="ndarray").reshape(-1, 2)
    return some[near.min(1)], some[near.max(1)]


def close_pairs(
    poses3d: np.ndarray, placed: np.ndarray, within_m: float, apart: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs i < j closer than within_m, closest first: (P, J, 3+), placed (P, J)[, apart (P,)] -> (K, 2), (K,) m."""
    i, j = all_pairs(len(poses3d)) if len(poses3d) <= ALL_PAIRS_UP_TO else near_pairs(poses3d, placed, within_m)
    if apart is not None:
        disjoint = (apart[i] & apart[j]) == 0
        i, j = i[disjoint], j[disjoint]
    if not len(i):
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    both = placed[i] & placed[j]
    diff = poses3d[i, :, :3] - poses3d[j, :, :3]
    total = (np.sqrt(np.einsum("kjc,kjc->kj", diff, diff)) * both).sum(1)
    count = both.sum(1)
    mean = np.where(count > 0, total / np.maximum(count, 1), np.inf)
    keep = np.flatnonzero(mean < within_m)
    if not len(keep):
        return np.zeros((0, 2), dtype=np.int64), mean[keep]
    keep = keep[np.argsort(mean[keep], kind="stable")]
    return np.stack([i[keep], j[keep]], axis=1), mean[keep]


@lru_cache(maxsize=ALL_PAIRS_UP_TO + 1)
def all_pairs(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Every pair i < j of count persons: (K,) x2 (cached: np.triu_indices builds a matrix each call)."""
    return np.triu_indices(count, 1)


def merge_coincident(poses3d: np.ndarray, views: np.ndarray, assignment: np.ndarray, within_m: float) -> np.ndarray:
    """Join coincident persons: poses (P, J, 4), views (P, J), assignment (P, V) -> (P', V), the same if none joined."""
    if within_m <= 0 or len(assignment) < 2:
        return assignment
    placed = (poses3d[..., 3] > 0) & (views >= 2)  # a joint placed by a prior may stray from its body
    masks = (assignment >= 0) @ (1 << np.arange(assignment.shape[1], dtype=np.int64))  # views < 63 (the matcher's)
    close, _ = close_pairs(poses3d, placed, within_m, masks)
    rows, alive = assignment, np.ones(len(assignment), dtype=bool)
    for i, j in close:
        if alive[i] and alive[j] and not np.any((rows[i] >= 0) & (rows[j] >= 0)):
            rows = rows.copy() if rows is assignment else rows
            rows[i], alive[j] = np.maximum(rows[i], rows[j]), False
    return rows if rows is assignment else rows[alive]
