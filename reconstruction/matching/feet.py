"""The paper's feet-assignment matcher (Sec. 3.2): persons matched across views by their feet.

Each detection becomes a pair of feet on the ground plane z = 0: location p = midpoint of the two
feet and stride v = right - left. Every view pair is scored with the edge cost of Eq. 4, solved as a
gated linear assignment (Jonker-Volgenant, via scipy) and the accepted edges of all pairs are merged
into persons, cheaper edges first, never two detections of one view in a person.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from data.keypoints import LEFT_ANKLE, LEFT_FOOT, NUM_JOINTS, RIGHT_ANKLE, RIGHT_FOOT
from data.multiview import ViewDetections
from reconstruction.camera import Camera, Rig
from reconstruction.matching.merge import merge_edges, pair_edges, solve_pair

FOOT_RULES = ("lowest", "mean")
SPACES = ("ground", "image")
NO_FOOT_JOINTS = "no_foot_joints"          # no foot joint (nor ankle, with the fallback) above min_score
FEET_ABOVE_HORIZON = "feet_above_horizon"  # scored foot joints exist, but none meets the ground in front
NO_COUNTERPART = "no_counterpart"          # has feet, but ended in no person of >= min_views views
_FOOT_COLUMNS = (*LEFT_FOOT, *RIGHT_FOOT, LEFT_ANKLE, RIGHT_ANKLE)  # gathered order: 3 + 3 + 2


@dataclass(frozen=True)
class FeetFeatures:
    """Feet of N detections: left, right, p, v (N, 2); has_left, has_right, has_p, has_stride (N,);
    reason (N,) str, "" where the detection has a location. Missing points are 0, never NaN."""

    left: np.ndarray
    right: np.ndarray
    has_left: np.ndarray
    has_right: np.ndarray
    p: np.ndarray
    v: np.ndarray
    has_p: np.ndarray
    has_stride: np.ndarray
    reason: np.ndarray

    def __len__(self) -> int:
        return len(self.p)


def features_from_feet(left: np.ndarray, right: np.ndarray, has_left: np.ndarray,
                       has_right: np.ndarray, reason: np.ndarray | None = None) -> FeetFeatures:
    """Location and stride from two feet: (N, 2), (N, 2), (N,), (N,) [, reason (N,)] -> FeetFeatures.

    With one foot only, p is that foot and the stride is unknown.
    """
    has_left = np.asarray(has_left, dtype=bool)
    has_right = np.asarray(has_right, dtype=bool)
    left = np.where(has_left[:, None], np.asarray(left, dtype=np.float64), 0.0)
    right = np.where(has_right[:, None], np.asarray(right, dtype=np.float64), 0.0)
    both = has_left & has_right
    p = np.where(both[:, None], (left + right) / 2, left + right)  # the absent foot is 0
    v = np.where(both[:, None], right - left, 0.0)
    has_p = has_left | has_right
    if reason is None:
        reason = np.where(has_p, "", NO_FOOT_JOINTS)
    return FeetFeatures(left, right, has_left, has_right, p, v, has_p, both, np.asarray(reason, dtype=str))


def _select_foot(ground: np.ndarray, y: np.ndarray, valid: np.ndarray, rule: str) -> tuple[np.ndarray, np.ndarray]:
    """One foot point per detection: ground (N, K, 2), image y (N, K), valid (N, K) -> (N, 2), ok (N,)."""
    ok = valid.any(axis=1)
    if rule == "lowest":
        pick = np.argmax(np.where(valid, y, -np.inf), axis=1)
        return ground[np.arange(len(ground)), pick], ok
    total = np.where(valid[..., None], ground, 0.0).sum(axis=1)
    return total / np.maximum(valid.sum(axis=1), 1)[:, None], ok


def feet_features(keypoints: np.ndarray, camera: Camera, rule: str = "lowest", min_score: float = 0.2,
                  ankle_fallback: bool = True) -> FeetFeatures:
    """Ground-plane feet (m) of N detections: keypoints (N, 23, 3) distorted pixels + score -> FeetFeatures.

    A foot is its joints (big toe, small toe, heel) with score > min_score: the one lowest in the
    image (largest y of the detected pixels) for rule "lowest", the mean of their ground points for
    "mean"; without any, the ankle if ``ankle_fallback``. Joints whose ground point lies behind the
    camera (above the horizon) are unusable.
    """
    if rule not in FOOT_RULES:
        raise ValueError(f"foot rule must be one of {FOOT_RULES}, got {rule!r}")
    kp = np.asarray(keypoints, dtype=np.float64)
    if kp.ndim != 3 or kp.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(f"keypoints must have shape (N, {NUM_JOINTS}, 3), got {kp.shape}")
    uv = kp[:, _FOOT_COLUMNS, :2]
    score = kp[:, _FOOT_COLUMNS, 2]
    finite = np.isfinite(uv).all(axis=-1) & np.isfinite(score)
    uv = np.where(finite[..., None], uv, 0.0)
    ground = camera.image_to_ground(uv)
    ground_ok = np.isfinite(ground).all(axis=-1)
    ground = np.where(ground_ok[..., None], ground, 0.0)
    in_front = ground_ok & (camera.depth(np.concatenate([ground, np.zeros_like(ground[..., :1])], -1)) > 0)
    scored = finite & (score > min_score)
    usable = scored & in_front
    feet = []
    for side in (0, 1):
        cols = slice(3 * side, 3 * side + 3)
        point, ok = _select_foot(ground[:, cols], uv[:, cols, 1], usable[:, cols], rule)
        if ankle_fallback:
            ankle = 6 + side
            use_ankle = ~ok & usable[:, ankle]
            point = np.where(use_ankle[:, None], ground[:, ankle], point)
            ok = ok | use_ankle
        feet.append((point, ok))
    considered = scored if ankle_fallback else scored[:, :6]
    reason = np.where(feet[0][1] | feet[1][1], "",
                      np.where(considered.any(axis=1), FEET_ABOVE_HORIZON, NO_FOOT_JOINTS))
    return features_from_feet(feet[0][0], feet[1][0], feet[0][1], feet[1][1], reason)


def pair_homography(camera_l: Camera, camera_m: Camera) -> np.ndarray:
    """The paper's H_{l,m}: undistorted pixels of view m -> undistorted pixels of view l via z = 0: (3, 3)."""
    H = camera_l.ground_to_image_homography() @ camera_m.image_to_ground_homography()
    return H / H[2, 2]


