"""The epipolar-constraint baseline of the paper's Table 6 ("EC", ``matching=epipolar``), and the shared pieces."""

from __future__ import annotations

from collections import Counter
from functools import lru_cache
from itertools import combinations

import numpy as np

from data.geometry.camera import Camera, Rig, fundamental_matrix
from data.multiview import ViewDetections
from reconstruction.matching.merge import match_pairs
from reconstruction.results import Matches

TOO_FEW_JOINTS = "too_few_joints"  # fewer than min_common_joints joints with score >= min_score
NO_COUNTERPART = "no_counterpart"  # enough joints, but ended in no person of >= min_views views


def undistorted_joints(view: ViewDetections, camera: Camera, min_score: float) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted confident joints (finite, score >= min_score): (N, J, 3) -> uv (N, J, 2) (else 0), ok (N, J)."""
    kp = np.asarray(view.keypoints, dtype=np.float64)
    ok = np.isfinite(kp).all(axis=-1) & (np.nan_to_num(kp[..., 2], nan=-np.inf) >= min_score)
    uv = camera.undistort_points(np.where(ok[..., None], kp[..., :2], 0.0))
    return np.where(ok[..., None], uv, 0.0), ok


@lru_cache(maxsize=8)
def fundamentals(rig: Rig) -> np.ndarray:
    """F of every view pair (a < b) of a rig, x_b^T F[a, b] x_a = 0, once per rig (not to be written): (V, V, 3, 3)."""
    F = np.zeros((len(rig), len(rig), 3, 3))
    for a, b in combinations(range(len(rig)), 2):
        F[a, b] = fundamental_matrix(rig[a], rig[b])
    return F


def _line_distance(lines: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance of points to lines: lines (Nl, J, 3), points (Np, J, 2) -> (Nl, Np, J), defined (Nl, 1, J)."""
    norm = np.hypot(lines[..., 0], lines[..., 1])
    defined = norm > 1e-12  # a point at the epipole has no epipolar line
    unit = lines / np.where(defined, norm, 1.0)[..., None]
    dist = np.abs(  # broadcasting, not einsum: einsum's per-joint batched dot is the slower at crowd sizes
        unit[:, None, :, 0] * points[None, :, :, 0] + unit[:, None, :, 1] * points[None, :, :, 1] + unit[:, None, :, 2]
    )
    return dist, defined[:, None, :]


def epipolar_distances(uv_a: np.ndarray, uv_b: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric epipolar distances (px): (Na, J, 2), (Nb, J, 2), F (3, 3) -> (Na, Nb, J) (0 at an epipole), defined."""
    ha = np.concatenate([uv_a, np.ones(uv_a.shape[:-1] + (1,))], axis=-1)
    hb = np.concatenate([uv_b, np.ones(uv_b.shape[:-1] + (1,))], axis=-1)
    in_b, ok_b = _line_distance(ha @ F.T, uv_b)  # lines of a's joints in view b
    in_a, ok_a = _line_distance(hb @ F, uv_a)  # lines of b's joints in view a
    defined = ok_b & ok_a.transpose(1, 0, 2)
    return np.where(defined, (in_b + in_a.transpose(1, 0, 2)) / 2, 0.0), defined


def epipolar_affinity(
    uv_a: np.ndarray, ok_a: np.ndarray, uv_b: np.ndarray, ok_b: np.ndarray, F: np.ndarray, min_common_joints: int = 3
) -> np.ndarray:
    """Mean symmetric epipolar distance over >= min_common_joints common joints, else inf: -> (Na, Nb)."""
    dist, defined = epipolar_distances(uv_a, uv_b, F)
    common = ok_a[:, None, :] & ok_b[None, :, :] & defined
    count = common.sum(axis=-1)
    total = np.where(common, dist, 0.0).sum(axis=-1)
    return np.where(count >= min_common_joints, total / np.maximum(count, 1), np.inf)


def unmatched_counts(usable: list[np.ndarray], assignment: np.ndarray) -> Counter[str]:
    """Detections left out of every person, by reason: V arrays (N_v,) bool, (P, V) -> Counter."""
    too_few = sum(int(np.sum(~u)) for u in usable)
    unplaced = sum(int(np.sum(u)) for u in usable) - int(np.sum(np.asarray(assignment) >= 0))
    return +Counter({TOO_FEW_JOINTS: too_few, NO_COUNTERPART: unplaced})  # +: the zero counts dropped


class EpipolarMatcher:
    """Epipolar-constraint matching: ``matcher(views, rig) -> Matches``; gate in pixels (mean epipolar distance)."""

    def __init__(
        self, min_score: float = 0.2, min_common_joints: int = 3, gate: float = 30.0, min_views: int = 2
    ) -> None:
        if int(min_common_joints) < 1 or int(min_views) < 1 or not float(gate) > 0:
            raise ValueError("min_common_joints and min_views must be >= 1 and gate > 0")
        self.min_score, self.min_common_joints = float(min_score), int(min_common_joints)
        self.gate, self.min_views = float(gate), int(min_views)

    def joints(self, views: list[ViewDetections], rig: Rig) -> list[tuple[np.ndarray, np.ndarray]]:
        """Undistorted confident joints of every view: V views -> V (uv (N, J, 2), ok (N, J))."""
        if len(views) != len(rig):
            raise ValueError(f"{len(views)} views of detections for a rig of {len(rig)} cameras")
        return [undistorted_joints(v, cam, self.min_score) for v, cam in zip(views, rig)]

    def __call__(self, views: list[ViewDetections], rig: Rig) -> Matches:
        """Assignment of one frame: V views -> Matches, (P, V) detection indices (-1 where absent)."""
        joints = self.joints(views, rig)

        F = fundamentals(rig)

        def cost(a: int, b: int) -> np.ndarray:
            return epipolar_affinity(*joints[a], *joints[b], F[a, b], self.min_common_joints)

        assignment = match_pairs(cost, [len(v) for v in views], self.gate, self.min_views)
        usable = [ok.sum(axis=1) >= self.min_common_joints for _, ok in joints]
        return Matches(assignment, unmatched_counts(usable, assignment))
