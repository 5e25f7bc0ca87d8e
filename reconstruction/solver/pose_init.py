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

The per-person work runs in compiled (numba) loops: a frame of a few persons costs microseconds.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from data.bone_lengths import MEAN_POSE

FULL_FIT_MIN_JOINTS = 6
GROSS_OUTLIER_M = 1.5  # from the mean body translated to the median joint: wrong by any pose
OUTLIER_M = 0.75  # from the fitted body: beyond a walking stride or a raised arm
_MIN_RAY_DEPTH_M = 0.1


@njit(cache=True)
def _fit_one(points: np.ndarray, known: np.ndarray, template: np.ndarray, out: np.ndarray) -> bool:
    """The template aligned to the known joints of one person (rotation + translation) into out (J, 3): placed."""
    J = len(points)
    count = 0
    c_src, c_dst = np.zeros(3), np.zeros(3)
    for j in range(J):
        if known[j]:
            count += 1
            for i in range(3):
                c_src[i] += template[j, i]
                c_dst[i] += points[j, i]
    c_src /= max(count, 1)
    c_dst /= max(count, 1)
    cov = np.zeros((3, 3))
    cross, dot = 0.0, 0.0
    for j in range(J):
        if known[j]:
            s0, s1, s2 = template[j, 0] - c_src[0], template[j, 1] - c_src[1], template[j, 2] - c_src[2]
            d0, d1, d2 = points[j, 0] - c_dst[0], points[j, 1] - c_dst[1], points[j, 2] - c_dst[2]
            cov[0, 0] += s0 * d0
            cov[0, 1] += s0 * d1
            cov[0, 2] += s0 * d2
            cov[1, 0] += s1 * d0
            cov[1, 1] += s1 * d1
            cov[1, 2] += s1 * d2
            cov[2, 0] += s2 * d0
            cov[2, 1] += s2 * d1
            cov[2, 2] += s2 * d2
            cross += s0 * d1 - s1 * d0
            dot += s0 * d0 + s1 * d1
    R = np.eye(3)
    full = False
    if count >= FULL_FIT_MIN_JOINTS:
        U, S, Vt = np.linalg.svd(cov)
        full = S[1] > 1e-3 * max(S[0], 1e-12)
    if full:  # Kabsch: R = V diag(1, 1, det) U^T
        det = np.sign(np.linalg.det(U @ Vt))
        V = Vt.T.copy()
        V[:, 2] *= det if det != 0.0 else 1.0
        R = V @ U.T
    else:  # rotation about z only
        angle = np.arctan2(cross, dot)
        R[0, 0], R[0, 1], R[1, 0], R[1, 1] = np.cos(angle), -np.sin(angle), np.sin(angle), np.cos(angle)
    for j in range(J):
        s0, s1, s2 = template[j, 0] - c_src[0], template[j, 1] - c_src[1], template[j, 2] - c_src[2]
        for i in range(3):
            out[j, i] = R[i, 0] * s0 + R[i, 1] * s1 + R[i, 2] * s2 + c_dst[i]
    return count > 0


