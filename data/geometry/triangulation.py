"""Batched, score-weighted linear triangulation (DLT)."""

from __future__ import annotations

import numba
import numpy as np

RQI_ITERATIONS = 3
RQI_TOLERANCE = 1e-10  # accepted eigenvector error bound (sine of the angle); the rest goes to eigh


def triangulate_dlt(poses2d: np.ndarray, proj: np.ndarray, min_views: int = 2) -> np.ndarray:
    """Score-weighted DLT: undistorted (u, v, score) (V, P, J, 3), proj (V, 3, 4) -> (P, J, 4), 0 where unsolvable."""
    poses2d = np.asarray(poses2d, dtype=np.float64)
    proj = np.asarray(proj, dtype=np.float64)
    V, P, J, _ = poses2d.shape
    if proj.shape != (V, 3, 4):
        raise ValueError(f"proj has shape {proj.shape}, expected ({V}, 3, 4) for {V} views")
    # the right singular vector of A's smallest singular value is the smallest eigenvector of A^T A (4x4)
    N, conf, solve = np.empty((P * J, 4, 4)), np.empty(P * J), np.empty(P * J, dtype=np.bool_)
    _normal_matrices(
        np.ascontiguousarray(poses2d.reshape(V, P * J, 3)), np.ascontiguousarray(proj), min_views, N, conf, solve
    )
    usable = solve & np.isfinite(N).all(axis=(1, 2))  # pixels so large that the rows overflow: not solvable
    X = smallest_eigenvectors(N, usable)
    finite = usable & (np.abs(X[:, 3]) > 1e-12)  # not at infinity
    out = np.zeros((P * J, 4))
    out[finite, :3] = X[finite, :3] / X[finite, 3:]
    out[finite, 3] = conf[finite]
    return out.reshape(P, J, 4)


@numba.njit(cache=True, error_model="numpy")
def _normal_matrices(
    poses: np.ndarray, proj: np.ndarray, min_views: int, N: np.ndarray, conf: np.ndarray, solve: np.ndarray
) -> None:
    """A^T A of the DLT rows of poses (V, n, 3), proj (V, 3, 4) -> N (n, 4, 4), mean score conf (n,), solve (n,)."""
    V, n = poses.shape[0], poses.shape[1]
    a = np.empty(4)
    for i in range(n):
        seen, total, top = 0, 0.0, 0.0
        for v in range(V):
            x, y, s = poses[v, i, 0], poses[v, i, 1], poses[v, i, 2]
            if np.isfinite(x) and np.isfinite(y) and np.isfinite(s) and s > 0:
                seen += 1
                total += s
                top = max(top, s)
        conf[i] = total / seen if seen else 0.0
        solve[i] = seen >= min_views
        for k in range(4):
            for m in range(4):
                N[i, k, m] = 0.0
        if not solve[i]:
            continue
        for v in range(V):
            x, y, s = poses[v, i, 0], poses[v, i, 1], poses[v, i, 2]
            if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(s) and s > 0):
                continue
            for r in range(2):
                u = x if r == 0 else y
                norm2 = 0.0
                for k in range(4):
                    a[k] = u * proj[v, 2, k] - proj[v, r, k]
                    norm2 += a[k] * a[k]
                weight = (s / top) ** 2 / (norm2 if norm2 > 0 else 1.0)
                for k in range(4):
                    for m in range(4):
                        N[i, k, m] += weight * a[k] * a[m]


def smallest_eigenvectors(N: np.ndarray, use: np.ndarray | None = None) -> np.ndarray:
    """Unit eigenvectors of the smallest eigenvalues of symmetric PSD (n, 4, 4), use (n,) -> (n, 4), 0 where unused."""
    N = np.ascontiguousarray(N, dtype=np.float64)
    use = np.ones(len(N), dtype=np.bool_) if use is None else np.ascontiguousarray(use, dtype=np.bool_)
    v, ok = np.empty((len(N), 4)), np.empty(len(N), dtype=np.bool_)
    _rayleigh_quotient(N, RQI_ITERATIONS, RQI_TOLERANCE, use, v, ok)
    if not ok.all():
        v[~ok] = np.linalg.eigh(N[~ok])[1][..., 0]
    return v


