"""Batched, score-weighted linear triangulation (DLT)."""
from __future__ import annotations

import numpy as np


def triangulate_dlt(poses2d: np.ndarray, proj: np.ndarray, min_views: int = 2) -> np.ndarray:
    """Score-weighted DLT of every joint of every person at once: (V, P, J, 3) -> (P, J, 4).

    poses2d holds undistorted pixels and a score per view (0 = not seen); proj (V, 3, 4) are the
    projection matrices of those pixels. Each view contributes two equations, normalised to unit
    length and weighted by the joint's score. The output is (x, y, z, confidence) with confidence
    the mean score of the views used, and 0 (with NaN-free zeros for x, y, z) for a joint seen in
    fewer than ``min_views`` views.
    """
    poses2d = np.asarray(poses2d, dtype=np.float64)
    proj = np.asarray(proj, dtype=np.float64)
    V, P, J, _ = poses2d.shape
    if proj.shape != (V, 3, 4):
        raise ValueError(f"proj has shape {proj.shape}, expected ({V}, 3, 4) for {V} views")
    xy, score = poses2d[..., :2], np.clip(poses2d[..., 2], 0.0, None)
    score = np.where(np.all(np.isfinite(xy), axis=-1), score, 0.0)
    xy = np.where(score[..., None] > 0, xy, 0.0)

    # rows[v, p, j, r, :] = xy_r * P[v, 2] - P[v, r] for r in (x, y)
    rows = xy[..., :, None] * proj[:, None, None, 2:3, :] - proj[:, None, None, :2, :]
    norms = np.linalg.norm(rows, axis=-1, keepdims=True)
    rows = rows / np.where(norms > 0, norms, 1.0) * score[..., None, None]
    A = rows.transpose(1, 2, 0, 3, 4).reshape(P * J, 2 * V, 4)

    seen = (score > 0).sum(axis=0).reshape(P * J)
    out = np.zeros((P * J, 4))
    solve = seen >= min_views
    if np.any(solve):
        _, _, vt = np.linalg.svd(A[solve])
        X = vt[:, -1, :]
        w = X[:, 3:4]
        ok = np.abs(w[:, 0]) > 1e-12
        pts = np.where(ok[:, None], X[:, :3] / np.where(ok, w[:, 0], 1.0)[:, None], 0.0)
        conf = score.reshape(V, P * J)[:, solve].sum(axis=0) / seen[solve]
        out[solve, :3] = pts
        out[solve, 3] = np.where(ok, conf, 0.0)
    return out.reshape(P, J, 4)


def reprojection_error(points3d: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Pixel distance between projected 3D joints and the 2D joints: (P, J, 4|3), (V, P, J, 3) -> (V, P, J).

    NaN where the 2D joint has score 0 or the 3D joint has confidence 0.
    """
    points3d = np.asarray(points3d, dtype=np.float64)
    poses2d = np.asarray(poses2d, dtype=np.float64)
    homog = np.concatenate([points3d[..., :3], np.ones(points3d.shape[:-1] + (1,))], axis=-1)
    img = np.einsum("vab,pjb->vpja", proj, homog)
    uv = img[..., :2] / img[..., 2:3]
    err = np.linalg.norm(uv - poses2d[..., :2], axis=-1)
    valid = poses2d[..., 2] > 0
    if points3d.shape[-1] == 4:
        valid &= points3d[None, ..., 3] > 0
    return np.where(valid, err, np.nan)