def to_image(features: FeetFeatures, camera: Camera) -> FeetFeatures:
    """Ground feet (m) into undistorted pixels of ``camera``: FeetFeatures -> FeetFeatures (pixels).

    Mapping view m's ground feet this way equals applying :func:`pair_homography` to its undistorted
    foot pixels. Feet behind the camera would land on mirrored pixels, so they become missing.
    """
    feet = np.stack([features.left, features.right], axis=1)
    front = camera.depth(np.concatenate([feet, np.zeros_like(feet[..., :1])], axis=-1)) > 0
    uv = camera.ground_to_image(feet, distort=False)
    return features_from_feet(uv[:, 0], uv[:, 1], features.has_left & front[:, 0],
                              features.has_right & front[:, 1], features.reason)


def edge_costs(fa: FeetFeatures, fb: FeetFeatures, k1: float = 1.0, k2: float = 0.5, k3: float = 0.25,
               unknown_stride_cost: float = 0.1) -> np.ndarray:
    """Eq. 4 between two views' feet in one space: (Na,), (Nb,) -> cost (Na, Nb), +inf without a location.

    c = k1 |p_a - p_b| + k2 | |v_a| - |v_b| | + k3 |v_a x v_b| / (|v_a| |v_b|). Where either stride is
    unknown (one foot only) the two stride terms are replaced by ``unknown_stride_cost``; a zero-length
    stride has no direction, so its direction term is 0.
    """
    location = np.linalg.norm(fa.p[:, None] - fb.p[None], axis=-1)
    len_a = np.linalg.norm(fa.v, axis=-1)
    len_b = np.linalg.norm(fb.v, axis=-1)
    cross = fa.v[:, None, 0] * fb.v[None, :, 1] - fa.v[:, None, 1] * fb.v[None, :, 0]
    denom = len_a[:, None] * len_b[None]
    sine = np.divide(np.abs(cross), denom, out=np.zeros_like(denom), where=denom > 1e-12)
    stride = k2 * np.abs(len_a[:, None] - len_b[None]) + k3 * sine
    stride = np.where(fa.has_stride[:, None] & fb.has_stride[None], stride, unknown_stride_cost)
    cost = k1 * location + stride
    return np.where(fa.has_p[:, None] & fb.has_p[None], cost, np.inf)


