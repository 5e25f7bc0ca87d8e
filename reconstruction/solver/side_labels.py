"""Left / right labels of a person's joint pairs made consistent across views, then with the body, before the DLT.

A 2D network that cannot tell a person's left arm from the right (a symmetric body seen from behind; the
synthetic capsule bodies for all arms) labels each view's pair at random. :func:`consistent_sides` finds,
per person and joint pair, the labelling of the views that the epipolar geometry agrees with best (every
labelling of the views that see both joints is tried; the two labellings that differ by exchanging every
view fit equally, the one that changes fewer views is kept), and relabels when it fits clearly better
than the labels as given. The pair is then consistent, but the whole pair may still be the wrong way round:
:func:`chain_sides` exchanges a limb pair (elbows, wrists, knees, ankles, feet) whose triangulated joints sit
farther from their parent pair (shoulders, elbows, hips, knees, ankles) as labelled than exchanged. Labels
that agree across views and with the body, what an accurate detector gives, are never changed.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from data.keypoints import FLIP_PAIRS

# (child pair, parent pair) along the limbs, parents first: a child is judged after its parent is settled
CHAINS = (((7, 8), (5, 6)), ((9, 10), (7, 8)), ((13, 14), (11, 12)), ((15, 16), (13, 14)))
CHAINS += tuple((child, (15, 16)) for child in ((17, 20), (18, 21), (19, 22)))


def fundamental_from_projections(pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """F with x_b^T F x_a = 0 for two cameras' projection matrices (3, 4) x2 -> (3, 3), unit norm."""
    centre = np.linalg.svd(pa)[2][-1]  # null vector of pa: camera a's centre
    e = pb @ centre
    ex = np.array([[0.0, -e[2], e[1]], [e[2], 0.0, -e[0]], [-e[1], e[0], 0.0]])
    F = ex @ pb @ np.linalg.pinv(pa)
    return F / np.linalg.norm(F)


def epipolar_distance(xa: np.ndarray, xb: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Symmetric point-to-epipolar-line distance (px): points (..., 2) in view a and b, F (3, 3) -> (...)."""
    ha = np.concatenate([xa, np.ones(xa.shape[:-1] + (1,))], axis=-1)
    hb = np.concatenate([xb, np.ones(xb.shape[:-1] + (1,))], axis=-1)
    la, lb = hb @ F, ha @ F.T  # b's line in a, a's line in b
    num = np.abs(np.sum(hb * lb, axis=-1))
    norm = lambda line: np.maximum(np.linalg.norm(line[..., :2], axis=-1), 1e-12)  # noqa: E731
    return 0.5 * num * (1 / norm(lb) + 1 / norm(la))


def _labelling_energies(same: np.ndarray, swap: np.ndarray) -> np.ndarray:
    """Pairwise costs (n, n) as labelled alike / exchanged -> energy of every labelling (2^n,) (bit v = view v
    exchanged)."""
    n = len(same)
    bits = (np.arange(2**n)[:, None] >> np.arange(n)) & 1  # (2^n, n)
    differ = bits[:, :, None] != bits[:, None, :]  # (2^n, n, n)
    upper = np.triu(np.ones((n, n), bool), 1)
    return np.where(differ, swap, same)[:, upper].sum(axis=1)


def consistent_sides(
    poses2d: np.ndarray, proj: np.ndarray, cap_px: float = 50.0, ratio: float = 0.9, min_gain_px: float = 20.0
) -> np.ndarray:
    """poses2d (V, P, J, 3) undistorted px + score, proj (V, 3, 4) -> a copy with each person's joint pairs
    labelled consistently across the views that see both joints (distances capped at cap_px; relabelled when
    the best labelling's cost is below ratio of the given one and lower by min_gain_px)."""
    V, P = poses2d.shape[:2]
    out = poses2d.copy()
    if V < 2 or P == 0:
        return out
    view_pairs = list(combinations(range(V), 2))
    Fs = {(a, b): fundamental_from_projections(proj[a], proj[b]) for a, b in view_pairs}
    left, right = np.array([p[0] for p in FLIP_PAIRS]), np.array([p[1] for p in FLIP_PAIRS])
    both = (poses2d[..., left, 2] > 0) & (poses2d[..., right, 2] > 0)  # (V, P, K)
    xy = poses2d[..., :2]
    same = np.zeros((V, V, P, len(left)))
    swap = np.zeros_like(same)
    for a, b in view_pairs:
        d = lambda i, j: np.minimum(epipolar_distance(xy[a][:, i], xy[b][:, j], Fs[a, b]), cap_px)  # noqa: E731
        same[a, b] = d(left, left) + d(right, right)
        swap[a, b] = d(left, right) + d(right, left)
    suspect = ((swap < same - min_gain_px) & both[:, None] & both[None, :]).any(axis=(0, 1))  # (P, K)
    for p, k in zip(*np.nonzero(suspect)):
        views = np.flatnonzero(both[:, p, k])
        energies = _labelling_energies(same[views][:, views, p, k], swap[views][:, views, p, k])
        flips = (np.arange(len(energies))[:, None] >> np.arange(len(views))) & 1
        order = np.lexsort((flips.sum(1), energies))  # lowest energy, then fewest views changed
        best = order[0]
        if energies[best] < ratio * energies[0] and energies[0] - energies[best] > min_gain_px:
            for v in views[flips[best] == 1]:
                out[v, p, [left[k], right[k]]] = out[v, p, [right[k], left[k]]]
    return out


def chain_sides(poses2d: np.ndarray, X: np.ndarray, ratio: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """poses2d (V, P, J, 3), the DLT X (P, J, 4) -> copies with a limb pair exchanged (in every view and in X)
    where its joints' distances to the parent pair, as labelled, sum to more than 1 / ratio times exchanged."""
    poses2d, X = poses2d.copy(), X.copy()
    for (cl, cr), (pl, pr) in CHAINS:
        ok = (X[:, [cl, cr, pl, pr], 3] > 0).all(axis=1)
        dist = lambda a, b: np.linalg.norm(X[:, a, :3] - X[:, b, :3], axis=-1)  # noqa: E731
        given, exchanged = dist(pl, cl) + dist(pr, cr), dist(pl, cr) + dist(pr, cl)
        flip = np.flatnonzero(ok & (exchanged < ratio * given))
        if len(flip):
            X[flip[:, None], [cl, cr]] = X[flip[:, None], [cr, cl]]
            poses2d[:, flip[:, None], [cl, cr]] = poses2d[:, flip[:, None], [cr, cl]]
    return poses2d, X
