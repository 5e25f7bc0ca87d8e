"""Mean per-joint position error."""

from __future__ import annotations

import numpy as np


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
    """Mean of the valid per-joint errors: (K, J) -> scalar (NaN when none is valid)."""
    errors = np.asarray(errors)
    return float(np.nanmean(errors)) if np.any(np.isfinite(errors)) else float("nan")
