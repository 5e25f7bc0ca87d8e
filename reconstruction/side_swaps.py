"""Left / right swaps of 2D detectors, found and undone before the MAP.

Bottom-up detectors such as OpenPose often give a person's left wrist as their right one in one view
(the arm behind the body, a person seen from behind). For every view v, the person's joints are
triangulated from the other views alone (a swap in v cannot pull them); for every symmetric joint
pair (left, right) seen in v and in at least two other views, the reprojection chi-square in v of the
two detections as given is compared with that of the two exchanged. The view whose exchange lowers
it most is swapped when the exchange leaves at most ``ratio`` of the chi-square and the chi-square as
given exceeds ``min_chi2`` (in units of the 2D noise).
"""
from __future__ import annotations

import numpy as np

from data.keypoints import FLIP_PAIRS
from reconstruction.triangulation import triangulate_dlt

_EPS_DEPTH = 1e-6


def leave_one_out(poses2d: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """Joints triangulated without each view: (V, P, J, 3) undistorted px + score -> (V, P, J, 4) (x, y, z, conf)."""
    out = []
    for v in range(len(proj)):
        others = np.array(poses2d, dtype=np.float64, copy=True)
        others[v, ..., 2] = 0.0
        out.append(triangulate_dlt(others, proj, 2))
    return np.stack(out)


def find_swaps(poses2d: np.ndarray, inv_sigma: np.ndarray, proj: np.ndarray,
               pairs: tuple[tuple[int, int], ...] = FLIP_PAIRS, ratio: float = 0.25,
               min_chi2: float = 18.0) -> list[tuple[int, int, int, int]]:
    """(view, person, left, right) to exchange: poses2d (V, P, J, 3) undistorted px + score, inv_sigma (V, P, J)
    1 / sigma (0 unseen), proj (V, 3, 4)."""
    if len(proj) < 3:
        return []
    X = leave_one_out(poses2d, proj)                                                  # (V, P, J, 4)
    hom = np.einsum("vab,vpjb->vpja", proj[:, :, :3], X[..., :3]) + proj[:, None, None, :, 3]
    xy = hom[..., :2] / np.maximum(hom[..., 2:3], _EPS_DEPTH)
    known = (X[..., 3] > 0) & (inv_sigma > 0)                                         # seen here, triangulated elsewhere
    uv = poses2d[..., :2]
    out = []
    for left, right in pairs:
        w_l, w_r = inv_sigma[..., left] ** 2, inv_sigma[..., right] ** 2             # (V, P)
        d = lambda a, b: np.sum((uv[:, :, a] - xy[:, :, b]) ** 2, axis=-1)          # noqa: E731
        given = w_l * d(left, left) + w_r * d(right, right)
        exchanged = w_r * d(right, left) + w_l * d(left, right)
        ok = known[..., left] & known[..., right] & (given > min_chi2) & (exchanged < ratio * given)
        gain = np.where(ok, given - exchanged, -np.inf)
        best = np.argmax(gain, axis=0)                                                # (P,)
        for p in np.flatnonzero(np.isfinite(gain[best, np.arange(gain.shape[1])])):
            out.append((int(best[p]), int(p), left, right))
    return out


def apply_swaps(poses2d: np.ndarray, swaps: list[tuple[int, int, int, int]]) -> np.ndarray:
    """A copy of the 2D poses (V, P, J, K) with each (view, person, left, right) exchanged."""
    out = np.array(poses2d, copy=True)
    for v, p, left, right in swaps:
        out[v, p, [left, right]] = out[v, p, [right, left]]
    return out
