"""CrowdPose's global maximum joints association (Li et al. CVPR 2019) over the boxes of one image."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from data.keypoints import NUM_JOINTS, OKS_SIGMAS


def associate_joints(
    xy: np.ndarray, scores: np.ndarray, boxes: np.ndarray, dist_thresh: float = 1.0, sigmas: np.ndarray | None = None
) -> np.ndarray:
    """Joint candidates xy (P, J, M, 2), scores (P, J, M), boxes (P, 4) xywh -> keypoints (P, J, 3) x, y, score."""
    xy = np.asarray(xy, dtype=np.float64)
    scores = np.asarray(scores, dtype=np.float64)
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    n_persons, n_joints, _ = scores.shape
    if xy.shape != scores.shape + (2,) or len(boxes) != n_persons:
        raise ValueError(f"shape mismatch: xy {xy.shape}, scores {scores.shape}, boxes {boxes.shape}")
    if sigmas is None:
        if n_joints != NUM_JOINTS:
            raise ValueError(f"give sigmas for {n_joints} joints (defaults exist for {NUM_JOINTS})")
        sigmas = OKS_SIGMAS
    box_scale = np.sqrt(np.clip(boxes[:, 2] * boxes[:, 3], 0.0, None))
    radii = dist_thresh * np.asarray(sigmas, dtype=np.float64)[None, :] * box_scale[:, None]  # (P, J)
    out = own_best(xy, scores)
    if n_persons < 2:
        return out
    nodes = joint_nodes(xy, scores, radii)
    person, node, weight, slot = best_per_node(nodes, scores)
    n_nodes = int(nodes.max()) + 1 if len(node) else 0
    joint_of_node = np.zeros(n_nodes, dtype=int)
    joint_of_node[nodes[nodes >= 0]] = np.nonzero(nodes >= 0)[1]
    first = np.searchsorted(joint_of_node, np.arange(n_joints + 1))  # nodes are numbered joint by joint
    w = np.zeros((n_persons, n_nodes))
    best = np.zeros((n_persons, n_nodes), dtype=int)
    w[person, node], best[person, node] = weight, slot
    shared = np.bincount(node, minlength=n_nodes) >= 2
    matched = [_match(w, first[j], first[j + 1]) for j in np.unique(joint_of_node[shared])]
    return _apply_matches(out, xy, w, best, joint_of_node, matched)


def _match(w: np.ndarray, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
    """Match persons to nodes start:stop of one joint by weights w (P, nodes) -> persons (K,), node indices (K,)."""
    rows, cols = linear_sum_assignment(w[:, start:stop], maximize=True)
    keep = w[rows, start + cols] > 0
    return rows[keep], start + cols[keep]


def _apply_matches(
    own: np.ndarray,
    xy: np.ndarray,
    w: np.ndarray,
    best: np.ndarray,
    joint_of_node: np.ndarray,
    matched: list[tuple[np.ndarray, np.ndarray]],
) -> np.ndarray:
    """Own best candidates (P, J, 3) with the matched joint types replaced by the matches -> (P, J, 3)."""
    if not matched:
        return own
    out = own.copy()
    joints = np.unique(joint_of_node[np.concatenate([c for _, c in matched])])
    out[:, joints, 2] = 0.0
    rows, cols = np.concatenate([r for r, _ in matched]), np.concatenate([c for _, c in matched])
    j = joint_of_node[cols]
    out[rows, j, :2] = xy[rows, j, best[rows, cols]]
    out[rows, j, 2] = w[rows, cols]
    return out


def own_best(xy: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """Each person's best candidate per joint: xy (P, J, M, 2), scores (P, J, M) -> (P, J, 3), 0 where none."""
    best = scores.argmax(axis=-1)[..., None]
    out = np.concatenate(
        [np.take_along_axis(xy, best[..., None], axis=2)[:, :, 0], np.take_along_axis(scores, best, axis=2)], -1
    )
    return np.where(out[..., 2:] > 0, out, 0.0)


def joint_nodes(xy: np.ndarray, scores: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Candidates xy (P, J, M, 2), scores (P, J, M), radii (P, J) -> node labels (P, J, M) (-1: no candidate)."""
    n_persons, n_joints, m = scores.shape
    pts = xy.transpose(1, 0, 2, 3).reshape(n_joints, n_persons * m, 2)
    valid = (scores > 0).transpose(1, 0, 2).reshape(n_joints, n_persons * m)
    r = np.repeat(radii.T, m, axis=1)  # (J, P M)
    owner = np.repeat(np.arange(n_persons), m)
    x, y = pts[..., 0], pts[..., 1]
    dist = np.sqrt((x[:, :, None] - x[:, None]) ** 2 + (y[:, :, None] - y[:, None]) ** 2)  # (J, P M, P M), as cdist
    linked = (dist <= (r[:, :, None] + r[:, None, :]) / 2) & (owner[:, None] != owner[None, :])
    linked &= valid[:, :, None] & valid[:, None, :]
    j, a, b = np.nonzero(linked)
    size = n_joints * n_persons * m
    graph = csr_matrix((np.ones(len(j), dtype=bool), (j * n_persons * m + a, j * n_persons * m + b)), (size, size))
    _, labels = connected_components(graph, directed=False)
    labels = labels.reshape(n_joints, n_persons, m).transpose(1, 0, 2)
    valid = scores > 0
    _, dense = np.unique(labels[valid], return_inverse=True)  # labels of absent candidates dropped, order kept
    out = np.full(scores.shape, -1, dtype=int)
    out[valid] = dense
    return out


def best_per_node(nodes: np.ndarray, scores: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each person's best candidate per node: nodes, scores (P, J, M) -> person, node, weight, slot, each (K,)."""
    p, _, m = np.nonzero(nodes >= 0)
    node, s = nodes[nodes >= 0], scores[nodes >= 0]
    order = np.lexsort((m, -s, node, p))
    p, node, s, m = p[order], node[order], s[order], m[order]
    first = np.ones(len(p), dtype=bool)
    first[1:] = (p[1:] != p[:-1]) | (node[1:] != node[:-1])
    return p[first], node[first], s[first], m[first]
