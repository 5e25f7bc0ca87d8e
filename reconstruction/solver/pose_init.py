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
_JACOBI_SWEEPS = 30  # a 3x3 SVD converges in ~4-6 (quadratically)


@njit(cache=True)
def _kabsch(cov: np.ndarray, R: np.ndarray) -> bool:
    """R (3, 3) = V diag(1, 1, det) U^T of cov = U S V^T (one-sided Jacobi SVD); False if rank < 2 (R untouched).

    Compact scalar loops: numba's compile time grows with every array access written out (np.linalg's
    wrappers take seconds).
    """
    WV = np.zeros((6, 3))  # rows 0-2: cov -> U S (columns orthogonalised by plane rotations); 3-5: I -> V
    for r in range(3):
        for k in range(3):
            WV[r, k] = cov[r, k]
        WV[3 + r, r] = 1.0
    for _ in range(_JACOBI_SWEEPS):
        rotated = False
        for a in range(2):
            for b in range(a + 1, 3):
                alpha, beta, gamma = 0.0, 0.0, 0.0
                for r in range(3):
                    alpha += WV[r, a] * WV[r, a]
                    beta += WV[r, b] * WV[r, b]
                    gamma += WV[r, a] * WV[r, b]
                if abs(gamma) <= 1e-15 * np.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                c = 1.0 / np.sqrt(1.0 + t * t)
                for r in range(6):
                    x = WV[r, a]
                    WV[r, a] = c * x - c * t * WV[r, b]
                    WV[r, b] = c * t * x + c * WV[r, b]
        if not rotated:
            break
    S = np.zeros(3)
    for k in range(3):
        S[k] = np.sqrt(WV[0, k] * WV[0, k] + WV[1, k] * WV[1, k] + WV[2, k] * WV[2, k])
    k0 = 0 if S[0] >= S[1] and S[0] >= S[2] else (1 if S[1] >= S[2] else 2)
    k1 = (k0 + 1) % 3 if S[(k0 + 1) % 3] >= S[(k0 + 2) % 3] else (k0 + 2) % 3
    if not S[k1] > 1e-3 * max(S[k0], 1e-12):
        return False
    for r in range(3):  # U's columns
        WV[r, k0] /= S[k0]
        WV[r, k1] /= S[k1]
    for i in range(3):  # the third pair as cross products: both frames right-handed, the det correction
        nv = WV[3 + (i + 1) % 3, k0] * WV[3 + (i + 2) % 3, k1] - WV[3 + (i + 2) % 3, k0] * WV[3 + (i + 1) % 3, k1]
        for m in range(3):
            nu = WV[(m + 1) % 3, k0] * WV[(m + 2) % 3, k1] - WV[(m + 2) % 3, k0] * WV[(m + 1) % 3, k1]
            R[i, m] = WV[3 + i, k0] * WV[m, k0] + WV[3 + i, k1] * WV[m, k1] + nv * nu
    return True


@njit(cache=True)
def _fit_one(points: np.ndarray, known: np.ndarray, template: np.ndarray, out: np.ndarray) -> bool:
    """The template aligned to the known joints of one person (rotation + translation) into out (J, 3): placed."""
    count = 0
    c = np.zeros((2, 3))  # centroids of the template (0) and the points (1) over the known joints
    for j in range(len(points)):
        if known[j]:
            count += 1
            for i in range(3):
                c[0, i] += template[j, i]
                c[1, i] += points[j, i]
    for i in range(3):
        c[0, i] /= max(count, 1)
        c[1, i] /= max(count, 1)
    cov = np.zeros((3, 3))
    for j in range(len(points)):
        if known[j]:
            for a in range(3):
                for b in range(3):
                    cov[a, b] += (template[j, a] - c[0, a]) * (points[j, b] - c[1, b])
    R = np.zeros((3, 3))
    if not (count >= FULL_FIT_MIN_JOINTS and _kabsch(cov, R)):  # rotation about z only
        angle = np.arctan2(cov[0, 1] - cov[1, 0], cov[0, 0] + cov[1, 1])
        R[0, 0], R[0, 1], R[1, 0], R[1, 1] = np.cos(angle), -np.sin(angle), np.sin(angle), np.cos(angle)
        R[2, 2] = 1.0
    for j in range(len(points)):
        for i in range(3):
            x = 0.0
            for k in range(3):
                x += R[i, k] * (template[j, k] - c[0, k])
            out[j, i] = x + c[1, i]
    return count > 0


