"""Percentage of correct parts (PCP) on the 10 parts of the Shelf/Campus protocol."""
from __future__ import annotations

import numpy as np

from data.keypoints import SHELF_PCP_PARTS

PART_NAMES: tuple[str, ...] = tuple(SHELF_PCP_PARTS)
# (10, 2) joint pairs of the 15-joint Shelf skeleton (Shelf-14 + mid-hip), and the part of each.
PART_JOINTS = np.array([pair for pairs in SHELF_PCP_PARTS.values() for pair in pairs])
PART_GROUP = np.array([i for i, pairs in enumerate(SHELF_PCP_PARTS.values()) for _ in pairs])


def correct_parts(pred: np.ndarray, gt: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """Which of the 10 parts are correct: (K, 15, 3), (K, 15, 3) -> (K, 10) bool.

    A part (a, b) is correct when the mean of the end-point errors is at most alpha times the
    ground-truth part length: (|p_a - g_a| + |p_b - g_b|) / 2 <= alpha |g_a - g_b|.
    """
    pred = np.asarray(pred, dtype=np.float64)[..., :3]
    gt = np.asarray(gt, dtype=np.float64)[..., :3]
    a, b = PART_JOINTS[:, 0], PART_JOINTS[:, 1]
    err = (np.linalg.norm(pred[:, a] - gt[:, a], axis=-1) + np.linalg.norm(pred[:, b] - gt[:, b], axis=-1)) / 2
    length = np.linalg.norm(gt[:, a] - gt[:, b], axis=-1)
    return err <= alpha * length


def pcp_by_part(correct: np.ndarray) -> dict[str, float]:
    """PCP (%) of each named part and the average: (K, 10) bool -> {part: %, 'average': %}."""
    correct = np.asarray(correct, dtype=bool).reshape(-1, len(PART_JOINTS))
    out = {}
    for i, name in enumerate(PART_NAMES):
        cols = correct[:, PART_GROUP == i]
        out[name] = 100.0 * float(cols.mean()) if cols.size else float("nan")
    out["average"] = 100.0 * float(correct.mean()) if correct.size else float("nan")
    return out
