"""Initial 3D poses for the MLE / MAP solvers: the DLT where a joint is triangulated, a fitted mean body elsewhere.

Joints the DLT reconstructed (seen in >= min_views views) are kept unless they are gross outliers:
behind a camera that sees them, farther than ``GROSS_OUTLIER_M`` from the mean body placed at the
median of the person's joints, or farther than ``OUTLIER_M`` from the body fitted to the remaining
joints (a DLT of two nearly parallel rays can land metres away and would start the solver far outside
the basin of the optimum). An outlier is re-initialised like an untriangulated joint; it keeps all its
observations in the solve. The mean standing body of
``data.bone_lengths.MEAN_POSE`` is aligned to them per person (a rotation + translation, no scale)
and supplies every other joint; a joint seen in exactly one view (or whose DLT failed) is then moved
to the point of that view's ray (the best-scored view's) closest to the body guess, so it starts
consistent with its observation. The rotation is a full 3D Kabsch fit when at least
``FULL_FIT_MIN_JOINTS`` non-collinear joints are known, else a rotation about the vertical z axis only
(DESIGN.md: world z up; people in a crowd stand upright), else none.
"""
from __future__ import annotations

import numpy as np

from data.bone_lengths import MEAN_POSE

FULL_FIT_MIN_JOINTS = 6
GROSS_OUTLIER_M = 1.5   # from the mean body translated to the median joint: wrong by any pose
OUTLIER_M = 0.75        # from the fitted body: beyond a walking stride or a raised arm
_MIN_RAY_DEPTH_M = 0.1


