"""Left / right swaps of 2D detectors (a wrist labelled as the other in one view), found and undone before the MAP."""

from __future__ import annotations

import numpy as np
from numba import njit

from data.geometry.triangulation import triangulate_dlt
from data.keypoints import FLIP_PAIRS
from reconstruction.solver.pose_kernels import EPS_DEPTH


def _squared(d: np.ndarray) -> np.ndarray:
    """Squared length of 2-vectors (..., 2) -> (...) (not np.sum over the axis of 2: slow on small arrays)."""
    return d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]


def _given(uv: np.ndarray, xy: np.ndarray, w2: np.ndarray, left, right) -> np.ndarray:
    """Chi-square of joint pairs as given: (V, P, J, 2) x2, (V, P, J), left, right (int or (K,)) -> (V, P[, K])."""
    r2 = w2 * _squared(uv - xy)
    return r2[..., left] + r2[..., right]


def _exchanged(uv: np.ndarray, xy: np.ndarray, w2: np.ndarray, left, right) -> np.ndarray:
    """Chi-square of joint pairs with the two detections exchanged: as :func:`_given`."""
    to_left, to_right = _squared(uv[..., right, :] - xy[..., left, :]), _squared(uv[..., left, :] - xy[..., right, :])
    return w2[..., right] * to_left + w2[..., left] * to_right


@njit(cache=True, error_model="numpy")
def _pair_chi2s(full, proj, poses2d, w2, left, right, given, exchanged) -> None:
    """Chi^2 of pairs (K,) against full (P, J, 4) as detected and exchanged: (V, P, J, 3), (V, P, J) -> (V, P, K) x2."""
    for v in range(poses2d.shape[0]):
        for p in range(poses2d.shape[1]):
            for k in range(len(left)):
                a, b = left[k], right[k]
                xa, ya = _projected(proj, v, full, p, a)
                xb, yb = _projected(proj, v, full, p, b)
                ua, va, ub, vb = poses2d[v, p, a, 0], poses2d[v, p, a, 1], poses2d[v, p, b, 0], poses2d[v, p, b, 1]
                wa, wb = w2[v, p, a], w2[v, p, b]
                given[v, p, k] = wa * ((ua - xa) ** 2 + (va - ya) ** 2) + wb * ((ub - xb) ** 2 + (vb - yb) ** 2)
                exchanged[v, p, k] = wb * ((ub - xa) ** 2 + (vb - ya) ** 2) + wa * ((ua - xb) ** 2 + (va - yb) ** 2)


@njit(cache=True, error_model="numpy")
def _projected(proj: np.ndarray, v: int, full: np.ndarray, p: int, j: int) -> tuple[float, float]:
    """Pixel of joint j of person p of full (P, J, 4) in view v, the depth clamped as person_prior.project does."""
    x, y, z = full[p, j, 0], full[p, j, 1], full[p, j, 2]
    h0 = proj[v, 0, 0] * x + proj[v, 0, 1] * y + proj[v, 0, 2] * z + proj[v, 0, 3]
    h1 = proj[v, 1, 0] * x + proj[v, 1, 1] * y + proj[v, 1, 2] * z + proj[v, 1, 3]
    depth = max(proj[v, 2, 0] * x + proj[v, 2, 1] * y + proj[v, 2, 2] * z + proj[v, 2, 3], EPS_DEPTH)
    return h0 / depth, h1 / depth


def find_swaps(
    poses2d: np.ndarray,
    inv_sigma: np.ndarray,  # 0 unseen
    proj: np.ndarray,  # (V, 3, 4)
    full: np.ndarray | None = None,  # (P, J, 4) the DLT from all views, if at hand
    pairs: tuple[tuple[int, int], ...] = FLIP_PAIRS,
    ratio: float = 0.25,
    min_chi2: float = 18.0,
) -> list[tuple[int, int, int, int]]:
    """(view, person, left, right) to exchange: poses2d (V, P, J, 3) undistorted px + score, 1/sigma (V, P, J)."""
    V = len(proj)
    if V < 3 or poses2d.shape[1] == 0:
        return []
    w2 = inv_sigma**2
    full = triangulate_dlt(poses2d, proj, 2) if full is None else full
    left, right = np.array([p[0] for p in pairs], dtype=np.int64), np.array([p[1] for p in pairs], dtype=np.int64)
    given, exchanged = np.empty((V, poses2d.shape[1], len(pairs))), np.empty((V, poses2d.shape[1], len(pairs)))
    as_float = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    _pair_chi2s(as_float(full), as_float(proj), as_float(poses2d), w2, left, right, given, exchanged)
    seen = inv_sigma > 0
    # a swap reprojects worse than its exchange even from the DLT it pulls (only the exchange test below
    # needs the other views alone)
    high = (given > min_chi2) & seen[..., left] & seen[..., right]
    if not high.any():
        return []
    bad = (high & (exchanged < given)).any(axis=0)  # (P, pairs)
    bad &= (full[:, left, 3] > 0) & (full[:, right, 3] > 0)
    persons, which = np.nonzero(bad)
    cand = [(int(p), int(left[k]), int(right[k])) for p, k in zip(persons, which)]
    if not cand:
        return []
    person, joints = np.array([c[0] for c in cand]), np.array([c[1:] for c in cand])  # (K,), (K, 2)
    sub = poses2d[:, person[:, None], joints]  # (V, K, 2, 3)
    sub_w2 = w2[:, person[:, None], joints]  # (V, K, 2)
    K = len(cand)
    others = np.repeat(sub[:, None], V, axis=1)  # (V, V, K, 2, 3): without view u
    others[np.arange(V), np.arange(V), ..., 2] = 0.0
    X = triangulate_dlt(others.reshape(V, V * K, 2, 3), proj, 2).reshape(V, K, 2, 4)  # one DLT for all V variants
    hom = np.matmul(X[..., :3].reshape(V, 2 * K, 3), proj[:, :, :3].transpose(0, 2, 1)) + proj[:, None, :, 3]
    pxy = (hom[..., :2] / np.maximum(hom[..., 2:], EPS_DEPTH)).reshape(V, K, 2, 2)  # each X[v] in its view v
    g, e = _given(sub[..., :2], pxy, sub_w2, 0, 1), _exchanged(sub[..., :2], pxy, sub_w2, 0, 1)  # (V, K)
    ok = (sub_w2 > 0).all(axis=-1) & (X[..., 3] > 0).all(axis=-1) & (g > min_chi2) & (e < ratio * g)
    gains = np.where(ok, g - e, -np.inf)
    best = np.argmax(gains, axis=0)
    keep = np.flatnonzero(np.isfinite(gains[best, np.arange(len(cand))]))
    return sorted((int(best[k]), *cand[k]) for k in keep)


def apply_swaps(poses2d: np.ndarray, swaps: list[tuple[int, int, int, int]]) -> np.ndarray:
    """A copy of the 2D poses (V, P, J, K) with each (view, person, left, right) exchanged."""
    out = np.array(poses2d, copy=True)
    for v, p, left, right in swaps:
        out[v, p, [left, right]] = out[v, p, [right, left]]
    return out
