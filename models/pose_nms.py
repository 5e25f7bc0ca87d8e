"""Pose-NMS of one image's persons: a person's duplicate boxes merged into one pose (AlphaPose's idea, simplified)."""

from __future__ import annotations

import numpy as np

from data.keypoints import OKS_SIGMAS


def joint_similarity(reference: np.ndarray, others: np.ndarray, area: float, sigmas: np.ndarray) -> np.ndarray:
    """Per-joint keypoint similarity: reference (J, 3), others (K, J, 3), area of the reference box -> (K, J)."""
    d2 = ((others[..., :2] - reference[None, :, :2]) ** 2).sum(-1)
    return np.exp(-d2 / (2 * max(area, 1e-9) * (2 * sigmas[None, :]) ** 2))


def find_duplicates(
    keypoints: np.ndarray, boxes: np.ndarray, scores: np.ndarray, oks: float = 0.7, sigmas: np.ndarray | None = None
) -> list[tuple[int, np.ndarray]]:
    """Keypoints (N, J, 3), boxes (N, 4) xywh, scores (N,) -> (kept index, its duplicates (D,)) in input order."""
    keypoints = np.asarray(keypoints, dtype=np.float64)
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    if not len(keypoints) == len(boxes) == len(scores):
        raise ValueError(
            f"pose-NMS: shape mismatch: keypoints {keypoints.shape}, boxes {boxes.shape}, scores {scores.shape}"
        )
    sigmas = OKS_SIGMAS if sigmas is None else np.asarray(sigmas, dtype=np.float64)
    remaining = np.argsort(-scores, kind="stable")
    groups = []
    while len(remaining):
        a, rest = int(remaining[0]), remaining[1:]
        seen = keypoints[a, :, 2] > 0
        sim = joint_similarity(keypoints[a], keypoints[rest], boxes[a, 2] * boxes[a, 3], sigmas)
        overlap = sim[:, seen].mean(axis=1) if seen.any() else np.zeros(len(rest))
        groups.append((a, rest[overlap > oks]))
        remaining = rest[overlap <= oks]
    return sorted(groups, key=lambda g: g[0])


def merge_joints(
    reference: np.ndarray, duplicates: np.ndarray, area: float, oks: float = 0.7, sigmas: np.ndarray | None = None
) -> np.ndarray:
    """Merge duplicates (K, J, 3) into reference (J, 3) of box area ``area`` -> (J, 3)."""
    if len(duplicates) == 0:
        return reference.copy()
    sigmas = OKS_SIGMAS if sigmas is None else np.asarray(sigmas, dtype=np.float64)
    agree = joint_similarity(reference, duplicates, area, sigmas) > oks
    group = np.concatenate([reference[None], duplicates])  # (K + 1, J, 3)
    use = np.concatenate([np.ones((1, len(reference)), dtype=bool), agree]) & (group[..., 2] > 0)
    use &= reference[None, :, 2] > 0
    weight = np.where(use, group[..., 2], 0.0)
    total = weight.sum(0)
    mean = (weight[..., None] * group[..., :2]).sum(0) / np.where(total > 0, total, 1.0)[:, None]
    return np.where(total[:, None] > 0, np.column_stack([mean, weight.max(0)]), reference)


def pose_nms(
    keypoints: np.ndarray, boxes: np.ndarray, scores: np.ndarray, oks: float = 0.7, sigmas: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints (N, J, 3), boxes (N, 4) xywh, scores (N,) -> kept indices (K,) in order, merged keypoints (K, J, 3)."""
    groups = find_duplicates(keypoints, boxes, scores, oks, sigmas)
    keypoints, boxes = np.asarray(keypoints, dtype=np.float64), np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    merged = [merge_joints(keypoints[a], keypoints[dup], boxes[a, 2] * boxes[a, 3], oks, sigmas) for a, dup in groups]
    keep = np.array([a for a, _ in groups], dtype=int)
    return keep, np.array(merged).reshape(len(keep), *keypoints.shape[1:])
