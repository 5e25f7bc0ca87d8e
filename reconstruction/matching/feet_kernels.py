"""Compiled loops of the feet features (feet.py, feet_uncertainty.py), without (N, K, 3, 3) temporaries."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def plane_points(und, H, view, level, heights, axis, offset, var, und_jac, xy, depth, cov) -> None:
    """Undistorted px und (N, K, 2) at heights (K,) -> plane xy (N, K, 2), depth (N, K), cov (N, K, 2, 2) if var."""
    N, K = und.shape[0], und.shape[1]
    for n in range(N):
        v = view[n]
        for k in range(K):
            h = H[v, level[k]]
            u0, u1 = und[n, k, 0], und[n, k, 1]
            w0 = h[0, 0] * u0 + h[0, 1] * u1 + h[0, 2]
            w1 = h[1, 0] * u0 + h[1, 1] * u1 + h[1, 2]
            w2 = h[2, 0] * u0 + h[2, 1] * u1 + h[2, 2]
            x, y = w0 / w2, w1 / w2
            xy[n, k, 0], xy[n, k, 1] = x, y
            depth[n, k] = x * axis[v, 0] + y * axis[v, 1] + heights[k] * axis[v, 2] + offset[v]
            if len(var) == 0:
                continue
            a, b = (h[0, 0] - x * h[2, 0]) / w2, (h[0, 1] - x * h[2, 1]) / w2  # d xy / d und, row x
            c, d = (h[1, 0] - y * h[2, 0]) / w2, (h[1, 1] - y * h[2, 1]) / w2  # ... row y
            if len(und_jac):  # d xy / d distorted px = (d xy / d und) (d und / d distorted px)
                U = und_jac[n, k]
                a, b = a * U[0, 0] + b * U[1, 0], a * U[0, 1] + b * U[1, 1]
                c, d = c * U[0, 0] + d * U[1, 0], c * U[0, 1] + d * U[1, 1]
            s, off = var[n, k], a * c + b * d
            cov[n, k, 0, 0], cov[n, k, 0, 1] = s * (a * a + b * b), s * off
            cov[n, k, 1, 0], cov[n, k, 1, 1] = s * off, s * (c * c + d * d)


@njit(cache=True, error_model="numpy")
def foot_points(ground, cov, depth, y, scored, lowest, ankle_fallback, point, point_cov, ok) -> None:
    """Left and right feet of ground (N, 8, 2) -> point (2, N, 2), point_cov (2, N, 2, 2), ok (2, N) (else zeros)."""
    for n in range(ground.shape[0]):
        for s in range(2):
            count, pick, top = 0, -1, -np.inf
            p0, p1, c00, c01, c10, c11 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            for k in range(3 * s, 3 * s + 3):
                if _usable(ground, depth, scored, n, k):
                    count += 1
                    if pick < 0 or y[n, k] > top:  # np.argmax: the first of the largest
                        pick, top = k, y[n, k]
                    p0, p1 = p0 + ground[n, k, 0], p1 + ground[n, k, 1]
                    c00, c01 = c00 + cov[n, k, 0, 0], c01 + cov[n, k, 0, 1]
                    c10, c11 = c10 + cov[n, k, 1, 0], c11 + cov[n, k, 1, 1]
            if count == 0 and ankle_fallback and _usable(ground, depth, scored, n, 6 + s):
                count, pick, lowest_pick = 1, 6 + s, True
            else:
                lowest_pick = lowest
            ok[s, n] = count > 0
            if count == 0:  # element-wise: array assignments would compile numba's broadcasting
                point[s, n, 0], point[s, n, 1] = 0.0, 0.0
                point_cov[s, n, 0, 0], point_cov[s, n, 0, 1], point_cov[s, n, 1, 0], point_cov[s, n, 1, 1] = 0, 0, 0, 0
            elif lowest_pick:
                point[s, n, 0], point[s, n, 1] = ground[n, pick, 0], ground[n, pick, 1]
                point_cov[s, n, 0, 0], point_cov[s, n, 0, 1] = cov[n, pick, 0, 0], cov[n, pick, 0, 1]
                point_cov[s, n, 1, 0], point_cov[s, n, 1, 1] = cov[n, pick, 1, 0], cov[n, pick, 1, 1]
            else:
                point[s, n, 0], point[s, n, 1] = p0 / count, p1 / count
                point_cov[s, n, 0, 0], point_cov[s, n, 0, 1] = c00 / (count * count), c01 / (count * count)
                point_cov[s, n, 1, 0], point_cov[s, n, 1, 1] = c10 / (count * count), c11 / (count * count)


@njit(cache=True, error_model="numpy")
def _usable(ground, depth, scored, n, k) -> bool:
    """Joint k of detection n: scored, its ground point finite and in front of the camera."""
    return scored[n, k] and np.isfinite(ground[n, k, 0]) and np.isfinite(ground[n, k, 1]) and depth[n, k] > 0


@lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile (or load) both kernels once per process on one detection, with the argument types of a frame."""
    index, row = np.zeros(1, np.int64), np.zeros(1)
    ground, depth, cov = np.empty((1, 1, 2)), np.empty((1, 1)), np.empty((1, 1, 2, 2))
    H, axis, var, no_jacobian = np.zeros((1, 1, 3, 3)), np.zeros((1, 3)), np.ones((1, 1)), np.zeros((0, 0, 2, 2))
    plane_points(ground, H, index, index, row, axis, row, var, no_jacobian, ground, depth, cov)
    joints, per_joint, scored = np.zeros((1, 8, 2)), np.zeros((1, 8)), np.zeros((1, 8), bool)
    point, point_cov, ok = np.empty((2, 1, 2)), np.empty((2, 1, 2, 2)), np.empty((2, 1), bool)
    foot_points(joints, np.zeros((1, 8, 2, 2)), per_joint, per_joint, scored, False, True, point, point_cov, ok)