def _kabsch(src: np.ndarray, dst: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations src -> dst of centred masked points, and whether each is well-posed: (P, J, 3) x 2, (P, J) -> (P, 3, 3), (P,)."""
    cov = np.matmul((src * mask[..., None]).transpose(0, 2, 1), dst)
    U, S, Vt = np.linalg.svd(cov)
    det = np.sign(_det3(np.matmul(U, Vt)))
    D = np.ones((len(cov), 3))
    D[:, 2] = np.where(det == 0, 1.0, det)
    R = np.matmul(Vt.transpose(0, 2, 1) * D[:, None, :], U.transpose(0, 2, 1))          # V D U^T
    ok = (mask.sum(axis=1) >= FULL_FIT_MIN_JOINTS) & (S[:, 1] > 1e-3 * np.maximum(S[:, 0], 1e-12))
    return R, ok


def _det3(M: np.ndarray) -> np.ndarray:
    """Determinants of 3x3 matrices: (..., 3, 3) -> (...)."""
    return (M[..., 0, 0] * (M[..., 1, 1] * M[..., 2, 2] - M[..., 1, 2] * M[..., 2, 1])
            - M[..., 0, 1] * (M[..., 1, 0] * M[..., 2, 2] - M[..., 1, 2] * M[..., 2, 0])
            + M[..., 0, 2] * (M[..., 1, 0] * M[..., 2, 1] - M[..., 1, 1] * M[..., 2, 0]))


def _yaw(src: np.ndarray, dst: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Rotations about z aligning centred masked points in the ground plane: (P, J, 3) x 2, (P, J) -> (P, 3, 3)."""
    m = mask.astype(float)
    cross = np.sum(m * (src[..., 0] * dst[..., 1] - src[..., 1] * dst[..., 0]), axis=1)
    dot = np.sum(m * (src[..., 0] * dst[..., 0] + src[..., 1] * dst[..., 1]), axis=1)
    angle = np.arctan2(cross, dot)
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((len(angle), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def fit_mean_body(points: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean body aligned to each person's known joints: (P, J, 3), (P, J) bool -> (P, J, 3), placed (P,)."""
    P, J, _ = points.shape
    template = np.broadcast_to(MEAN_POSE[:J], (P, J, 3))
    count = known.sum(axis=1)
    m = known[..., None].astype(float)
    c_src = (template * m).sum(axis=1) / np.maximum(count, 1)[:, None]
    c_dst = (np.where(known[..., None], points, 0.0)).sum(axis=1) / np.maximum(count, 1)[:, None]
    src = template - c_src[:, None]
    dst = np.where(known[..., None], points - c_dst[:, None], 0.0)
    R, full_ok = _kabsch(src, dst, known)
    if not full_ok.all():
        R = np.where(full_ok[:, None, None], R, _yaw(src, dst, known))
    return np.matmul(src, R.transpose(0, 2, 1)) + c_dst[:, None], count > 0


def closest_on_rays(guess: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Point of the best-scored view's ray closest to each guess: (P, J, 3), (V, P, J, 3), (V, 3, 4) -> (P, J, 3).

    poses2d are undistorted pixels + score; joints seen in no view keep their guess.
    """
    M, p4 = proj[:, :, :3], proj[:, :, 3]
    Minv = np.linalg.inv(M)
    centre = -np.matmul(Minv, p4[..., None])[..., 0]                              # (V, 3)
    score = np.where(np.isfinite(poses2d[..., 0]) & np.isfinite(poses2d[..., 1]), poses2d[..., 2], 0.0)
    best = np.argmax(score, axis=0)                                               # (P, J)
    seen = np.take_along_axis(score, best[None], axis=0)[0] > 0
    uv = np.take_along_axis(np.where(score[..., None] > 0, poses2d[..., :2], 0.0), best[None, ..., None], 0)[0]
    homog = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1)
    d = np.matmul(Minv[best], homog[..., None])[..., 0]
    c = centre[best]
    t = _dot3(guess - c, d) / _dot3(d, d)
    # keep the point in front of the camera (depth along the ray direction, d has unit third image row)
    t = np.maximum(t, _MIN_RAY_DEPTH_M)
    return np.where(seen[..., None], c + t[..., None] * d, guess)


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of 3-vectors: (..., 3) x 2 -> (...)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _in_front(points: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Whether each point has positive depth in every view that sees it: (P, J, 3), (V, P, J, 3), (V, 3, 4) -> (P, J)."""
    depth = np.matmul(proj[:, None, 2, :3], points.reshape(-1, 3).T).reshape((len(proj),) + points.shape[:2]) \
        + proj[:, None, None, 2, 3]
    return np.all((depth > 0) | ~(poses2d[..., 2] > 0), axis=0)


def _masked_median(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-person median over the masked joints, 0 without any: (P, J, 3), (P, J) -> (P, 3) (np.nanmedian, sorted)."""
    ranked = np.sort(np.where(mask[..., None], values, np.inf), axis=1)          # masked joints first
    count = mask.sum(axis=1)[:, None, None]
    lo = np.take_along_axis(ranked, np.maximum(count - 1, 0) // 2, axis=1)[:, 0]
    hi = np.take_along_axis(ranked, count // 2 - (count == 0), axis=1)[:, 0]
    return np.where(count[:, 0] > 0, 0.5 * (lo + hi), 0.0)


def inlier_joints(points: np.ndarray, known: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Known joints that are not gross outliers (see the module docstring): (P, J, 3), (P, J), ... -> (P, J)."""
    ok = known & _in_front(points, poses2d, proj)
    template = MEAN_POSE[: points.shape[1]]
    offset = _masked_median(points - template, ok)
    far = points - template - offset[:, None]
    ok &= np.sqrt(_dot3(far, far)) <= GROSS_OUTLIER_M
    body, _ = fit_mean_body(points, ok)
    off = points - body
    return ok & (np.sqrt(_dot3(off, off)) <= OUTLIER_M)


def initial_poses(dlt: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start poses from the DLT and the fitted mean body: (P, J, 4), (V, P, J, 3), (V, 3, 4) -> (P, J, 3), placed (P,).

    placed is False for a person without any usable triangulated joint (nothing to anchor the body to).
    """
    dlt = np.asarray(dlt, dtype=np.float64)
    known = inlier_joints(dlt[..., :3], dlt[..., 3] > 0, poses2d, proj)
    body, placed = fit_mean_body(dlt[..., :3], known)
    guess = closest_on_rays(body, poses2d, proj)
    return np.where(known[..., None], dlt[..., :3], guess), placed


def reinitialise_outliers(X: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Reset the gross outliers of a solved pose to the fitted body (as initial_poses does for the DLT):
    (P, J, 3), (V, P, J, 3) undistorted px + score, (V, 3, 4) -> (P, J, 3).

    Used between the MLE and MAP stages: the MLE keeps a joint seen along nearly parallel rays where
    its likelihood alone puts it, possibly metres away, and the MAP would start far outside its basin.
    """
    seen = np.any(poses2d[..., 2] > 0, axis=0)
    known = inlier_joints(X, seen, poses2d, proj)
    body, _ = fit_mean_body(X, known)
    return np.where(known[..., None], X, closest_on_rays(body, poses2d, proj))
