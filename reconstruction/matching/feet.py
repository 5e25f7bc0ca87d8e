"""The paper's feet-assignment matcher (Sec. 3.2): persons matched across views by their feet on the ground."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from data.geometry.camera import Camera, Rig
from data.keypoints import LEFT_ANKLE, LEFT_FOOT, NUM_JOINTS, RIGHT_ANKLE, RIGHT_FOOT
from data.multiview import ViewDetections
from reconstruction.matching.feet_kernels import foot_points
from reconstruction.matching.feet_uncertainty import (
    joint_sigmas,
    location_covariance,
    mahalanobis_distances,
    views_joints_on_planes,
)
from reconstruction.matching.merge import match_pairs
from reconstruction.results import Matches

FOOT_RULES = ("lowest", "mean")
SPACES = ("ground", "image")
METRICS = ("euclidean", "mahalanobis")
NO_FOOT_JOINTS = "no_foot_joints"  # no foot joint (nor ankle, with the fallback) above min_score
FEET_ABOVE_HORIZON = "feet_above_horizon"  # scored foot joints exist, but none meets the ground in front
NO_COUNTERPART = "no_counterpart"  # has feet, but ended in no person of >= min_views views
_FOOT_COLUMNS = (*LEFT_FOOT, *RIGHT_FOOT, LEFT_ANKLE, RIGHT_ANKLE)  # gathered order: 3 + 3 + 2


@dataclass(frozen=True)
class FeetFeatures:
    """Feet of N detections: left, right, p, v (N, 2), has_* (N,) bool; missing points are 0, never NaN."""

    left: np.ndarray
    right: np.ndarray
    has_left: np.ndarray
    has_right: np.ndarray
    p: np.ndarray
    v: np.ndarray
    has_p: np.ndarray
    has_stride: np.ndarray
    reason: np.ndarray  # (N,) str, "" where the detection has a location
    cov: np.ndarray | None = None  # (N, 2, 2) covariance of p; None where no pixel noise was propagated

    def __len__(self) -> int:
        return len(self.p)


def features_from_feet(
    left: np.ndarray,
    right: np.ndarray,
    has_left: np.ndarray,
    has_right: np.ndarray,
    reason: np.ndarray | None = None,
    cov_left: np.ndarray | None = None,
    cov_right: np.ndarray | None = None,
) -> FeetFeatures:
    """Location and stride from two feet (N, 2), (N,) each [, covariances (N, 2, 2)]; one foot: p = it, no stride."""
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
    cov = None
    if cov_left is not None and cov_right is not None:
        cov = location_covariance(cov_left, cov_right, has_left, has_right)
    return FeetFeatures(left, right, has_left, has_right, p, v, has_p, both, np.asarray(reason, dtype=str), cov)


def feet_features(keypoints: np.ndarray, camera: Camera, rule: str = "mean", **settings) -> FeetFeatures:
    """Ground-plane feet (m) of keypoints (N, 23, 3) distorted px + score -> FeetFeatures (views_feet_features)."""
    return views_feet_features([keypoints], [camera], rule, **settings)


def views_feet_features(
    keypoints: list[np.ndarray],
    cameras: list[Camera],
    rule: str = "mean",
    min_score: float = 0.2,
    ankle_fallback: bool = True,
    pixel_sigma: float | None = None,
    ankle_height_m: float = 0.07,
    foot_joint_height_m: float = 0.0,
    sigma_score_power: float = 0.0,
) -> FeetFeatures:
    """Ground-plane feet (m) of V views' detections, view after view: V (N_v, 23, 3), V cameras -> FeetFeatures."""
    if rule not in FOOT_RULES:
        raise ValueError(f"foot rule must be one of {FOOT_RULES}, got {rule!r}")
    kps = [np.asarray(k, dtype=np.float64) for k in keypoints]
    for kp in kps:
        if kp.ndim != 3 or kp.shape[1:] != (NUM_JOINTS, 3):
            raise ValueError(f"keypoints must have shape (N, {NUM_JOINTS}, 3), got {kp.shape}")
    kp = np.concatenate(kps) if len(kps) != 1 else kps[0]
    uv = kp[:, _FOOT_COLUMNS, :2]
    score = kp[:, _FOOT_COLUMNS, 2]
    finite = np.isfinite(uv[..., 0]) & np.isfinite(uv[..., 1]) & np.isfinite(score)  # not .all(-1): slow on 2
    uv = np.where(finite[..., None], uv, 0.0)
    heights = np.array([foot_joint_height_m] * 6 + [ankle_height_m] * 2, dtype=np.float64)
    sigma = None if pixel_sigma is None else joint_sigmas(score, pixel_sigma, sigma_score_power)
    ground, depth, cov = views_joints_on_planes(cameras, [len(k) for k in kps], uv, heights, sigma)
    cov = np.zeros(ground.shape + (2,)) if cov is None else cov
    scored = finite & (score > min_score)
    point, point_cov, ok = np.empty((2, len(kp), 2)), np.empty((2, len(kp), 2, 2)), np.empty((2, len(kp)), bool)
    scored_c, lowest = np.ascontiguousarray(scored), rule == "lowest"
    foot_points(ground, cov, depth, uv[..., 1].copy(), scored_c, lowest, bool(ankle_fallback), point, point_cov, ok)
    considered = scored if ankle_fallback else scored[:, :6]
    reason = np.where(ok[0] | ok[1], "", np.where(considered.any(axis=1), FEET_ABOVE_HORIZON, NO_FOOT_JOINTS))
    covs = (point_cov[0], point_cov[1]) if pixel_sigma is not None else (None, None)
    return features_from_feet(point[0], point[1], ok[0], ok[1], reason, *covs)