@njit(cache=True)
def _fit_bodies(points: np.ndarray, known: np.ndarray, template: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """_fit_one of every person: (P, J, 3), (P, J) -> bodies (P, J, 3), placed (P,)."""
    P, J = known.shape
    out, placed = np.empty((P, J, 3)), np.zeros(P, dtype=np.bool_)
    for p in range(P):
        placed[p] = _fit_one(points[p], known[p], template, out[p])
    return out, placed


@njit(cache=True)
def _median_offset(points: np.ndarray, template: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Median of points - template over the masked joints per axis, 0 without any: (J, 3), (J, 3), (J,) -> (3,).

    An insertion sort of <= J values (np.median compiles for seconds).
    """
    out, sorted_ = np.zeros(3), np.empty(len(mask))
    for i in range(3):
        n = 0
        for j in range(len(mask)):
            if mask[j]:
                x = points[j, i] - template[j, i]
                k = n
                while k > 0 and sorted_[k - 1] > x:
                    sorted_[k] = sorted_[k - 1]
                    k -= 1
                sorted_[k] = x
                n += 1
        if n:
            out[i] = (sorted_[(n - 1) // 2] + sorted_[n // 2]) / 2
    return out


@njit(cache=True)
def _far(a: np.ndarray, b: np.ndarray, c: np.ndarray, limit: float) -> bool:
    """|a - b - c| > limit of 3-vectors."""
    d = 0.0
    for i in range(3):
        e = a[i] - b[i] - c[i]
        d += e * e
    return np.sqrt(d) > limit


@njit(cache=True)
def _inliers(
    points: np.ndarray, known: np.ndarray, score: np.ndarray, proj: np.ndarray, template: np.ndarray
) -> np.ndarray:
    """Known joints that are not gross outliers: (P, J, 3), (P, J), scores (V, P, J), (V, 3, 4) -> (P, J)."""
    P, J = known.shape
    ok = known.copy()
    for p in range(P):
        for j in range(J):
            for v in range(len(proj)):
                depth = 0.0
                for i in range(3):
                    depth += proj[v, 2, i] * points[p, j, i]
                if score[v, p, j] > 0 and not depth + proj[v, 2, 3] > 0:
                    ok[p, j] = False
        offset = _median_offset(points[p], template, ok[p])
        for j in range(J):
            ok[p, j] &= not _far(points[p, j], template[j], offset, GROSS_OUTLIER_M)
    bodies, _ = _fit_bodies(points, ok, template)
    zero = np.zeros(3)
    for p in range(P):
        for j in range(J):
            ok[p, j] &= not _far(points[p, j], bodies[p, j], zero, OUTLIER_M)
    return ok


@njit(cache=True)
def _onto_rays(
    guess: np.ndarray, xy: np.ndarray, score: np.ndarray, Minv: np.ndarray, centre: np.ndarray
) -> np.ndarray:
    """Point of the best-scored view's ray closest to each guess (P, J, 3); unseen joints keep theirs."""
    out = guess.copy()
    d = np.empty(3)
    for p in range(len(guess)):
        for j in range(guess.shape[1]):
            best = 0  # np.argmax(score[:, p, j]): the first maximum, or the first NaN
            for v in range(len(score)):
                if not score[v, p, j] <= score[best, p, j] and not np.isnan(score[best, p, j]):
                    best = v
            if not score[best, p, j] > 0:
                continue
            num, den = 0.0, 0.0
            for i in range(3):
                d[i] = Minv[best, i, 0] * xy[best, p, j, 0] + Minv[best, i, 1] * xy[best, p, j, 1] + Minv[best, i, 2]
                num += (guess[p, j, i] - centre[best, i]) * d[i]
                den += d[i] * d[i]
            t = max(num / den, _MIN_RAY_DEPTH_M)  # in front of the camera
            for i in range(3):
                out[p, j, i] = centre[best, i] + t * d[i]
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
