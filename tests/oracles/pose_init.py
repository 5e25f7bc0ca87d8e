"""Plain-numpy reference of reconstruction.solver.pose_init (frozen from its numba version of Dec 2026, which used
np.linalg.svd / det and np.median): one person at a time, for tests only."""

from __future__ import annotations

import numpy as np

from data.bone_lengths import MEAN_POSE
from reconstruction.solver.pose_init import _MIN_RAY_DEPTH_M, FULL_FIT_MIN_JOINTS, GROSS_OUTLIER_M, OUTLIER_M


def fit_one(points: np.ndarray, known: np.ndarray, template: np.ndarray) -> tuple[np.ndarray, bool]:
    """The template aligned to the known joints (Kabsch by LAPACK's SVD, else a yaw): (J, 3), (J,) -> (J, 3), placed."""
    count = int(known.sum())
    c_src = template[known].sum(0) / max(count, 1)
    c_dst = points[known].sum(0) / max(count, 1)
    cov = (template[known] - c_src).T @ (points[known] - c_dst)
    R = np.eye(3)
    U, S, Vt = np.linalg.svd(cov)
    if count >= FULL_FIT_MIN_JOINTS and S[1] > 1e-3 * max(S[0], 1e-12):
        V = Vt.T.copy()
        V[:, 2] *= np.sign(np.linalg.det(U @ Vt)) or 1.0
        R = V @ U.T
    else:
        angle = np.arctan2(cov[0, 1] - cov[1, 0], cov[0, 0] + cov[1, 1])
        R[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    return (template - c_src) @ R.T + c_dst, count > 0


def inliers(points: np.ndarray, known: np.ndarray, score: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Known joints in front of the cameras that see them and near the shifted, then fitted body: -> (J,) bool."""
    template = MEAN_POSE[: len(points)]
    depth = np.einsum("vk,jk->vj", proj[:, 2, :3], points) + proj[:, 2, 3:]
    ok = known & ~((score > 0) & ~(depth > 0)).any(0)
    offset = np.median(points[ok] - template[ok], axis=0) if ok.any() else np.zeros(3)
    ok &= ~(np.linalg.norm(points - template - offset, axis=1) > GROSS_OUTLIER_M)
    body, _ = fit_one(points, ok, template)
    return ok & ~(np.linalg.norm(points - body, axis=1) > OUTLIER_M)


def start(
    points: np.ndarray, known: np.ndarray, poses2d: np.ndarray, proj: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """pose_init._start, person by person: (P, J, 3), (P, J), (V, P, J, 3), (V, 3, 4) -> (P, J, 3), placed (P,)."""
    score = np.where(np.isfinite(poses2d[..., 0]) & np.isfinite(poses2d[..., 1]), poses2d[..., 2], 0.0)
    out, placed = np.array(points, dtype=np.float64), np.zeros(len(points), dtype=bool)
    for p in range(len(points)):
        ok = inliers(out[p], known[p], score[:, p], proj)
        body, placed[p] = fit_one(out[p], ok, MEAN_POSE[: points.shape[1]])
        for j in np.flatnonzero(~ok):
            best = int(np.argmax(score[:, p, j]))
            out[p, j] = body[j]
            if score[best, p, j] > 0:  # the point of the best view's ray closest to the body's joint
                M = np.linalg.inv(proj[best, :, :3])
                centre = -M @ proj[best, :, 3]
                d = M @ np.append(poses2d[best, p, j, :2], 1.0)
                t = max((body[j] - centre) @ d / (d @ d), _MIN_RAY_DEPTH_M)
                out[p, j] = centre + t * d
    return out, placed