def split_features(features: FeetFeatures, counts: list[int]) -> list[FeetFeatures]:
    """FeetFeatures of stacked views -> one per view (N_v rows each, in order)."""
    cuts = np.cumsum(counts)[:-1]
    fields = [
        np.split(getattr(features, name), cuts) if getattr(features, name) is not None else [None] * len(counts)
        for name in FeetFeatures.__dataclass_fields__
    ]
    return [FeetFeatures(*values) for values in zip(*fields)]


def pair_homography(camera_l: Camera, camera_m: Camera) -> np.ndarray:
    """The paper's H_{l,m}: undistorted pixels of view m -> undistorted pixels of view l via z = 0: (3, 3)."""
    H = camera_l.ground_to_image_homography() @ camera_m.image_to_ground_homography()
    return H / H[2, 2]


def to_image(features: FeetFeatures, camera: Camera) -> FeetFeatures:
    """Ground feet (m) -> FeetFeatures in undistorted pixels of ``camera``; feet behind the camera become missing."""
    feet = np.stack([features.left, features.right], axis=1)
    front = camera.depth(np.concatenate([feet, np.zeros_like(feet[..., :1])], axis=-1)) > 0
    uv = camera.ground_to_image(feet, distort=False)
    return features_from_feet(
        uv[:, 0], uv[:, 1], features.has_left & front[:, 0], features.has_right & front[:, 1], features.reason
    )


def edge_costs(
    fa: FeetFeatures,
    fb: FeetFeatures,
    k1: float = 1.0,
    k2: float = 0.5,
    k3: float = 0.25,
    unknown_stride_cost: float = 0.1,
    metric: str = "euclidean",
    floor_m: float = 0.05,
) -> np.ndarray:
    """Eq. 4 costs of (Na,), (Nb,) feet -> (Na, Nb), inf without a location (design.md: feet.py)."""
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    if metric == "euclidean":
        location = np.linalg.norm(fa.p[:, None] - fb.p[None], axis=-1)
    elif fa.cov is None or fb.cov is None:
        raise ValueError("the mahalanobis metric needs features with a covariance (give pixel_sigma)")
    else:
        location = mahalanobis_distances(fa.p, fb.p, fa.cov, fb.cov, floor_m)
    len_a = np.linalg.norm(fa.v, axis=-1)
    len_b = np.linalg.norm(fb.v, axis=-1)
    cross = fa.v[:, None, 0] * fb.v[None, :, 1] - fa.v[:, None, 1] * fb.v[None, :, 0]
    denom = len_a[:, None] * len_b[None]
    sine = np.divide(np.abs(cross), denom, out=np.zeros_like(denom), where=denom > 1e-12)
    stride = k2 * np.abs(len_a[:, None] - len_b[None]) + k3 * sine
    stride = np.where(fa.has_stride[:, None] & fb.has_stride[None], stride, unknown_stride_cost)
    cost = k1 * location + stride
    return np.where(fa.has_p[:, None] & fb.has_p[None], cost, np.inf)


def metric_defaults(metric: str) -> tuple[float, float, float, float]:
    """Default (k2, k3, gate, unknown_stride_cost) of a ground-space location metric."""
    if metric == "mahalanobis":  # location in standard deviations; stride terms off (mostly noise)
        return 0.0, 0.0, 3.0, 0.0
    return 0.5, 0.25, 0.6, 0.1  # metres: the paper's Eq. 4


