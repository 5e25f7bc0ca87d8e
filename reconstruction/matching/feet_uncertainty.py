"""Uncertainty of the feet matcher's ground points, and its Mahalanobis location cost."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from data.geometry.camera import Camera
from reconstruction.matching.feet_kernels import plane_points

_DIFF_STEP_PX = 0.5  # central-difference step of the undistortion Jacobian
_TINY = 1e-12  # relative size under which a homography's H[2, 2] counts as 0


def normalized(H: np.ndarray) -> np.ndarray:
    """A homography scaled to H[2, 2] = 1, or to unit norm where H[2, 2] is 0: (3, 3) -> (3, 3)."""
    scale = H[2, 2] if abs(H[2, 2]) > _TINY * np.abs(H).max() else np.linalg.norm(H)
    return H / scale


def plane_to_image_homography(camera: Camera, height: float = 0.0) -> np.ndarray:
    """Homography from (X, Y) on the plane z = height to undistorted pixels: (3, 3)."""
    H = camera.K @ np.column_stack([camera.R[:, 0], camera.R[:, 1], height * camera.R[:, 2] + camera.t])
    return normalized(H)


def image_to_plane_homography(camera: Camera, height: float = 0.0) -> np.ndarray | None:
    """Homography from undistorted pixels to (X, Y) on z = height: (3, 3); None: the camera centre is on it."""
    try:
        H = np.linalg.inv(plane_to_image_homography(camera, height))
    except np.linalg.LinAlgError:
        return None
    return normalized(H) if np.all(np.isfinite(H)) else None


@lru_cache(maxsize=256)
def cached_image_to_plane(camera: Camera, height: float) -> np.ndarray | None:
    """:func:`image_to_plane_homography`, computed once per (camera, height): cameras are immutable; read-only."""
    H = image_to_plane_homography(camera, height)
    if H is not None:
        H.flags.writeable = False
    return H


def undistortion_jacobian(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """Jacobian of distorted -> undistorted pixels by central differences: (..., 2) -> (..., 2, 2)."""
    uv = np.asarray(uv, dtype=np.float64)
    eye = np.broadcast_to(np.eye(2), uv.shape[:-1] + (2, 2))
    if not camera.has_distortion or uv.size == 0:
        return eye.copy()
    cols = [
        (camera.undistort_points(uv + _DIFF_STEP_PX * e) - camera.undistort_points(uv - _DIFF_STEP_PX * e))
        / (2 * _DIFF_STEP_PX)
        for e in np.eye(2)
    ]
    return np.stack(cols, axis=-1)


def joints_on_planes(
    camera: Camera, uv: np.ndarray, heights: np.ndarray, sigma_px: float | np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Distorted px (N, K, 2) at heights (K,) m -> plane (X, Y) (N, K, 2), depth (N, K), covariance (N, K, 2, 2)."""
    uv = np.asarray(uv, dtype=np.float64)
    return views_joints_on_planes([camera], [len(uv)], uv, heights, sigma_px)


