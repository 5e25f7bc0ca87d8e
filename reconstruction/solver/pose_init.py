"""Start poses for the MLE / MAP: the DLT where a joint is triangulated, a fitted mean body elsewhere."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from data.bone_lengths import MEAN_POSE

FULL_FIT_MIN_JOINTS = 6
GROSS_OUTLIER_M = 1.5  # from the mean body translated to the median joint: wrong by any pose
OUTLIER_M = 0.75  # from the fitted body: beyond a walking stride or a raised arm
_MIN_RAY_DEPTH_M = 0.1
_JACOBI_SWEEPS = 30  # a 3x3 converges in 3-5 (quadratically; the last sweep finds nothing to rotate)


@njit(cache=True)
def _jacobi_svd(m: np.ndarray, sweeps: int) -> None:
    """One-sided Jacobi SVD of the 3x3 in m[0:3] (-> U S) with m[3:6] = I (-> V): plane rotations until none."""
    for r in range(3):
        m[3 + r, r] = 1.0
    for _ in range(sweeps):
        rotated = False
        for a in range(2):
            for b in range(a + 1, 3):
                alpha, beta, gamma = 0.0, 0.0, 0.0
                for r in range(3):
                    alpha, beta, gamma = alpha + m[r, a] ** 2, beta + m[r, b] ** 2, gamma + m[r, a] * m[r, b]
                if abs(gamma) > 1e-15 * np.sqrt(alpha * beta):  # a plane rotation orthogonalises columns a, b
                    rotated = True
                    zeta = (beta - alpha) / (2.0 * gamma)
                    t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                    c = 1.0 / np.sqrt(1.0 + t * t)
                    for r in range(6):
                        x = m[r, a]
                        m[r, a], m[r, b] = c * x - c * t * m[r, b], c * t * x + c * m[r, b]
        if not rotated:
            break


@njit(cache=True)
def _fit_one(points: np.ndarray, known: np.ndarray, template: np.ndarray, out: np.ndarray, m: np.ndarray) -> bool:
    """The template (J, 3) aligned to the known (J,) of points (J, 3) into out (J, 3) -> placed; m (12, 3) scratch."""
    for r in range(12):  # rows 0-2: cov -> U S; 3-5: I -> V; 6, 7: template, point centroids; 8: S; 9-11: R
        for k in range(3):
            m[r, k] = 0.0
    count = 0
    for j in range(len(points)):
        if known[j]:
            count += 1
            for i in range(3):
                m[6, i] += template[j, i]
                m[7, i] += points[j, i]
    for i in range(6, 8):
        for k in range(3):
            m[i, k] /= max(count, 1)
    for j in range(len(points)):
        if known[j]:
            for a in range(3):
                for b in range(3):
                    m[a, b] += (template[j, a] - m[6, a]) * (points[j, b] - m[7, b])
    angle = np.arctan2(m[0, 1] - m[1, 0], m[0, 0] + m[1, 1])  # the yaw fallback
    _jacobi_svd(m, _JACOBI_SWEEPS if count >= FULL_FIT_MIN_JOINTS else 0)
    for k in range(3):
        m[8, k] = np.sqrt(m[0, k] ** 2 + m[1, k] ** 2 + m[2, k] ** 2)
    k2 = 0 if m[8, 0] <= m[8, 1] and m[8, 0] <= m[8, 2] else (1 if m[8, 1] <= m[8, 2] else 2)  # the smallest
    k0, k1 = (k2 + 1) % 3, (k2 + 2) % 3
    full = count >= FULL_FIT_MIN_JOINTS and min(m[8, k0], m[8, k1]) > 1e-3 * max(m[8, k0], m[8, k1], 1e-12)
    for i in range(3 if full else 0):  # R = v0 u0^T + v1 u1^T + (v0 x v1)(u0 x u1)^T: Kabsch's det correction
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        nv = m[3 + i1, k0] * m[3 + i2, k1] - m[3 + i2, k0] * m[3 + i1, k1]
        for k in range(3):
            k_1, k_2 = (k + 1) % 3, (k + 2) % 3
            nu = (m[k_1, k0] * m[k_2, k1] - m[k_2, k0] * m[k_1, k1]) / (m[8, k0] * m[8, k1])
            m[9 + i, k] = m[3 + i, k0] * m[k, k0] / m[8, k0] + m[3 + i, k1] * m[k, k1] / m[8, k1] + nv * nu
    if not full:  # rotation about z only
        m[9, 0], m[9, 1], m[10, 0], m[10, 1], m[11, 2] = np.cos(angle), -np.sin(angle), np.sin(angle), np.cos(angle), 1
    for j in range(len(points)):
        for i in range(3):
            x = 0.0
            for k in range(3):
                x += m[9 + i, k] * (template[j, k] - m[6, k])
            out[j, i] = x + m[7, i]
    return count > 0


@njit(cache=True)
def _score(poses2d: np.ndarray, v: int, p: int, j: int) -> float:
    """The score of joint j of person p in view v of poses2d (V, P, J, 3), 0 where its pixel is not finite."""
    finite = np.isfinite(poses2d[v, p, j, 0]) and np.isfinite(poses2d[v, p, j, 1])
    return poses2d[v, p, j, 2] if finite else 0.0


class StartInputs(NamedTuple):
    """_start_kernel's inputs."""

    points: np.ndarray  # (P, J, 3)
    known: np.ndarray  # (P, J)
    poses2d: np.ndarray  # (V, P, J, 3) undistorted px + score
    proj: np.ndarray  # (V, 3, 4)
    Minv: np.ndarray  # (V, 3, 3) = M^-1
    centre: np.ndarray  # (V, 3) camera centres
    template: np.ndarray  # (J, 3)