@numba.njit(cache=True, error_model="numpy")
def _rayleigh_quotient(
    N: np.ndarray, iterations: int, tol: float, use: np.ndarray, out: np.ndarray, ok: np.ndarray
) -> None:
    """Smallest eigenvectors of N (n, 4, 4) where use (n,) -> out (n, 4), certified ok (n,) (0 and ok where unused)."""
    B_inv, C_inv, v, z, cv = np.empty((3, 3)), np.empty((3, 3)), np.empty(4), np.empty(4), np.empty(3)
    for i in range(N.shape[0]):
        if not use[i]:
            out[i, 0], out[i, 1], out[i, 2], out[i, 3], ok[i] = 0.0, 0.0, 0.0, 0.0, True
            continue
        A = N[i]
        det = _inverse_sym3(A, 0.0, B_inv)
        pd = A[0, 0] > 0 and A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0] > 0 and det > 0
        for r in range(3):
            v[r] = -(B_inv[r, 0] * A[0, 3] + B_inv[r, 1] * A[1, 3] + B_inv[r, 2] * A[2, 3])
        v[3] = 1.0
        _normalise(v, False)
        for _ in range(iterations):
            rho = _quadratic(A, v)
            _inverse_sym3(A, rho, C_inv)
            cc_c, cc_v = 0.0, 0.0
            for r in range(3):
                Cc = C_inv[r, 0] * A[0, 3] + C_inv[r, 1] * A[1, 3] + C_inv[r, 2] * A[2, 3]
                cv[r] = C_inv[r, 0] * v[0] + C_inv[r, 1] * v[1] + C_inv[r, 2] * v[2]
                z[r] = Cc  # C^-1 c, until z's own entries below
                cc_c += A[r, 3] * Cc
                cc_v += A[r, 3] * cv[r]
            # z = (N - rho I)^-1 v times the Schur complement s = d - rho - c^T C^-1 c, which vanishes as rho converges:
            # the direction without the division, so a converged rho (s = 0 or its rounding) still gives a step
            num, s = v[3] - cc_v, A[3, 3] - rho - cc_c
            for r in range(3):
                z[r] = s * cv[r] - z[r] * num
            z[3] = num
            _normalise(z, True)
            if np.isfinite(z[0]) and np.isfinite(z[1]) and np.isfinite(z[2]) and np.isfinite(z[3]):
                for r in range(4):  # element-wise: a slice assignment compiles numba's shape-error formatting
                    v[r] = z[r]
        rho = _quadratic(A, v)
        resid = 0.0
        for r in range(4):
            Nv = A[r, 0] * v[0] + A[r, 1] * v[1] + A[r, 2] * v[2] + A[r, 3] * v[3]
            resid += (Nv - rho * v[r]) ** 2
        gap = 1.0 / (B_inv[0, 0] + B_inv[1, 1] + B_inv[2, 2]) - rho
        ok[i] = pd and gap > 0 and np.sqrt(resid) <= tol * gap
        for r in range(4):
            out[i, r] = v[r]


@numba.njit(cache=True, error_model="numpy")
def _inverse_sym3(A: np.ndarray, shift: float, out: np.ndarray) -> float:
    """out = (A[:3, :3] - shift I)^-1 by cofactors (inf / NaN when singular) -> the determinant."""
    a, b, c = A[0, 0] - shift, A[0, 1], A[0, 2]
    d, e, f = A[1, 1] - shift, A[1, 2], A[2, 2] - shift
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * c00 + b * c01 + c * c02
    out[0, 0], out[0, 1], out[0, 2] = c00 / det, c01 / det, c02 / det
    out[1, 0], out[1, 1], out[1, 2] = c01 / det, (a * f - c * c) / det, (b * c - a * e) / det
    out[2, 0], out[2, 1], out[2, 2] = c02 / det, (b * c - a * e) / det, (a * d - b * b) / det
    return det


@numba.njit(cache=True, error_model="numpy")
def _quadratic(A: np.ndarray, v: np.ndarray) -> float:
    """v^T A v of a 4x4 matrix."""
    total = 0.0
    for r in range(4):
        total += v[r] * (A[r, 0] * v[0] + A[r, 1] * v[1] + A[r, 2] * v[2] + A[r, 3] * v[3])
    return total


@numba.njit(cache=True, error_model="numpy")
def _normalise(v: np.ndarray, w_positive: bool) -> None:
    """v / |v| in place, its last entry made >= 0 when w_positive."""
    norm = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3])
    if w_positive and v[3] < 0:
        norm = -norm
    for r in range(4):
        v[r] /= norm


def reprojection_error(points3d: np.ndarray, poses2d: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Pixel distance of projected 3D to 2D joints: (P, J, 4|3), (V, P, J, 3) -> (V, P, J), NaN where a score is 0."""
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
