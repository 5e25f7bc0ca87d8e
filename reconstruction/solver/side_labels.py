"""Left / right labels of a person's joint pairs made consistent across views, then with the body, before the DLT."""

from __future__ import annotations

import numpy as np

from data.geometry.triangulation import smallest_eigenvectors
from data.keypoints import FLIP_PAIRS
from reconstruction.solver.person_prior import project
from reconstruction.solver.pose_kernels import EPS_DEPTH

# (child pair, parent pair) along the limbs, parents first: a child is judged after its parent is settled
CHAINS = (((7, 8), (5, 6)), ((9, 10), (7, 8)), ((13, 14), (11, 12)), ((15, 16), (13, 14)))
CHAINS += tuple((child, (15, 16)) for child in ((17, 20), (18, 21), (19, 22)))


def _normals(points: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """The DLT's normal matrix of each observation: points (..., V, 2) in cameras proj (V, 3, 4) -> (..., V, 4, 4)."""
    rows = np.stack(
        [points[..., :1] * proj[:, 2] - proj[:, 0], points[..., 1:2] * proj[:, 2] - proj[:, 1]], axis=-2
    )  # (..., V, 2, 4), unit rows as triangulate_dlt
    rows /= np.maximum(np.linalg.norm(rows, axis=-1, keepdims=True), 1e-12)
    return rows.transpose(*range(rows.ndim - 2), -1, -2) @ rows


def _solve(N: np.ndarray) -> np.ndarray:
    """Summed normal matrices (..., 4, 4) -> the points (..., 3) they triangulate."""
    X = smallest_eigenvectors(N.reshape(-1, 4, 4)).reshape(N.shape[:-1])
    w = X[..., 3:]
    return X[..., :3] / np.where(np.abs(w) > 1e-12, w, 1e-12)


def _project(X: np.ndarray, proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points X (..., 3) in the cameras (V, 3, 4) -> pixels (..., V, 2), in front of the camera (..., V)."""
    uv, z = project(X.reshape(-1, 1, 3), proj)  # (V, n, 1, 2), depths clamped to EPS_DEPTH
    shape = (*X.shape[:-1], len(proj))
    return np.moveaxis(uv[:, :, 0], 0, 1).reshape(*shape, 2), (z[:, :, 0] > EPS_DEPTH).T.reshape(shape)


def _errors(uv: np.ndarray, front: np.ndarray, points: np.ndarray, cap_px: float) -> np.ndarray:
    """Distances (..., V) px of projections uv (..., V, 2) to points (..., V, 2), capped (also behind a camera)."""
    d = np.hypot(uv[..., 0] - points[..., 0], uv[..., 1] - points[..., 1])
    return np.where(front, np.minimum(d, cap_px), cap_px)


def _view_costs(A, B, proj, xl, xr, seen, cap_px):
    """Costs (..., V) of each view as given and exchanged for the pair's points A, B (..., 3); 0 where not seen."""
    (ua, fa), (ub, fb) = _project(A, proj), _project(B, proj)
    keep = _errors(ua, fa, xl, cap_px) + _errors(ub, fb, xr, cap_px)
    swap = _errors(ua, fa, xr, cap_px) + _errors(ub, fb, xl, cap_px)
    return keep * seen, swap * seen


def best_labellings(
    xl: np.ndarray, xr: np.ndarray, seen: np.ndarray, proj: np.ndarray, cap_px: float = 50.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs xl, xr (Q, V, 2), seen (Q, V), proj (V, 3, 4) -> views to swap (Q, V), its cost, cost as given (Q,) px."""
    Q, V = seen.shape
    Ml, Mr = _normals(xl, proj), _normals(xr, proj)  # (Q, V, 4, 4)
    i, j = np.triu_indices(V, 1)
    pair_seen = seen[:, i] & seen[:, j]  # (Q, S)
    costs, seeds = [], []
    for exchanged in (False, True):  # view j as labelled, then exchanged
        NA = Ml[:, i] + (Mr if exchanged else Ml)[:, j]
        NB = Mr[:, i] + (Ml if exchanged else Mr)[:, j]
        keep, swap = _view_costs(_solve(NA), _solve(NB), proj, xl[:, None], xr[:, None], seen[:, None], cap_px)
        costs.append(np.where(pair_seen, np.minimum(keep, swap).sum(-1), np.inf))
        seeds.append(swap < keep)
    costs, seeds = np.concatenate(costs, 1), np.concatenate(seeds, 1)  # (Q, 2S), (Q, 2S, V)
    labels = seeds[np.arange(Q), np.argmin(costs, axis=1)]
    for _ in range(2):  # refine: triangulate from every view as labelled, relabel
        flip = (labels & seen)[..., None, None]
        A = _solve((np.where(flip, Mr, Ml) * seen[..., None, None]).sum(1))
        B = _solve((np.where(flip, Ml, Mr) * seen[..., None, None]).sum(1))
        keep, swap = _view_costs(A, B, proj, xl, xr, seen, cap_px)
        labels = (swap < keep) & seen
    cost = np.where(labels, swap, keep).sum(-1)
    labels ^= (2 * labels.sum(-1) > seen.sum(-1))[:, None]  # the fewer views changed
    A, B = _solve((Ml * seen[..., None, None]).sum(1)), _solve((Mr * seen[..., None, None]).sum(1))
    return labels & seen, cost, _view_costs(A, B, proj, xl, xr, seen, cap_px)[0].sum(-1)


def consistent_sides(
    poses2d: np.ndarray, proj: np.ndarray, cap_px: float = 50.0, ratio: float = 0.9, min_gain_px: float = 20.0
) -> np.ndarray:
    """poses2d (V, P, J, 3) undistorted px + score, proj (V, 3, 4) -> a copy with joint pairs labelled consistently."""
    V, P = poses2d.shape[:2]
    out = poses2d.copy()
    if V < 2 or P == 0:
        return out
    left, right = np.array([p[0] for p in FLIP_PAIRS]), np.array([p[1] for p in FLIP_PAIRS])
    both = (poses2d[..., left, 2] > 0) & (poses2d[..., right, 2] > 0)  # (V, P, K)
    p, k = np.nonzero(both.sum(axis=0) >= 2)
    if len(p) == 0:
        return out
    xl = poses2d[:, p, left[k], :2].transpose(1, 0, 2)  # (Q, V, 2)
    xr = poses2d[:, p, right[k], :2].transpose(1, 0, 2)
    labels, cost, given = best_labellings(xl, xr, both[:, p, k].T, proj, cap_px)
    apply = labels & ((cost < ratio * given) & (given - cost > min_gain_px))[:, None]
    q, v = np.nonzero(apply)
    out[v, p[q], left[k[q]]], out[v, p[q], right[k[q]]] = poses2d[v, p[q], right[k[q]]], poses2d[v, p[q], left[k[q]]]
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) scaled to unit length (zero vectors stay zero)."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(norm > 1e-9, v / np.maximum(norm, 1e-9), 0.0)


def _across(v: np.ndarray, up: np.ndarray, min_share: float) -> np.ndarray:
    """Unit directions v (P, 3) across unit up (P, 3); zero where less than min_share of v's length is left."""
    flat = v - (v * up).sum(-1, keepdims=True) * up
    share = np.linalg.norm(flat, axis=-1) / np.maximum(np.linalg.norm(v, axis=-1), 1e-9)
    return _unit(flat) * (share >= min_share)[:, None]


def facing_directions(X: np.ndarray, min_share: float = 0.5) -> np.ndarray:
    """The DLT X (P, J, 4) -> each person's left direction (P, 3) from joints whose labels do not matter, or 0."""
    ok = X[..., 3] > 0

    def mid(joints: list[int], all_seen: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Midpoint (P, 3) of the seen joints; known (P,) when all (or, all_seen False, any) are seen."""
        seen = ok[:, joints]
        centre = (X[:, joints, :3] * seen[..., None]).sum(1) / np.maximum(seen.sum(1), 1)[:, None]
        return centre, seen.all(1) if all_seen else seen.any(1)

    (shoulders, s_ok), (hips, h_ok), (ears, e_ok) = mid([5, 6]), mid([11, 12]), mid([3, 4])
    (toes, t_ok), (heels, f_ok) = mid([17, 18, 20, 21], all_seen=False), mid([19, 22])
    up = _unit(shoulders - hips) * (s_ok & h_ok)[:, None]
    head = _across(X[:, 0, :3] - ears, up, min_share) * (e_ok & ok[:, 0])[:, None]
    feet = _across(toes - heels, up, min_share) * (t_ok & f_ok)[:, None]
    agree = (head * feet).sum(-1) >= 0
    return np.cross(up, _unit(head + feet)) * agree[:, None]


def facing_sides(poses2d: np.ndarray, X: np.ndarray, min_cos: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """poses2d (V, P, J, 3), the DLT X (P, J, 4) -> copies with the central pairs turned to the way the body faces."""
    poses2d, X = poses2d.copy(), X.copy()
    left = facing_directions(X)
    for a, b in ((1, 2), (3, 4), (5, 6), (11, 12)):
        ok = (X[:, a, 3] > 0) & (X[:, b, 3] > 0)
        cos = (_unit(X[:, a, :3] - X[:, b, :3]) * left).sum(-1)
        flip = np.flatnonzero(ok & (cos < -min_cos))
        if len(flip):
            X[flip[:, None], [a, b]] = X[flip[:, None], [b, a]]
            poses2d[:, flip[:, None], [a, b]] = poses2d[:, flip[:, None], [b, a]]
    return poses2d, X


def chain_sides(poses2d: np.ndarray, X: np.ndarray, ratio: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """poses2d (V, P, J, 3), the DLT X (P, J, 4) -> copies with limb pairs exchanged where closer to the parent so."""
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
