"""Camera rigs for synthetic scenes: a ring of cameras around the area."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from data.geometry.camera import Camera, Rig


def look_at_camera(
    name: str, center: Sequence[float], target: Sequence[float], image_size: tuple[int, int], focal_px: float
) -> Camera:
    """A distortion-free camera at center (3,) looking at target (3,), image x right and y down."""
    center = np.asarray(center, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - center
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        raise ValueError(f"camera {name!r}: the look-at target coincides with the camera centre")
    forward = forward / norm
    right = np.cross(forward, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-6:
        raise ValueError(f"camera {name!r}: looking straight up or down, the image axes are undefined")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    w, h = (int(s) for s in image_size)
    K = np.array([[focal_px, 0.0, w / 2], [0.0, focal_px, h / 2], [0.0, 0.0, 1.0]])
    return Camera(name, K, np.zeros(5), R, -R @ center, (w, h))


def ring_rig(
    num_cameras: int,
    radius: float,
    height: float,
    look_at: Sequence[float] = (0.0, 0.0, 1.0),
    image_size: tuple[int, int] = (1280, 720),
    focal_px: float = 1000.0,
) -> Rig:
    """Cameras "0".."V-1" evenly spaced on a circle of this radius around look_at (3,), at this height."""
    cx, cy, _ = (float(v) for v in look_at)
    cams = []
    for v in range(int(num_cameras)):
        a = 2 * math.pi * v / num_cameras
        center = (cx + radius * math.cos(a), cy + radius * math.sin(a), height)
        cams.append(look_at_camera(str(v), center, look_at, image_size, focal_px))
    return Rig.from_cameras(cams)
