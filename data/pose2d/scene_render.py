"""Rendered views of a multi-view 3D crowd: each camera's image of the bodies and its ground-truth 2D."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import partial

import cv2
import numpy as np

from data.geometry.camera import Camera, Rig
from data.image_ids import coco_image_id
from data.keypoints import NUM_JOINTS
from data.multiview import Frame, Sequence, ViewDetections
from data.pose2d import render
from data.pose2d.view_coco import coco_images

# Independent random streams of a scene seed: default_rng([seed, STREAM, ...]).
LOOK, BACKDROP, FLOOR, LIGHT, GRAIN, ORDER = range(6)
FLOOR_MARGIN_M = 10.0  # the floor texture and its tile lines reach this far beyond the persons' area
FLOOR_TEXEL_M = 0.05  # floor texture resolution (coarser when the floor is large)
MAX_TEXTURE_PX = 2048
FLOOR_WEIGHT = 0.7  # floor colour over the backdrop where a pixel sees the ground
UNDISTORT_STEP_PX = 8  # the floor of a distorting lens: exact undistortion every this many pixels, bilinear between
MIN_DEPTH_M = 0.1  # a person with a joint closer to the camera plane than this is not painted


@dataclass(frozen=True)
class Scene:
    """The rig, a seed, and the persons' area (xmin, xmax, ymin, ymax) m around which the floor is laid."""

    rig: Rig
    seed: int
    area: tuple[float, float, float, float]


@dataclass
class RenderedView:
    """One camera's render of P persons: image or None, owner (H, W) by person row, keypoints (P, 23, 3), boxes."""

    image: np.ndarray | None
    owner: np.ndarray
    keypoints: np.ndarray
    boxes: np.ndarray


def render_view(
    scene: Scene, view: int, frame: int, poses: np.ndarray, ids: np.ndarray, paint: bool = True
) -> RenderedView:
    """Render one view of a frame with persons (P, 23, 3) (world, m) of ids (P,); paint=False: labels only."""
    camera = scene.rig[view]
    poses = np.asarray(poses, dtype=np.float64)
    shown = np.flatnonzero([_paintable(camera, joints) for joints in poses])
    light = _light(camera, scene.seed)
    views = [render.view_person(camera, poses[p], light) for p in shown]
    looks = [render.sample_look(np.random.default_rng([int(scene.seed), LOOK, int(ids[p])])) for p in shown]
    image = _background(scene, view) if paint else None
    if image is not None:
        render.draw_shadows(image, camera, poses[shown])
    painted = render.paint_persons(image, views, looks, camera.size)  # numbered by the shown persons
    keypoints, boxes = np.zeros((len(poses), NUM_JOINTS, 3)), np.zeros((len(poses), 4))
    keypoints[shown], boxes[shown] = render.person_labels(camera, poses[shown], views, painted)
    if image is not None:
        grain_rng = np.random.default_rng([int(scene.seed), GRAIN, int(frame), int(view)])
        image = render.finish(image, render.grain_field(grain_rng, camera.size))
    return RenderedView(image, _rows_owner(painted, shown), keypoints, boxes)