class FeetMatcher:
    """Feet assignment across views: ``matcher(views, rig) -> Matches`` (settings: docs/design.md, feet.py)."""

    def __init__(
        self,
        *,
        k1: float = 1.0,
        k2: float | None = None,
        k3: float | None = None,
        gate: float | None = None,
        space: str = "ground",
        foot_rule: str = "mean",
        min_score: float = 0.2,
        ankle_fallback: bool = True,
        min_views: int = 2,
        unknown_stride_cost: float | None = None,
        location_metric: str | None = None,
        pixel_sigma: float = 3.0,
        ground_sigma_floor: float = 0.1,
        ankle_height_m: float = 0.07,
        foot_joint_height_m: float = 0.0,
        sigma_score_power: float = 0.0,
        margin: float = 0.0,
    ) -> None:
        metric = location_metric or ("euclidean" if space == "image" else "mahalanobis")
        if space not in SPACES or foot_rule not in FOOT_RULES or metric not in METRICS:
            raise ValueError(
                f"need space in {SPACES}, foot_rule in {FOOT_RULES}, location_metric in "
                f"{METRICS}; got {space!r}, {foot_rule!r}, {metric!r}"
            )
        if space == "image" and (gate is None or unknown_stride_cost is None or metric != "euclidean"):
            raise ValueError("space='image' costs are Euclidean pixels: give gate and unknown_stride_cost in pixels")
        d_k2, d_k3, d_gate, d_unknown = metric_defaults(metric)
        k2, k3 = (d_k2 if k2 is None else k2), (d_k3 if k3 is None else k3)
        if min(k1, k2, k3, margin) < 0 or int(min_views) < 1 or pixel_sigma <= 0 or ground_sigma_floor <= 0:
            raise ValueError("k1, k2, k3, margin must be >= 0, min_views >= 1, pixel_sigma and ground_sigma_floor > 0")
        self.k1, self.k2, self.k3 = float(k1), float(k2), float(k3)
        self.gate = d_gate if gate is None else float(gate)
        self.unknown_stride_cost = d_unknown if unknown_stride_cost is None else float(unknown_stride_cost)
        self.space, self.foot_rule, self.location_metric = space, foot_rule, metric
        self.min_score, self.ankle_fallback, self.min_views = float(min_score), bool(ankle_fallback), int(min_views)
        self.pixel_sigma, self.ground_sigma_floor = float(pixel_sigma), float(ground_sigma_floor)
        self.ankle_height_m, self.foot_joint_height_m = float(ankle_height_m), float(foot_joint_height_m)
        self.sigma_score_power, self.margin = float(sigma_score_power), float(margin)

    def features(self, views: list[ViewDetections], rig: Rig) -> list[FeetFeatures]:
        """Ground-plane feet of every view: V views -> V FeetFeatures."""
        return split_features(self.stacked_features(views, rig), [len(v) for v in views])

    def stacked_features(self, views: list[ViewDetections], rig: Rig) -> FeetFeatures:
        """Ground-plane feet of the detections of all views, view after view: V views -> FeetFeatures."""
        if len(views) != len(rig):
            raise ValueError(f"{len(views)} views of detections for a rig of {len(rig)} cameras")
        sigma = self.pixel_sigma if self.location_metric == "mahalanobis" else None
        settings = (self.min_score, self.ankle_fallback, sigma, self.ankle_height_m, self.foot_joint_height_m)
        keypoints = [v.keypoints for v in views]
        return views_feet_features(keypoints, list(rig), self.foot_rule, *settings, self.sigma_score_power)

    def pair_cost(self, fa: FeetFeatures, fb: FeetFeatures, camera_a: Camera) -> np.ndarray:
        """Edge costs of a view pair (a < b) in the configured space: (Na,), (Nb,) -> (Na, Nb)."""
        if self.space == "image":
            fa, fb = to_image(fa, camera_a), to_image(fb, camera_a)
        return edge_costs(
            fa, fb, self.k1, self.k2, self.k3, self.unknown_stride_cost, self.location_metric, self.ground_sigma_floor
        )

    def __call__(self, views: list[ViewDetections], rig: Rig) -> Matches:
        """Assignment of one frame: V views -> Matches, (P, V) detection indices (-1 where absent)."""
        feats = self.features(views, rig)
        cost = lambda a, b: self.pair_cost(feats[a], feats[b], rig[a])  # noqa: E731
        assignment = match_pairs(cost, [len(v) for v in views], self.gate, self.min_views, self.margin)
        reasons = Counter(str(r) for f in feats for r in f.reason if r)
        unplaced = sum(int(f.has_p.sum()) for f in feats) - int(np.sum(assignment >= 0))
        if unplaced:
            reasons[NO_COUNTERPART] = unplaced
        return Matches(assignment, reasons)
