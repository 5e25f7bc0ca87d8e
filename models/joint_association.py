"""CrowdPose's global maximum joints association (Li et al. CVPR 2019) over the boxes of one image.

Per joint type ``j``:

1. Joint nodes. The candidates of joint ``j`` from all boxes are linked when they come from different
   boxes and lie closer than an OKS-like radius ``dist_thresh * sigma_j * (s_p + s_q) / 2``, where
   ``s_p = sqrt(w_p h_p)`` is the scale of box ``p`` and ``sigma_j`` its COCO OKS sigma (CrowdPose's own
   grouping criterion is ``d <= sigma_j * sqrt(area)``, i.e. ``dist_thresh = 1``). The connected
   components of these links are the nodes: physical joints seen from several boxes. Components do not
   depend on the order of the boxes (long chains of close joints in a dense crowd may merge; a lower
   ``dist_thresh`` splits them).
2. Matching. A bipartite graph persons x nodes with weight = the score of the person's best candidate in
   the node (0 if it has none) is solved as a maximum-weight matching
   (``scipy.optimize.linear_sum_assignment(maximize=True)``), so no two persons claim one node.

A matched person gets the position and score of its own best candidate in its node. An unmatched person
(its every candidate claimed by someone with more to gain) keeps the position of its best candidate with
score 0, as CrowdPose keeps only matched joints; the position is kept because COCO's OKS uses the
coordinates of every predicted keypoint, whatever its score. A person with no candidate gets (0, 0, 0).
Exact ties between matchings are broken by scipy, i.e. by person order.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial.distance import cdist

from data.keypoints import NUM_JOINTS, OKS_SIGMAS


def associate_joints(
    xy: np.ndarray, scores: np.ndarray, boxes: np.ndarray, dist_thresh: float = 1.0, sigmas: np.ndarray | None = None
) -> np.ndarray:
    """Associate joint candidates to persons: xy (P, J, M, 2) image px, scores (P, J, M), boxes (P, 4) xywh
    -> keypoints (P, J, 3) x, y, score.

    ``sigmas`` (J,): per-joint OKS sigmas of the node radius; defaults to the COCO-23 ones (J must be 23).
    Candidates with score <= 0 are absent.
    """
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
    sigmas = np.asarray(sigmas, dtype=np.float64)
    box_scale = np.sqrt(np.clip(boxes[:, 2] * boxes[:, 3], 0.0, None))
    out = np.zeros((n_persons, n_joints, 3))
    for j in range(n_joints):
        out[:, j] = associate_joint(xy[:, j], scores[:, j], dist_thresh * sigmas[j] * box_scale)
    return out


def joint_nodes(points: np.ndarray, owners: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Cluster candidates into joint nodes: points (C, 2), owners (C,) person ids, radii (C,) -> labels (C,).

    Two candidates of different owners are linked when their distance is at most the mean of their radii;
    the nodes are the connected components of the links.
    """
    if len(points) == 0:
        return np.zeros(0, dtype=int)
    dist = cdist(points, points)
    linked = (dist <= (radii[:, None] + radii[None, :]) / 2) & (owners[:, None] != owners[None, :])
    _, labels = connected_components(csr_matrix(linked), directed=False)
    return labels


def associate_joint(xy: np.ndarray, scores: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """One joint type: xy (P, M, 2), scores (P, M), per-person node radii (P,) -> (P, 3) x, y, score."""
    n_persons = len(scores)
    out = np.zeros((n_persons, 3))
    owners, slots = np.nonzero(scores > 0)
    if len(owners) == 0:
        return out
    labels = joint_nodes(xy[owners, slots], owners, radii[owners])
    weight = np.zeros((n_persons, labels.max() + 1))
    best = np.full(weight.shape, -1)
    for c, (p, node) in enumerate(zip(owners, labels)):
        if scores[p, slots[c]] > weight[p, node]:
            weight[p, node], best[p, node] = scores[p, slots[c]], slots[c]
    own_best = scores.argmax(axis=1)
    has_any = scores.max(axis=1) > 0
    out[has_any, :2] = xy[has_any, own_best[has_any]]
    for p, node in zip(*linear_sum_assignment(weight, maximize=True)):
        if weight[p, node] > 0:
            out[p] = (*xy[p, best[p, node]], weight[p, node])
    return out