def views_joints_on_planes(
    cameras: list[Camera],
    counts: list[int],
    uv: np.ndarray,
    heights: np.ndarray,
    sigma_px: float | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """joints_on_planes of V views stacked in view order (counts[v] rows): uv (N, K, 2) -> (N, K, 2), (N, K), cov."""
    uv = np.asarray(uv, dtype=np.float64)
    heights = np.broadcast_to(np.asarray(heights, dtype=np.float64), uv.shape[1:2])
    levels, level = np.unique(heights, return_inverse=True)
    view = np.repeat(np.arange(len(cameras)), counts)
    H = np.full((len(cameras), len(levels), 3, 3), np.nan)  # NaN: camera centre on that plane (no mapping)
    for v, camera in enumerate(cameras):
        for k, h in enumerate(levels):
            Hk = cached_image_to_plane(camera, float(h))
            if Hk is not None:
                H[v, k] = Hk
    und = _per_view(cameras, view, uv, lambda camera, rows: camera.undistort_points(uv[rows]), uv.copy())
    axis = np.array([c.R[2] for c in cameras], dtype=np.float64).reshape(-1, 3)  # optical axes: (V, 3)
    offset = np.array([c.t[2] for c in cameras], dtype=np.float64)
    xy, depth = np.empty(uv.shape), np.empty(uv.shape[:2])
    var = np.zeros((0, 0)) if sigma_px is None else np.broadcast_to(np.asarray(sigma_px, np.float64) ** 2, uv.shape[:2])
    cov = np.empty(uv.shape + (2,)) if sigma_px is not None else np.zeros((0, 0, 2, 2))
    und_jac = np.zeros((0, 0, 2, 2))  # empty: no distortion, the identity
    if sigma_px is not None and any(c.has_distortion for c in cameras):
        eye = np.broadcast_to(np.eye(2), uv.shape[:2] + (2, 2)).copy()
        und_jac = _per_view(cameras, view, uv, lambda camera, rows: undistortion_jacobian(camera, uv[rows]), eye)
    plane_points(
        und, H, view, level.astype(np.int64), heights.astype(np.float64), axis, offset,
        np.ascontiguousarray(var), und_jac, xy, depth, cov,
    )  # fmt: skip
    return xy, depth, (None if sigma_px is None else cov)


def _per_view(cameras: list[Camera], view: np.ndarray, uv: np.ndarray, of, out: np.ndarray) -> np.ndarray:
    """out with the rows of each distorted camera's view replaced by of(camera, rows) (the stacked detections)."""
    for v, camera in enumerate(cameras):
        if camera.has_distortion:
            rows = view == v
            out[rows] = of(camera, rows)
    return out


def joint_sigmas(score: np.ndarray, sigma_px: float, score_power: float = 0.0) -> np.ndarray:
    """Pixel SD per joint, sigma_px * score^-power (power 0: the same for all): (N, K) -> (N, K)."""
    score = np.clip(np.asarray(score, dtype=np.float64), 0.05, 1.0)
    return float(sigma_px) * score ** -float(score_power)


def location_covariance(
    cov_left: np.ndarray, cov_right: np.ndarray, has_left: np.ndarray, has_right: np.ndarray
) -> np.ndarray:
    """Covariance of p = mean of the present feet (independent): (N, 2, 2) x2, (N,) x2 -> (N, 2, 2)."""
    both = (np.asarray(has_left) & np.asarray(has_right))[:, None, None]
    cl = np.where(np.asarray(has_left)[:, None, None], cov_left, 0.0)
    cr = np.where(np.asarray(has_right)[:, None, None], cov_right, 0.0)
    return np.where(both, (cl + cr) / 4, cl + cr)


def mahalanobis_distances(
    pa: np.ndarray, pb: np.ndarray, cov_a: np.ndarray, cov_b: np.ndarray, floor_m: float = 0.05
) -> np.ndarray:
    """sqrt(dp^T (S_a + S_b + floor^2 I)^-1 dp): (Na, 2), (Nb, 2), (Na, 2, 2), (Nb, 2, 2) -> (Na, Nb) in SDs."""
    pa, pb = np.asarray(pa, dtype=np.float64), np.asarray(pb, dtype=np.float64)
    cov_a, cov_b = np.asarray(cov_a, dtype=np.float64), np.asarray(cov_b, dtype=np.float64)
    dx, dy = pa[:, None, 0] - pb[None, :, 0], pa[:, None, 1] - pb[None, :, 1]
    # the entries of S = S_a + S_b + floor^2 I, pair by pair, without (Na, Nb, 2, 2) temporaries
    floor2 = float(floor_m) ** 2
    a = cov_a[:, None, 0, 0] + cov_b[None, :, 0, 0] + floor2
    c = cov_a[:, None, 1, 1] + cov_b[None, :, 1, 1] + floor2
    b = 0.5 * (cov_a[:, None, 0, 1] + cov_a[:, None, 1, 0] + cov_b[None, :, 0, 1] + cov_b[None, :, 1, 0])
    quad = (c * dx * dx - 2 * b * dx * dy + a * dy * dy) / (a * c - b * b)
    return np.sqrt(np.maximum(quad, 0.0))
