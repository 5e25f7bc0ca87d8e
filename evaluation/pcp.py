"""Percentage of correct parts (PCP) on the 10 parts of the Shelf/Campus protocol."""

from __future__ import annotations

import numpy as np

from data.keypoints import SHELF_PCP_PARTS

PART_NAMES: tuple[str, ...] = tuple(SHELF_PCP_PARTS)
# (10, 2) joint pairs of the 15-joint Shelf skeleton (Shelf-14 + mid-hip), and the part of each.
PART_JOINTS = np.array([pair for pairs in SHELF_PCP_PARTS.values() for pair in pairs])
PART_GROUP = np.array([i for i, pairs in enumerate(SHELF_PCP_PARTS.values()) for _ in pairs])


def correct_parts(pred: np.ndarray, gt: np.ndarray, alpha: float = 0.5, parts: np.ndarray = PART_JOINTS) -> np.ndarray:
    """Which parts (N, 2) are correct: (K, J, 3), (K, J, 3) -> (K, N) bool (mean end error <= alpha x length)."""
    pred = np.asarray(pred, dtype=np.float64)[..., :3]
    gt = np.asarray(gt, dtype=np.float64)[..., :3]
    a, b = parts[:, 0], parts[:, 1]
    err = (np.linalg.norm(pred[:, a] - gt[:, a], axis=-1) + np.linalg.norm(pred[:, b] - gt[:, b], axis=-1)) / 2
    return err <= alpha * np.linalg.norm(gt[:, a] - gt[:, b], axis=-1)


def pcp_by_part(correct: np.ndarray, valid: np.ndarray | None = None) -> dict[str, float]:
    """PCP (%) of each part and their average over the valid parts: (K, 10) bool [, (K, 10) bool] -> {part: %}."""
    correct = np.asarray(correct, dtype=bool).reshape(-1, len(PART_JOINTS))
    valid = np.ones_like(correct) if valid is None else np.asarray(valid, dtype=bool).reshape(correct.shape)
    out = {}
    for i, name in enumerate(PART_NAMES):
        cols, use = correct[:, PART_GROUP == i], valid[:, PART_GROUP == i]
        out[name] = 100.0 * float(cols[use].mean()) if use.any() else float("nan")
    out["average"] = 100.0 * float(correct[valid].mean()) if valid.any() else float("nan")
    return out


def part_validity(valid15: np.ndarray) -> np.ndarray:
    """A part is scored when both its Shelf-14 + mid-hip ends are valid: (K, 15) bool -> (K, 10) bool."""
    valid15 = np.asarray(valid15, dtype=bool)
    return valid15[:, PART_JOINTS[:, 0]] & valid15[:, PART_JOINTS[:, 1]]
