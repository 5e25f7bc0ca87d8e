"""Pinhole cameras with OpenCV distortion (k1, k2, p1, p2, k3), and rigs of named cameras (formats.md conventions)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Iterator

import cv2
import numpy as np

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera: K (3, 3), dist (5,), R (3, 3), t (3,), size (w, h) in pixels."""

    name: str
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]
    _fov_r2: float = field(init=False, repr=False)
    _distorted: bool = field(init=False, repr=False)  # any distortion coefficient non-zero (asked per frame)
    _P: np.ndarray = field(init=False, repr=False)  # K [R | t], fixed with the camera (asked per frame)

    def __post_init__(self) -> None:
        for key, shape in (("K", (3, 3)), ("dist", (5,)), ("R", (3, 3)), ("t", (3,))):
            value = np.array(getattr(self, key), dtype=np.float64)
            if value.shape != shape:
                raise ValueError(f"camera {self.name!r}: {key} has shape {value.shape}, expected {shape}")
            if not np.all(np.isfinite(value)):
                raise ValueError(f"camera {self.name!r}: {key} has a non-finite value")
            value.flags.writeable = False
            object.__setattr__(self, key, value)
        try:
            w, h = (int(s) for s in self.size)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"camera {self.name!r}: size must be two integers (w, h), got {self.size}") from None
        if not (0 < w < 2**31 and 0 < h < 2**31):
            raise ValueError(f"camera {self.name!r}: size must be positive, got {self.size}")
        object.__setattr__(self, "size", (w, h))
        object.__setattr__(self, "_distorted", bool(np.any(self.dist != 0)))
        object.__setattr__(self, "_fov_r2", self._field_of_view_r2())
        P = self.K @ np.hstack([self.R, self.t[:, None]])
        P.flags.writeable = False
        object.__setattr__(self, "_P", P)

    # --- geometry ---------------------------------------------------------------------------------
    @property
    def P(self) -> np.ndarray:
        """Projection matrix K [R | t] of undistorted pixels (read-only): (3, 4)."""
        return self._P

    @property
    def center(self) -> np.ndarray:
        """Camera centre in the world: (3,)."""
        return -self.R.T @ self.t

    @property
    def has_distortion(self) -> bool:
        """Whether any distortion coefficient is non-zero."""
        return self._distorted

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points to the camera frame: (..., 3) -> (..., 3)."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def depth(self, points: np.ndarray) -> np.ndarray:
        """Depth along the optical axis (m): (..., 3) -> (...,)."""
        return self.world_to_camera(points)[..., 2]

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points to distorted pixels with cv2.projectPoints: (..., 3) -> (..., 2)."""
        points = np.asarray(points, dtype=np.float64)
        flat = points.reshape(-1, 3)
        if flat.shape[0] == 0:
            return np.zeros(points.shape[:-1] + (2,))
        # R as stored, not through cv2.Rodrigues (which snaps it to a rotation): agrees with P and the homographies.
        uv, _ = cv2.projectPoints(self.world_to_camera(flat), np.zeros(3), np.zeros(3), self.K, self.dist)
        return uv.reshape(points.shape[:-1] + (2,))

    def undistort_points(self, uv: np.ndarray) -> np.ndarray:
        """Distorted pixels to undistorted pixels of the same K: (..., 2) -> (..., 2)."""
        uv = np.asarray(uv, dtype=np.float64)
        if not self.has_distortion or uv.size == 0:
            return uv.copy()
        out = cv2.undistortPoints(uv.reshape(-1, 1, 2), self.K, self.dist, None, self.K, criteria=_UNDISTORT_CRITERIA)
        return out.reshape(uv.shape)

    def distort_points(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted pixels to distorted pixels: (..., 2) -> (..., 2)."""
        uv = np.asarray(uv, dtype=np.float64)
        if not self.has_distortion or uv.size == 0:
            return uv.copy()
        ones = np.ones(uv.shape[:-1] + (1,))
        rays = np.concatenate([uv, ones], axis=-1) @ np.linalg.inv(self.K).T
        out, _ = cv2.projectPoints(rays.reshape(-1, 3), np.zeros(3), np.zeros(3), self.K, self.dist)
        return out.reshape(uv.shape)

    def in_view(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether world points are in front, in the calibrated field of view and the image: (..., 3) -> (...,)."""
        cam = self.world_to_camera(points)
        z = cam[..., 2]
        safe_z = np.where(z > 1e-9, z, 1.0)
        r2 = (cam[..., 0] ** 2 + cam[..., 1] ** 2) / safe_z**2
        ok = (z > 1e-9) & (r2 <= self._fov_r2 * 1.05)
        uv = self.project(points)
        inside = np.all((uv >= -margin) & (uv <= np.subtract(self.size, 1) + margin), axis=-1)
        return ok & inside

    def _field_of_view_r2(self) -> float:
        """Largest squared normalised radius of the image border (a distortion-safe FOV bound)."""
        w, h = self.size
        xs, ys = np.linspace(0, w - 1, 9), np.linspace(0, h - 1, 9)
        border = np.array([(x, y) for y in (0, h - 1) for x in xs] + [(x, y) for x in (0, w - 1) for y in ys], float)
        und = self.undistort_points(border)
        # Where strong distortion is not invertible (e.g. Wildtrack's corners) the iterative undistortion
        # lands on a wrong point; keep only border points it maps back onto themselves.
        exact = np.linalg.norm(self.distort_points(und) - border, axis=1) < 0.5
        norm = (und[exact] - self.K[:2, 2]) / np.diag(self.K)[:2]
        return float(np.max(np.sum(norm**2, axis=1))) if len(norm) else float("inf")

    # --- ground plane z = 0 -----------------------------------------------------------------------
    def ground_to_image_homography(self) -> np.ndarray:
        """Homography from ground (X, Y) on z = 0 to undistorted pixels: (3, 3)."""
        H = self.K @ np.column_stack([self.R[:, 0], self.R[:, 1], self.t])
        return H / H[2, 2]

    def image_to_ground_homography(self) -> np.ndarray:
        """Homography from undistorted pixels to ground (X, Y) on z = 0: (3, 3)."""
        try:
            H = np.linalg.inv(self.ground_to_image_homography())
        except np.linalg.LinAlgError:
            raise ValueError(
                f"camera {self.name!r}: its centre lies on the ground plane z = 0, so pixels have no ground point"
            ) from None
        return H / H[2, 2]

    def image_to_ground(self, uv: np.ndarray, undistort: bool = True) -> np.ndarray:
        """Pixels to ground-plane points (m): (..., 2) -> (..., 2); distorted pixels unless undistort=False."""
        uv = self.undistort_points(uv) if undistort else np.asarray(uv, dtype=np.float64)
        return apply_homography(self.image_to_ground_homography(), uv)

    def ground_to_image(self, xy: np.ndarray, distort: bool = True) -> np.ndarray:
        """Ground-plane points (m) to pixels: (..., 2) -> (..., 2); distorted unless distort=False."""
        uv = apply_homography(self.ground_to_image_homography(), xy)
        return self.distort_points(uv) if distort else uv

    def to_dict(self) -> dict:
        """The cameras.json entry of this camera (docs/formats.md)."""
        return {key: getattr(self, key).tolist() for key in ("K", "dist", "R", "t")} | {"size": list(self.size)}


def apply_homography(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Apply a 3x3 homography to 2D points: (..., 2) -> (..., 2)."""
    xy = np.asarray(xy, dtype=np.float64)
    homog = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1) @ np.asarray(H).T
    return homog[..., :2] / homog[..., 2:3]


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix [v]_x: (3,) -> (3, 3)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def fundamental_matrix(camera_a: Camera, camera_b: Camera) -> np.ndarray:
    """F with x_b^T F x_a = 0 for undistorted pixels of the same world point, unit Frobenius norm: (3, 3)."""
    R = camera_b.R @ camera_a.R.T  # camera a frame -> camera b frame
    t = camera_b.t - R @ camera_a.t
    F = np.linalg.inv(camera_b.K).T @ skew(t) @ R @ np.linalg.inv(camera_a.K)
    return F / np.linalg.norm(F)


