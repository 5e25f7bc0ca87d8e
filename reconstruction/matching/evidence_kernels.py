"""Compiled loop of the evidence matcher: the chi-square of every detection pair of a view pair.

Each pair's body evidence is a sum over the joints both detections see of the Sampson distance to the
epipolar geometry, added to the feet term; the loop stops as soon as a pair cannot pass its gate any
more, so unrelated pairs (most of a crowd's) cost one or two joints each.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _popcount(x: np.int64) -> int:
    """Number of set bits of a non-negative 64-bit integer."""
    x = x - ((x >> 1) & 0x5555555555555555)
    x = (x & 0x3333333333333333) + ((x >> 2) & 0x3333333333333333)
    x = (x + (x >> 4)) & 0x0F0F0F0F0F0F0F0F
    return int((x * 0x0101010101010101) >> 56) & 0xFF


@njit(cache=True)
def _masks(var: np.ndarray) -> np.ndarray:
    """Bit masks of the usable joints (var > 0) of every detection, 62 joints per word: (N, J) -> (N, W) int64."""
    N, J = var.shape
    out = np.zeros((N, (J + 61) // 62), dtype=np.int64)
    for i in range(N):
        for k in range(J):
            if var[i, k] > 0.0:
                out[i, k // 62] |= np.int64(1) << (k % 62)
    return out


@njit(cache=True)
def pair_chi2(
    uv_a: np.ndarray,
    var_a: np.ndarray,
    uv_b: np.ndarray,
    var_b: np.ndarray,
    F: np.ndarray,
    feet_d2: np.ndarray,
    limits: np.ndarray,
    min_dof: int,
    cap: float,
    body_scale2: float,
    chi2_out: np.ndarray,
    dof_out: np.ndarray,
) -> None:
    """Chi-square feet + body / body_scale2 and degrees of freedom of every pair (i, j); inf where rejected.

    uv_a (Na, J, 2) undistorted pixels, var_a (Na, J) pixel variances (0 = joint not usable), the same for
    b; F (3, 3) with x_b^T F x_a = 0; feet_d2 (Na, Nb) squared Mahalanobis feet distance (2 dof), NaN where
    either detection has no feet; limits (D + 1,) the gate chi^2 quantile per dof; cap: the most one joint
    adds (an outlying joint, e.g. a left / right swap, counts as a bad joint, not as a wrong person);
    body_scale2: the squared noise scale the body terms are divided by (the feet term keeps its own model).
    """
    Na, J = var_a.shape
    Nb = var_b.shape[0]
    la = np.empty((Na, J, 3))  # epipolar lines of a's joints in view b
    for i in range(Na):
        for k in range(J):
            x, y = uv_a[i, k, 0], uv_a[i, k, 1]
            for r in range(3):
                la[i, k, r] = F[r, 0] * x + F[r, 1] * y + F[r, 2]
    lb = np.empty((Nb, J, 3))  # lines of b's joints in view a: F^T x_b
    for j in range(Nb):
        for k in range(J):
            x, y = uv_b[j, k, 0], uv_b[j, k, 1]
            for r in range(3):
                lb[j, k, r] = F[0, r] * x + F[1, r] * y + F[2, r]
    mask_a, mask_b = _masks(var_a), _masks(var_b)
    for i in range(Na):
        for j in range(Nb):
            feet = feet_d2[i, j]
            dof = 0
            d2 = 0.0
            if not np.isnan(feet):
                dof = 2
                d2 = feet
                if d2 > limits[2 + J]:  # the cheap test: no body evidence can save these feet
                    chi2_out[i, j] = np.inf
                    dof_out[i, j] = 2
                    continue
            common = 0
            for w in range(mask_a.shape[1]):
                common += _popcount(mask_a[i, w] & mask_b[j, w])
            possible = dof + common
            if possible < min_dof or d2 > limits[possible]:
                chi2_out[i, j] = np.inf
                dof_out[i, j] = possible
                continue
            for k in range(J):
                if var_a[i, k] > 0.0 and var_b[j, k] > 0.0:
                    l0, l1, l2 = la[i, k, 0], la[i, k, 1], la[i, k, 2]
                    e = uv_b[j, k, 0] * l0 + uv_b[j, k, 1] * l1 + l2
                    m0, m1 = lb[j, k, 0], lb[j, k, 1]
                    denom = var_b[j, k] * (l0 * l0 + l1 * l1) + var_a[i, k] * (m0 * m0 + m1 * m1)
                    if denom > 0.0:
                        d2 += min(e * e / denom, cap) / body_scale2
                        dof += 1
                        if d2 > limits[possible]:
                            break
            if dof < min_dof or d2 > limits[dof]:
                chi2_out[i, j] = np.inf
            else:
                chi2_out[i, j] = d2
            dof_out[i, j] = dof


@njit(cache=True)
def _find(parent: np.ndarray, i: int) -> int:
    """Root of i, with path halving."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def merge_linked(ga: np.ndarray, gb: np.ndarray, view_of: np.ndarray, linked: np.ndarray) -> np.ndarray:
    """Complete-linkage merging of edges (ga[k], gb[k]) in the given order -> root of every detection (N,).

    Two components join when no view is in both and linked[x, y] holds for every x of one and y of the
    other (linked: (N, N) bool, symmetric). Members are kept as linked lists (head, next, tail per root).
    """
    n = len(view_of)
    parent = np.arange(n)
    views = np.zeros(n, dtype=np.int64)
    nxt = np.full(n, -1)
    tail = np.arange(n)
    size = np.ones(n, dtype=np.int64)
    for i in range(n):
        views[i] = np.int64(1) << view_of[i]
    for k in range(len(ga)):
        a, b = _find(parent, ga[k]), _find(parent, gb[k])
        if a == b or (views[a] & views[b]) != 0:
            continue
        ok = True
        x = a
        while x >= 0 and ok:
            y = b
            while y >= 0:
                if not linked[x, y]:
                    ok = False
                    break
                y = nxt[y]
            x = nxt[x]
        if not ok:
            continue
        if size[a] < size[b]:
            a, b = b, a
        parent[b] = a
        views[a] |= views[b]
        nxt[tail[a]] = b
        tail[a] = tail[b]
        size[a] += size[b]
    for i in range(n):
        parent[i] = _find(parent, i)
    return parent