def _rows_owner(owner: np.ndarray, shown: np.ndarray) -> np.ndarray:
    """An owner map (H, W) of the shown persons (S,) renumbered by their rows of the input persons."""
    parts = len(render.PART_GROUPS)
    part = owner.astype(np.int64) - 1
    rows = np.append(shown, 0)[np.where(part >= 0, part // parts, len(shown))]
    return np.where(part >= 0, 1 + rows * parts + part % parts, 0).astype(np.uint16)


def _paintable(camera: Camera, joints: np.ndarray) -> bool:
    """Whether a person (23, 3) can be painted: in front of the camera, and inside a distorting lens's view."""
    if np.any(camera.depth(joints) < MIN_DEPTH_M):
        return False
    return not camera.has_distortion or bool(np.all(camera.in_view(joints, margin=float(max(camera.size)))))


def _light(camera: Camera, seed: int) -> np.ndarray:
    """Image direction (2,) of the highlights: the scene's sun seen from the camera, towards the top."""
    rng = np.random.default_rng([int(seed), LIGHT])
    azimuth, elevation = rng.uniform(0, 2 * math.pi), rng.uniform(0.5, 1.2)
    flat = math.cos(elevation)
    x, y, _ = camera.R @ np.array([flat * math.cos(azimuth), flat * math.sin(azimuth), math.sin(elevation)])
    light = np.array([x, -abs(y)])
    norm = float(np.linalg.norm(light))
    return light / norm if norm > 1e-6 else np.array([0.0, -1.0])


def _background(scene: Scene, view: int) -> np.ndarray:
    """The empty scene (H, W, 3) uint8 seen by one camera: its backdrop, the floor and its tile lines."""
    camera = scene.rig[view]
    image = render.backdrop(np.random.default_rng([int(scene.seed), BACKDROP, int(view)]), camera.size)
    rng = np.random.default_rng([int(scene.seed), FLOOR])
    xmin, xmax, ymin, ymax = (float(v) for v in scene.area)
    extent = (xmin - FLOOR_MARGIN_M, xmax + FLOOR_MARGIN_M, ymin - FLOOR_MARGIN_M, ymax + FLOOR_MARGIN_M)
    texel = max(FLOOR_TEXEL_M, (extent[1] - extent[0]) / MAX_TEXTURE_PX, (extent[3] - extent[2]) / MAX_TEXTURE_PX)
    size = (int(math.ceil((extent[1] - extent[0]) / texel)), int(math.ceil((extent[3] - extent[2]) / texel)))
    texture = render.smooth_field(rng, size, int(rng.integers(3, 8)), 40, 200)
    xy, ground = _ground_points(camera)
    maps = np.clip((xy - np.float32([extent[0], extent[2]])) / np.float32(texel), -1e5, 1e5)
    floor = cv2.remap(texture, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    blend = cv2.addWeighted(image, 1.0 - FLOOR_WEIGHT, floor, FLOOR_WEIGHT, 0.0)
    np.copyto(image, blend, where=ground[..., None])
    tile = rng.uniform(0.5, 2.0)  # tile lines at multiples of tile m
    xs = tile * np.arange(math.ceil(extent[0] / tile), math.floor(extent[1] / tile) + 1)
    ys = tile * np.arange(math.ceil(extent[2] / tile), math.floor(extent[3] / tile) + 1)
    lines = np.concatenate(render.grid_lines(xs, ys, extent))
    render.draw_ground_lines(image, camera, lines, render.random_colour(rng))
    return image


def _ground_points(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Ground point (H, W, 2) float32 (x, y on z = 0, m) seen by every pixel, and whether it sees the ground (H, W)."""
    w, h = camera.size
    if camera.has_distortion:
        uv = _undistorted_pixels(camera)
    else:
        uv = np.stack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)), axis=-1)
    ray_z = (camera.R.T @ np.linalg.inv(camera.K))[2]  # world z of a pixel's ray, linear in (u, v, 1)
    above = bool(camera.center[2] > 0)  # a camera below the floor sees none of it
    ground = above & (uv[..., 0] * ray_z[0] + uv[..., 1] * ray_z[1] + ray_z[2] < -1e-9)
    xy = cv2.perspectiveTransform(uv.reshape(-1, 1, 2), camera.image_to_ground_homography()).reshape(h, w, 2)
    return np.nan_to_num(xy, nan=0.0, posinf=1e5, neginf=-1e5), ground


def _undistorted_pixels(camera: Camera) -> np.ndarray:
    """Undistorted position (H, W, 2) float32 of every pixel: exact on a grid of UNDISTORT_STEP_PX, bilinear between."""
    w, h = camera.size
    xs = np.linspace(0, w - 1, int(math.ceil((w - 1) / UNDISTORT_STEP_PX)) + 1)
    ys = np.linspace(0, h - 1, int(math.ceil((h - 1) / UNDISTORT_STEP_PX)) + 1)
    coarse = camera.undistort_points(np.stack(np.meshgrid(xs, ys), axis=-1))  # (ny, nx, 2)
    along_x, along_y = _linear_weights(xs, w), _linear_weights(ys, h)  # (w, nx), (h, ny)
    full = [along_y @ coarse[..., c] @ along_x.T for c in (0, 1)]
    return np.stack(full, axis=-1).astype(np.float32)


def _linear_weights(knots: np.ndarray, n: int) -> np.ndarray:
    """Weights (n, K) of linear interpolation at 0..n-1 between K increasing knots."""
    weights = np.zeros((n, len(knots)))
    at = np.arange(n, dtype=np.float64)
    right = np.clip(np.searchsorted(knots, at, side="right"), 1, len(knots) - 1)
    frac = (at - knots[right - 1]) / (knots[right] - knots[right - 1])
    weights[np.arange(n), right - 1] = 1.0 - frac
    weights[np.arange(n), right] = frac
    return weights


def frame_images(scene: Scene, frame: int, poses: np.ndarray, ids: np.ndarray) -> list[np.ndarray]:
    """Every view's image (H, W, 3) uint8 BGR, rig order, of frame number ``frame`` with persons (P, 23, 3)."""
    return [render_view(scene, v, frame, poses, ids).image for v in range(len(scene.rig))]


def ground_truth_views(scene: Scene, frame: int, poses: np.ndarray, ids: np.ndarray) -> list[ViewDetections]:
    """Per view the ground-truth 2D of the render of persons (P, 23, 3) with ids (P,) (no pixels drawn)."""
    out = []
    for v in range(len(scene.rig)):
        rendered = render_view(scene, v, frame, poses, ids, paint=False)
        order_rng = np.random.default_rng([int(scene.seed), ORDER, int(frame), v])
        out.append(ground_truth_detections(rendered, ids, order_rng))
    return out


def ground_truth_detections(rendered: RenderedView, ids: np.ndarray, rng: np.random.Generator) -> ViewDetections:
    """The painted persons of a render as detections (N, 23, 3), score 1 where labelled, shuffled by rng."""
    v = rendered.keypoints[..., 2]
    kept = np.flatnonzero((rendered.boxes[:, 2] > 0) & np.any(v > 0, axis=1))
    kept = kept[rng.permutation(len(kept))]
    keypoints = rendered.keypoints[kept].copy()
    keypoints[..., 2] = (v[kept] > 0).astype(np.float64)
    return ViewDetections(
        keypoints, rendered.boxes[kept], np.ones(len(kept)), np.asarray(ids, dtype=np.int64)[kept], v[kept] == 1
    )


def render_sequence(sequence: Sequence, seed: int) -> Sequence:
    """A Sequence whose views are the ground truth of the render of gt_poses (P, 23, 4), with lazy images and ids."""
    rig = sequence.rig
    scene = Scene(rig, int(seed), _area(sequence))
    frames, left_out = [], 0
    for frame in sequence.frames:
        poses, ids, missing = _renderable(frame)
        left_out += missing
        views = ground_truth_views(scene, frame.index, poses, ids)
        images = partial(frame_images, scene, frame.index, poses, ids)
        image_ids = [coco_image_id(frame.index, v, len(rig)) for v in range(len(rig))]
        frames.append(replace(frame, views=views, images=images, image_ids=image_ids))
    meta = {**sequence.meta, "render": {"seed": int(seed), "persons_left_out": left_out}}
    return replace(
        sequence, frames=frames, meta=meta, protocols=list(sequence.protocols), coco_images=coco_images(frames, rig)
    )


def _area(sequence: Sequence) -> tuple[float, float, float, float]:
    """The persons' area: the sequence's where the dataset gives it, else the extent of the ground truth."""
    if sequence.area is not None:
        return sequence.area
    points = [f.gt_poses[..., :2].reshape(-1, 2) for f in sequence.frames if f.gt_poses is not None]
    points = np.concatenate(points) if points else np.zeros((0, 2))
    if len(points) == 0:
        return (-1.0, 1.0, -1.0, 1.0)
    lo, hi = points.min(axis=0), points.max(axis=0)
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def _renderable(frame: Frame) -> tuple[np.ndarray, np.ndarray, int]:
    """The joints (P, 23, 3) and ids (P,) of the frame's fully annotated persons, and how many were left out."""
    if frame.gt_poses is None or len(frame.gt_poses) == 0:
        return np.zeros((0, NUM_JOINTS, 3)), np.zeros(0, np.int64), 0
    gt = np.asarray(frame.gt_poses, dtype=np.float64)
    if gt.shape[1:] != (NUM_JOINTS, 4):
        raise ValueError(f"frame {frame.index}: gt_poses {gt.shape}, the renderer needs COCO-23 (P, 23, 4)")
    ids = np.arange(len(gt)) if frame.gt_ids is None else np.asarray(frame.gt_ids, dtype=np.int64)
    full = np.all(gt[..., 3] > 0, axis=1) & np.all(np.isfinite(gt[..., :3]), axis=(1, 2))
    return gt[full, :, :3].copy(), ids[full].copy(), int(np.count_nonzero(~full))
