"""Skeletons drawn over RGB uint8 camera images (H, W, 3), possibly resized by (sx, sy) from the camera size."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from matplotlib import colormaps

from data.geometry.camera import Camera, Rig
from data.keypoints import LIMBS

GT_COLOR = (0, 0, 0)  # ground truth over images: thin black lines
DETECTION_COLOR = (255, 255, 255)  # the 2D detections the 3D came from: thin white lines
CANVAS_GREY = 200  # background where a view has no image
UNMATCHED_COLOR = (0.55, 0.55, 0.55)
_SHIFT = 4  # cv2 sub-pixel bits: coordinates are drawn at 1/16 px


def person_colors(n: int) -> np.ndarray:
    """n distinct colours, the same for person p in every picture -> (n, 3) RGB in [0, 1], no grey."""
    tab10 = np.asarray(colormaps["tab10"].colors, dtype=np.float64)
    light = np.asarray(colormaps["tab20"].colors, dtype=np.float64)[1::2]
    palette = np.concatenate([np.delete(tab10, 7, axis=0), np.delete(light, 7, axis=0)])
    if n <= len(palette):
        return palette[:n].copy()
    hues = (np.arange(n) * 0.618033988749895) % 1.0
    hsv = np.stack([hues * 179, np.full(n, 220), np.where(np.arange(n) % 2, 255, 190)], axis=1)
    return cv2.cvtColor(hsv.astype(np.uint8)[None], cv2.COLOR_HSV2RGB)[0] / 255.0


def _rgb255(color: np.ndarray | tuple) -> tuple[int, int, int]:
    """RGB floats in [0, 1] -> an int tuple for cv2 (the array stays RGB)."""
    return tuple(int(round(255 * c)) for c in color)


def project_skeleton(
    camera: Camera, pose: np.ndarray, scale: tuple[float, float] = (1.0, 1.0)
) -> tuple[np.ndarray, np.ndarray]:
    """One 3D pose (J, 4) into a (resized) image -> pixels (J, 2), drawable (J,) (in the field of view)."""
    pose = np.asarray(pose, dtype=np.float64)
    xyz = np.where(np.isfinite(pose[:, :3]), pose[:, :3], 0.0)
    ok = (pose[:, 3] > 0) & np.isfinite(pose).all(axis=1)
    ok &= camera.in_view(xyz, margin=float(max(camera.size)))
    return np.where(ok[:, None], camera.project(xyz) * np.asarray(scale, dtype=np.float64), 0.0), ok


def _fixed(uv: np.ndarray) -> tuple[int, int]:
    """A pixel as cv2 fixed-point coordinates."""
    return int(round(uv[0] * (1 << _SHIFT))), int(round(uv[1] * (1 << _SHIFT)))


def draw_skeleton(image: np.ndarray, uv: np.ndarray, ok: np.ndarray, color: tuple, thickness: int, radius: int) -> None:
    """Draw the limbs and joint dots of one 2D skeleton in place: image (H, W, 3), uv (J, 2), ok (J,)."""
    for a, b in LIMBS:
        if ok[a] and ok[b]:
            cv2.line(image, _fixed(uv[a]), _fixed(uv[b]), color, thickness, cv2.LINE_AA, _SHIFT)
    for j in np.flatnonzero(ok):
        if radius > 0:
            cv2.circle(image, _fixed(uv[j]), radius << _SHIFT, color, -1, cv2.LINE_AA, _SHIFT)


def _canvas(image: np.ndarray | None, camera: Camera) -> np.ndarray:
    """A drawable RGB copy of the image, or a grey canvas of the camera size: (H, W, 3) uint8."""
    if image is None:
        w, h = camera.size
        return np.full((h, w, 3), CANVAS_GREY, dtype=np.uint8)
    image = np.asarray(image)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    return np.ascontiguousarray(image[..., :3], dtype=np.uint8).copy()


def draw_reprojections(
    images: list[np.ndarray | None],
    rig: Rig,
    poses3d: np.ndarray,
    image_scale: list[tuple[float, float]] | None = None,
    gt_poses: np.ndarray | None = None,
    detections: list[np.ndarray] | None = None,
) -> list[np.ndarray]:
    """3D poses (P, J, 4) reprojected (with distortion) over V images -> V RGB (H, W, 3); GT (G, J, 4) in thin black,
    each view's 2D detections (N, J, 3) in thin white."""
    poses3d = np.asarray(poses3d, dtype=np.float64)
    colors = [_rgb255(c) for c in person_colors(len(poses3d))]
    scales = image_scale if image_scale is not None else [(1.0, 1.0)] * len(rig)
    if len(images) != len(rig) or len(scales) != len(rig):
        raise ValueError(f"{len(images)} images and {len(scales)} scales for a rig of {len(rig)} cameras")
    out = []
    for v, (camera, image, scale) in enumerate(zip(rig, images, scales)):
        canvas = _canvas(image, camera)
        size = min(canvas.shape[:2])
        thick, radius = max(1, round(size / 300)), max(2, round(size / 200))
        for pose in () if detections is None else np.asarray(detections[v], dtype=np.float64):
            uv = pose[:, :2] * np.asarray(scale)
            draw_skeleton(
                canvas, uv, (pose[:, 2] > 0) & np.isfinite(uv).all(axis=1), DETECTION_COLOR, max(1, thick // 2), 1
            )
        for pose in () if gt_poses is None else np.asarray(gt_poses, dtype=np.float64):
            draw_skeleton(canvas, *project_skeleton(camera, pose, scale), GT_COLOR, max(1, thick // 2), 0)
        for pose, color in zip(poses3d, colors):
            draw_skeleton(canvas, *project_skeleton(camera, pose, scale), color, thick, radius)
        out.append(canvas)
    return out


def image_grid(images: list[np.ndarray], labels: list[str] | None = None, tile_width: int = 960) -> np.ndarray:
    """Images side by side on a near-square grid, each resized to ``tile_width``: -> (H, W, 3) uint8."""
    if not images:
        raise ValueError("image_grid needs at least one image")
    cols = math.ceil(math.sqrt(len(images)))
    rows = math.ceil(len(images) / cols)
    tile_h = max(round(tile_width * im.shape[0] / im.shape[1]) for im in images)
    grid = np.full((rows * tile_h, cols * tile_width, 3), 255, dtype=np.uint8)
    for i, im in enumerate(images):
        h = round(tile_width * im.shape[0] / im.shape[1])
        tile = cv2.resize(np.asarray(im, dtype=np.uint8), (tile_width, h), interpolation=cv2.INTER_AREA)
        r, c = divmod(i, cols)
        grid[r * tile_h : r * tile_h + h, c * tile_width : (c + 1) * tile_width] = tile
        if labels is not None:  # white outline, then black text: readable on any image
            for colour, thickness in (((255, 255, 255), 4), ((0, 0, 0), 2)):
                origin = (c * tile_width + 10, r * tile_h + 34)
                cv2.putText(grid, labels[i], origin, cv2.FONT_HERSHEY_SIMPLEX, 1.0, colour, thickness, cv2.LINE_AA)
    return grid


def load_view_images(
    folder: str | Path, rig: Rig, pattern: str = "cam{i}.png"
) -> tuple[list[np.ndarray | None], list[tuple[float, float]]]:
    """One RGB image per camera (pattern with i, name) -> images, scales (V, 2) image / camera size."""
    images, scales = [], []
    for i, camera in enumerate(rig):
        path = Path(folder) / pattern.format(i=i, name=camera.name)
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
        if bgr is None:
            images.append(None)
            scales.append((1.0, 1.0))
            continue
        images.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
        scales.append((bgr.shape[1] / camera.size[0], bgr.shape[0] / camera.size[1]))
    return images, scales