class StartScratch(NamedTuple):
    """_start_kernel's work arrays (no allocations in the kernel): ok (P, J), body (J + 1, 3), m (12, 3), buf (J,)."""

    ok: np.ndarray
    body: np.ndarray
    m: np.ndarray
    buf: np.ndarray


@njit(cache=True)
def _inliers(inp: StartInputs, p: int, work: StartScratch) -> bool:
    """Person p's plausible known joints into work.ok, the body fitted to them into work.body -> placed."""
    points, template, proj, ok, body, buf = inp.points, inp.template, inp.proj, work.ok, work.body, work.buf
    poses2d, m = inp.poses2d, work.m  # every field read once, outside the loops (docs/design.md)
    J = len(template)
    shift = body[J]
    for j in range(J):  # behind a camera that sees it
        for v in range(len(proj)):
            depth = 0.0
            for i in range(3):
                depth += proj[v, 2, i] * points[p, j, i]
            ok[p, j] &= not (_score(poses2d, v, p, j) > 0 and not depth + proj[v, 2, 3] > 0)
    for i in range(3):  # the template shifted by the median of points - template: insertion sorts
        n = 0
        for j in range(J):
            body[j, i] = template[j, i]
            if ok[p, j]:
                x = points[p, j, i] - template[j, i]
                k = n
                while k > 0 and buf[k - 1] > x:
                    buf[k], k = buf[k - 1], k - 1
                buf[k], n = x, n + 1
        shift[i] = (buf[(n - 1) // 2] + buf[n // 2]) / 2 if n else 0.0
    placed = False
    for limit in (GROSS_OUTLIER_M, OUTLIER_M):  # far from the body shifted, then from the body fitted
        for j in range(J):
            d = 0.0
            for i in range(3):
                d += (points[p, j, i] - body[j, i] - shift[i]) ** 2
            ok[p, j] &= not np.sqrt(d) > limit
        placed = _fit_one(points[p], ok[p], template, body, m)
        shift[0], shift[1], shift[2] = 0.0, 0.0, 0.0
    return placed


@njit(cache=True)
def _start_kernel(inp: StartInputs, out: np.ndarray, placed: np.ndarray, work: StartScratch) -> None:
    """_start per person: out (P, J, 3) (enters as points), placed (P,); work.ok enters as known."""
    poses2d, Minv, centre, body, buf, ok = inp.poses2d, inp.Minv, inp.centre, work.body, work.buf, work.ok
    for p in range(len(out)):
        placed[p] = _inliers(inp, p, work)
        for j in range(out.shape[1]):  # the rest: the body, moved onto the best-scored view's ray
            if ok[p, j]:
                continue
            best = 0  # np.argmax of the scores: the first maximum, or the first NaN
            for v in range(len(poses2d)):
                top = _score(poses2d, best, p, j)
                if not _score(poses2d, v, p, j) <= top and not np.isnan(top):
                    best = v
            if not _score(poses2d, best, p, j) > 0:
                for i in range(3):
                    out[p, j, i] = body[j, i]
                continue
            num, den = 0.0, 0.0
            for i in range(3):
                buf[i] = Minv[best, i, 0] * poses2d[best, p, j, 0] + Minv[best, i, 1] * poses2d[best, p, j, 1]
                buf[i] += Minv[best, i, 2]
                num, den = num + (body[j, i] - centre[best, i]) * buf[i], den + buf[i] * buf[i]
            t = max(num / den, _MIN_RAY_DEPTH_M)  # in front of the camera
            for i in range(3):
                out[p, j, i] = centre[best, i] + t * buf[i]


def _writable(a: np.ndarray, dtype: type) -> np.ndarray:
    """a as a writable C-contiguous array of dtype (a copy if needed): one compiled specialisation per kernel."""
    a = np.ascontiguousarray(a, dtype=dtype)
    return a if a.flags.writeable else a.copy()


def fit_mean_body(points: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean body aligned to each person's known joints: (P, J, 3), (P, J) bool -> (P, J, 3), placed (P,)."""
    points, known = _writable(points, np.float64), _writable(known, np.bool_)
    out, placed, m = np.empty(points.shape), np.zeros(len(points), dtype=bool), np.empty((12, 3))
    for p in range(len(points)):
        placed[p] = _fit_one(points[p], known[p], MEAN_POSE[: points.shape[1]], out[p], m)
    return out, placed


def _start(
    points: np.ndarray, known: np.ndarray, poses2d: np.ndarray, proj: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Inliers of points kept, every other joint from the fitted body moved onto its ray -> (P, J, 3), placed (P,)."""
    points, known, proj = _writable(points, np.float64), _writable(known, np.bool_), _writable(proj, np.float64)
    P, J = known.shape
    Minv = np.linalg.inv(proj[:, :, :3])
    inputs = StartInputs(
        points=points,
        known=known,
        poses2d=_writable(poses2d, np.float64),
        proj=proj,
        Minv=Minv,
        centre=-np.matmul(Minv, proj[:, :, 3:])[..., 0],
        template=MEAN_POSE[:J],
    )
    work = StartScratch(ok=known.copy(), body=np.empty((J + 1, 3)), m=np.empty((12, 3)), buf=np.empty(max(J, 3)))
    out, placed = points.copy(), np.zeros(P, dtype=bool)
    _start_kernel(inputs, out, placed, work)
    return out, placed


def initial_poses(dlt: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start poses: DLT (P, J, 4), (V, P, J, 3) undistorted px + score, (V, 3, 4) -> (P, J, 3), placed (P,) bool."""
    dlt = np.asarray(dlt, dtype=np.float64)
    return _start(dlt[..., :3], dlt[..., 3] > 0, poses2d, proj)


def reinitialise_outliers(X: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Gross outliers of solved poses reset as initial_poses does: (P, J, 3), (V, P, J, 3), (V, 3, 4) -> (P, J, 3)."""
    return _start(X, np.any(np.asarray(poses2d)[..., 2] > 0, axis=0), poses2d, proj)[0]