@njit(cache=True)
def _fit_bodies(points: np.ndarray, known: np.ndarray, template: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """_fit_one of every person: (P, J, 3), (P, J) -> bodies (P, J, 3), placed (P,)."""
    P = len(points)
    out, placed = np.empty(points.shape), np.zeros(P, dtype=np.bool_)
    for p in range(P):
        placed[p] = _fit_one(points[p], known[p], template, out[p])
    return out, placed


@njit(cache=True)
def _masked_median(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Median over the masked rows of each column, 0 without any: (J, 3), (J,) -> (3,)."""
    out = np.zeros(3)
    n = mask.sum()
    if n:
        column = np.empty(n)
        for i in range(3):
            k = 0
            for j in range(len(mask)):
                if mask[j]:
                    column[k] = values[j, i]
                    k += 1
            out[i] = np.median(column)
    return out


@njit(cache=True)
def _distance(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """|a - b - c| of 3-vectors."""
    d0, d1, d2 = a[0] - b[0] - c[0], a[1] - b[1] - c[1], a[2] - b[2] - c[2]
    return np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@njit(cache=True)
def _inliers(
    points: np.ndarray, known: np.ndarray, score: np.ndarray, proj: np.ndarray, template: np.ndarray
) -> np.ndarray:
    """Known joints that are not gross outliers: (P, J, 3), (P, J), scores (V, P, J), (V, 3, 4) -> (P, J)."""
    P, J = known.shape
    ok = known.copy()
    zero = np.zeros(3)
    for p in range(P):
        for j in range(J):
            X = points[p, j]
            for v in range(len(proj)):
                depth = proj[v, 2, 0] * X[0] + proj[v, 2, 1] * X[1] + proj[v, 2, 2] * X[2] + proj[v, 2, 3]
                if score[v, p, j] > 0 and not depth > 0:
                    ok[p, j] = False
        offset = _masked_median(points[p] - template, ok[p])
        for j in range(J):
            if _distance(points[p, j], template[j], offset) > GROSS_OUTLIER_M:
                ok[p, j] = False
    bodies, _ = _fit_bodies(points, ok, template)
    for p in range(P):
        for j in range(J):
            if _distance(points[p, j], bodies[p, j], zero) > OUTLIER_M:
                ok[p, j] = False
    return ok


@njit(cache=True)
def _onto_rays(
    guess: np.ndarray, xy: np.ndarray, score: np.ndarray, Minv: np.ndarray, centre: np.ndarray
) -> np.ndarray:
    """Point of the best-scored view's ray closest to each guess (P, J, 3); unseen joints keep theirs."""
    out = guess.copy()
    P, J = guess.shape[:2]
    for p in range(P):
        for j in range(J):
            best = np.argmax(score[:, p, j])
            if not score[best, p, j] > 0:
                continue
            u, w = xy[best, p, j, 0], xy[best, p, j, 1]
            M, c, g = Minv[best], centre[best], guess[p, j]
            d0 = M[0, 0] * u + M[0, 1] * w + M[0, 2]
            d1 = M[1, 0] * u + M[1, 1] * w + M[1, 2]
            d2 = M[2, 0] * u + M[2, 1] * w + M[2, 2]
            t = ((g[0] - c[0]) * d0 + (g[1] - c[1]) * d1 + (g[2] - c[2]) * d2) / (d0 * d0 + d1 * d1 + d2 * d2)
            t = max(t, _MIN_RAY_DEPTH_M)  # in front of the camera
            out[p, j, 0], out[p, j, 1], out[p, j, 2] = c[0] + t * d0, c[1] + t * d1, c[2] + t * d2
    return out


def _views(poses2d: np.ndarray, proj: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Contiguous pixels (V, P, J, 2), scores (V, P, J) (0 where not finite), M^-1 (V, 3, 3), centres (V, 3)."""
    poses2d = np.asarray(poses2d, dtype=np.float64)
    score = np.where(np.isfinite(poses2d[..., 0]) & np.isfinite(poses2d[..., 1]), poses2d[..., 2], 0.0)
    Minv = np.linalg.inv(proj[:, :, :3])
    centre = -np.matmul(Minv, proj[:, :, 3:])[..., 0]
    return np.ascontiguousarray(poses2d[..., :2]), np.ascontiguousarray(score), Minv, centre


def fit_mean_body(points: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean body aligned to each person's known joints: (P, J, 3), (P, J) bool -> (P, J, 3), placed (P,)."""
    return _fit_bodies(
        np.ascontiguousarray(points, dtype=np.float64), np.asarray(known, dtype=bool), MEAN_POSE[: points.shape[1]]
    )


def _start(
    points: np.ndarray, known: np.ndarray, poses2d: np.ndarray, proj: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Inliers of points kept, every other joint from the fitted body moved onto its ray -> (P, J, 3), placed (P,)."""
    xy, score, Minv, centre = _views(poses2d, proj)
    points = np.ascontiguousarray(points, dtype=np.float64)
    template = MEAN_POSE[: points.shape[1]]
    inl = _inliers(points, np.asarray(known, dtype=bool), score, np.asarray(proj, dtype=np.float64), template)
    body, placed = _fit_bodies(points, inl, template)
    return np.where(inl[..., None], points, _onto_rays(body, xy, score, Minv, centre)), placed


def initial_poses(dlt: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start poses from the DLT and the fitted mean body: (P, J, 4), (V, P, J, 3), (V, 3, 4) -> (P, J, 3), placed (P,).

    poses2d are undistorted pixels + score. placed is False for a person without any usable
    triangulated joint (nothing to anchor the body to).
    """
    dlt = np.asarray(dlt, dtype=np.float64)
    return _start(dlt[..., :3], dlt[..., 3] > 0, poses2d, proj)


def reinitialise_outliers(X: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Reset the gross outliers of a solved pose to the fitted body (as initial_poses does for the DLT):
    (P, J, 3), (V, P, J, 3) undistorted px + score, (V, 3, 4) -> (P, J, 3).

    Used between the MLE and MAP stages: the MLE keeps a joint seen along nearly parallel rays where
    its likelihood alone puts it, possibly metres away, and the MAP would start far outside its basin.
    """
    return _start(X, np.any(np.asarray(poses2d)[..., 2] > 0, axis=0), poses2d, proj)[0]