@dataclass(frozen=True)
class Rig:
    """An ordered set of named cameras; view index v is the position in this order."""

    cameras: tuple[Camera, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "cameras", tuple(self.cameras))
        names = [c.name for c in self.cameras]
        if len(set(names)) != len(names):
            raise ValueError(f"camera names must be unique, got {names}")
        proj = np.stack([c.P for c in self.cameras]) if self.cameras else np.zeros((0, 3, 4))
        object.__setattr__(self, "_proj", proj)  # fixed with the cameras (asked per frame)

    @classmethod
    def from_cameras(cls, cameras: Iterable[Camera]) -> "Rig":
        """A rig of these cameras, in this order."""
        return cls(tuple(cameras))

    @property
    def names(self) -> list[str]:
        """Camera names in view order."""
        return [c.name for c in self.cameras]

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self.cameras)

    def __getitem__(self, key: int | str) -> Camera:
        if isinstance(key, str):
            for cam in self.cameras:
                if cam.name == key:
                    return cam
            raise KeyError(f"no camera named {key!r} in the rig {self.names}")
        return self.cameras[key]

    def projection_matrices(self) -> np.ndarray:
        """Projection matrices of undistorted pixels (a copy: the compiled kernels take writable arrays): (V, 3, 4)."""
        return self._proj.copy()

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points into every view (distorted pixels): (..., 3) -> (V, ..., 2)."""
        return np.stack([c.project(points) for c in self.cameras])

    def undistort(self, poses2d: np.ndarray) -> np.ndarray:
        """Undistort the (x, y) of per-view keypoints, keeping scores: (V, ..., 3) -> (V, ..., 3)."""
        poses2d = np.asarray(poses2d, dtype=np.float64)
        out = poses2d.copy()
        for v, cam in enumerate(self.cameras):
            if cam.has_distortion:
                out[v, ..., :2] = cam.undistort_points(poses2d[v, ..., :2])
        return out

    def to_dict(self) -> dict:
        """The cameras.json content of this rig (docs/formats.md)."""
        return {c.name: c.to_dict() for c in self.cameras}
