"""The RANSAC baseline of the paper's Table 6 (``matching=ransac``): persons matched across views by consensus."""

from __future__ import annotations

import numpy as np

from data.geometry.camera import Camera, Rig
from data.keypoints import NUM_JOINTS
from data.multiview import ViewDetections
from reconstruction.matching.epipolar import undistorted_joints, unmatched_counts
from reconstruction.matching.merge import match_pairs
from reconstruction.results import Matches


def depth_axis(camera: Camera) -> np.ndarray:
    """The optical axis made horizontal, or itself for a camera looking within ~6 degrees of vertical: world (3,)."""
    axis = camera.R[2]
    flat = np.array([axis[0], axis[1], 0.0])
    norm = np.linalg.norm(flat)
    return flat / norm if norm > 0.1 else axis


def world_rays(uv: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Rays of undistorted pixels, unit depth along depth_axis: (..., 2) -> world (..., 3), ok (...,) (else 0)."""
    homog = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1)
    rays = homog @ (camera.R.T @ np.linalg.inv(camera.K)).T
    along = rays @ depth_axis(camera)
    ok = along > 1e-6
    return np.where(ok[..., None], rays / np.where(ok, along, 1.0)[..., None], 0.0), ok


def midpoint_depths(
    rays_a: np.ndarray, rays_b: np.ndarray, center_a: np.ndarray, center_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Depths of the closest points of rays (Na, J, 3), (Nb, J, 3) from (3,), (3,) -> lam_a, lam_b (Na, Nb, J)/NaN."""
    w = center_a - center_b
    aa = np.sum(rays_a**2, axis=-1)[:, None]  # (Na, 1, J)
    cc = np.sum(rays_b**2, axis=-1)[None]  # (1, Nb, J)
    bb = np.einsum("ajk,bjk->abj", rays_a, rays_b)  # (Na, Nb, J)
    dd = (rays_a @ w)[:, None]
    ee = (rays_b @ w)[None]
    denom = aa * cc - bb**2
    ok = denom > 1e-12 * aa * cc
    safe = np.where(ok, denom, 1.0)
    lam_a = np.where(ok, (bb * ee - cc * dd) / safe, np.nan)
    lam_b = np.where(ok, (aa * ee - bb * dd) / safe, np.nan)
    return lam_a, lam_b


def sample_masks(common: np.ndarray, keys: np.ndarray, sample_size: int) -> np.ndarray:
    """Minimal samples, the common joints of the sample_size smallest keys: (Na, Nb, J), (T, J) -> (Na, Nb, T, J)."""
    key = np.where(common[:, :, None, :], keys[None, None], np.inf)
    if sample_size > key.shape[-1]:
        return np.zeros(key.shape, dtype=bool)
    kth = np.partition(key, sample_size - 1, axis=-1)[..., sample_size - 1 : sample_size]
    return (key <= kth) & np.isfinite(key)


def transfer_errors(
    depth: np.ndarray, rays_from: np.ndarray, center_from: np.ndarray, camera_to: Camera, uv_to: np.ndarray
) -> np.ndarray:
    """Float32 pixel error of rays_from (..., 1, J, 3) at depth (Na, Nb, T) vs uv_to -> (Na, Nb, T, J), inf behind."""
    P = camera_to.P
    origin = (P @ np.append(center_from, 1.0)).astype(np.float32)  # image of the ray origin (3,)
    q = (rays_from @ P[:, :3].T).astype(np.float32)  # image of the ray direction
    uv_to = np.asarray(uv_to, dtype=np.float32)
    d = depth.astype(np.float32)[..., None]
    hz = origin[2] + d * q[..., 2]
    front = hz > 1e-9
    inv = 1.0 / np.where(front, hz, 1.0)
    ex = (origin[0] + d * q[..., 0]) * inv - uv_to[..., 0]
    ey = (origin[1] + d * q[..., 1]) * inv - uv_to[..., 1]
    return np.where(front, np.hypot(ex, ey), np.float32(np.inf))


class RansacMatcher:
    """Geometric-consensus (RANSAC / MSAC) matching: ``matcher(views, rig) -> Matches``."""

    def __init__(
        self,
        *,
        min_score: float = 0.2,  # a joint counts when scored >= this in both detections
        min_common_joints: int = 3,  # pairs with fewer such joints are never matched
        sample_size: int = 2,  # joints per minimal sample (their mean depth is the hypothesis)
        iterations: int = 20,  # hypotheses per candidate pair
        inlier_px: float = 40.0,  # symmetric transfer error (px) where an inlier ends and errors truncate
        gate: float = 0.5,  # pairs whose MSAC cost (in [0, 1]) exceeds this are never matched
        seed: int = 0,  # seed of the joint orders, the same on every frame
        min_views: int = 2,  # persons seen in fewer views are dropped
    ) -> None:
        if int(sample_size) < 1 or int(iterations) < 1 or int(min_views) < 1:
            raise ValueError("sample_size, iterations and min_views must be >= 1")
        if int(min_common_joints) < int(sample_size):
            raise ValueError("min_common_joints must be >= sample_size (a sample is drawn from the common joints)")
        if not float(inlier_px) > 0 or not float(gate) > 0:
            raise ValueError("inlier_px and gate must be > 0")
        self.min_score, self.min_common_joints = float(min_score), int(min_common_joints)
        self.sample_size, self.iterations = int(sample_size), int(iterations)
        self.inlier_px, self.gate = float(inlier_px), float(gate)
        self.seed, self.min_views = int(seed), int(min_views)

    def sample_keys(self, num_joints: int) -> np.ndarray:
        """The random joint orders of one call, as sort keys: -> (iterations, J)."""
        return np.random.default_rng(self.seed).random((self.iterations, num_joints))

    def pair_cost(
        self,
        uv_a: np.ndarray,
        ok_a: np.ndarray,
        uv_b: np.ndarray,
        ok_b: np.ndarray,
        camera_a: Camera,
        camera_b: Camera,
        keys: np.ndarray,
    ) -> np.ndarray:
        """MSAC cost of every candidate pair: (Na, J, 2), (Na, J), (Nb, J, 2), (Nb, J), keys (T, J) -> (Na, Nb)."""
        (rays_a, fwd_a), (rays_b, fwd_b) = world_rays(uv_a, camera_a), world_rays(uv_b, camera_b)
        lam_a, lam_b = midpoint_depths(rays_a, rays_b, camera_a.center, camera_b.center)
        common = (ok_a & fwd_a)[:, None] & (ok_b & fwd_b)[None] & np.isfinite(lam_a)
        count = common.sum(axis=-1)
        sample = sample_masks(common, keys, self.sample_size)
        depth_a = np.where(sample, lam_a[:, :, None], 0.0).sum(-1) / self.sample_size  # (Na, Nb, T)
        depth_b = np.where(sample, lam_b[:, :, None], 0.0).sum(-1) / self.sample_size
        valid = (depth_a > 0) & (depth_b > 0) & (sample.sum(-1) == self.sample_size)
        a_to_b = transfer_errors(depth_a, rays_a[:, None, None], camera_a.center, camera_b, uv_b[None, :, None])
        b_to_a = transfer_errors(depth_b, rays_b[None, :, None], camera_b.center, camera_a, uv_a[:, None, None])
        err = (a_to_b + b_to_a) / 2
        loss = np.where(common[:, :, None], np.minimum(err / self.inlier_px, 1.0), 0.0).sum(-1)
        loss = np.where(valid, loss / np.maximum(count, 1)[..., None], 1.0)
        best = loss.min(axis=-1, initial=1.0).astype(np.float64)
        return np.where(count >= self.min_common_joints, best, np.inf)

    def __call__(self, views: list[ViewDetections], rig: Rig) -> Matches:
        """Assignment of one frame: V views -> Matches, (P, V) detection indices (-1 where absent)."""
        if len(views) != len(rig):
            raise ValueError(f"{len(views)} views of detections for a rig of {len(rig)} cameras")
        joints = [undistorted_joints(v, cam, self.min_score) for v, cam in zip(views, rig)]
        keys = self.sample_keys(views[0].keypoints.shape[1] if views else NUM_JOINTS)

        def cost(a: int, b: int) -> np.ndarray:
            return self.pair_cost(*joints[a], *joints[b], rig[a], rig[b], keys)

        assignment = match_pairs(cost, [len(v) for v in views], self.gate, self.min_views)
        usable = [ok.sum(axis=1) >= self.min_common_joints for _, ok in joints]
        return Matches(assignment, unmatched_counts(usable, assignment))