class FeetMatcher:
    """Feet assignment across views: ``matcher(views, rig) -> (P, V)`` detection index per view or -1.

    Defaults are for space="ground" (metres). space="image" is the paper's literal variant: for each
    pair l < m, both views' feet are compared in undistorted pixels of view l, so ``gate`` and
    ``unknown_stride_cost`` must then be given in pixels (and k3 scaled to pixels). Counts of
    detections left out of every person, by reason, are kept in ``last_unmatched_reasons`` (last frame)
    and ``unmatched_reasons`` (all frames since construction).
    """

    def __init__(self, k1: float = 1.0, k2: float = 0.5, k3: float = 0.25, gate: float | None = None,
                 space: str = "ground", foot_rule: str = "lowest", min_score: float = 0.2,
                 ankle_fallback: bool = True, min_views: int = 2,
                 unknown_stride_cost: float | None = None) -> None:
        if space not in SPACES:
            raise ValueError(f"space must be one of {SPACES}, got {space!r}")
        if foot_rule not in FOOT_RULES:
            raise ValueError(f"foot_rule must be one of {FOOT_RULES}, got {foot_rule!r}")
        if space == "image" and (gate is None or unknown_stride_cost is None):
            raise ValueError("space='image' costs are in pixels: give gate and unknown_stride_cost in pixels")
        if min(k1, k2, k3) < 0 or int(min_views) < 1:
            raise ValueError("k1, k2, k3 must be >= 0 and min_views >= 1")
        self.k1, self.k2, self.k3 = float(k1), float(k2), float(k3)
        self.gate = 0.6 if gate is None else float(gate)
        self.unknown_stride_cost = 0.1 if unknown_stride_cost is None else float(unknown_stride_cost)
        self.space, self.foot_rule = space, foot_rule
        self.min_score, self.ankle_fallback, self.min_views = float(min_score), bool(ankle_fallback), int(min_views)
        self.last_unmatched_reasons: Counter[str] = Counter()
        self.unmatched_reasons: Counter[str] = Counter()

    def features(self, views: list[ViewDetections], rig: Rig) -> list[FeetFeatures]:
        """Ground-plane feet of every view: V views -> V FeetFeatures."""
        if len(views) != len(rig):
            raise ValueError(f"{len(views)} views of detections for a rig of {len(rig)} cameras")
        return [feet_features(v.keypoints, cam, self.foot_rule, self.min_score, self.ankle_fallback)
                for v, cam in zip(views, rig)]

    def pair_cost(self, fa: FeetFeatures, fb: FeetFeatures, camera_a: Camera) -> np.ndarray:
        """Edge costs of a view pair (a < b) in the configured space: (Na,), (Nb,) -> (Na, Nb)."""
        if self.space == "image":
            fa, fb = to_image(fa, camera_a), to_image(fb, camera_a)
        return edge_costs(fa, fb, self.k1, self.k2, self.k3, self.unknown_stride_cost)

    def __call__(self, views: list[ViewDetections], rig: Rig) -> np.ndarray:
        """Assignment of one frame: V views -> (P, V) detection indices, -1 where absent."""
        feats = self.features(views, rig)
        edges = [np.zeros((0, 5))]
        for a, b in combinations(range(len(views)), 2):
            cost = self.pair_cost(feats[a], feats[b], rig[a])
            rows, cols = solve_pair(cost, self.gate)
            edges.append(pair_edges(a, b, rows, cols, cost))
        assignment = merge_edges(np.concatenate(edges), [len(v) for v in views], self.min_views)
        reasons = Counter(str(r) for f in feats for r in f.reason if r)
        unplaced = sum(int(f.has_p.sum()) for f in feats) - int(np.sum(assignment >= 0))
        if unplaced:
            reasons[NO_COUNTERPART] = unplaced
        self.last_unmatched_reasons = reasons
        self.unmatched_reasons = self.unmatched_reasons + reasons
        return assignment
