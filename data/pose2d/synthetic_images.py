"""Synthetic crowded images with COCO-23 keypoints for training the 2D model on a CPU."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
from tqdm import tqdm

from data.geometry.camera import Camera
from data.keypoints import LIMBS, NUM_JOINTS
from data.pose2d import render
from data.pose2d.coco_keypoints import load_coco23, write_coco_keypoints
from data.pose2d.records import ImageRecord
from data.synthetic.body import pose_joints, sample_body
from data.synthetic.rigs import look_at_camera

STATURE_M = 1.7  # stature used to turn the wanted pixel height into a depth
MIN_SPACING_M = 0.5


@dataclass(frozen=True)
class ImageOptions:
    """Image size (w, h), persons (min, max), height_px (min, max) at 1.7 m (None: H/6..5H/8), JPEG quality."""

    size: tuple[int, int] = (640, 480)
    persons: tuple[int, int] = (4, 12)
    height_px: tuple[float, float] | None = None
    jpeg_quality: int = 92

    def __post_init__(self) -> None:
        if self.height_px is None:
            object.__setattr__(self, "height_px", (self.size[1] / 6, self.size[1] * 5 / 8))
        checks = (
            ("size", min(self.size) >= 32, "must be at least 32 x 32 pixels"),
            (
                "persons",
                1 <= self.persons[0] <= self.persons[1] <= render.MAX_PERSONS,
                f"must be (min, max), 1 <= min <= max <= {render.MAX_PERSONS}",
            ),
            ("height_px", 0 < self.height_px[0] <= self.height_px[1], "must be (min, max), 0 < min <= max"),
            ("jpeg_quality", 1 <= self.jpeg_quality <= 100, "must be in 1..100"),
        )
        for key, ok, what in checks:
            if not ok:
                raise ValueError(f"synthetic image option {key}={getattr(self, key)!r} {what}")


@dataclass
class SyntheticImage:
    """Image (H, W, 3) uint8 BGR, keypoints (N, 23, 3) x, y, v, boxes (N, 4) xywh, background or None."""

    image: np.ndarray
    keypoints: np.ndarray
    boxes: np.ndarray
    background: np.ndarray | None = None


def sample_camera(rng: np.random.Generator, size: tuple[int, int]) -> Camera:
    """A low camera at (0, 0, h) looking along +x, focal 0.75..1.1 x width: people hide each other."""
    focal = rng.uniform(0.75, 1.1) * size[0]
    height = rng.uniform(0.8, 2.4)
    target = (rng.uniform(5.0, 9.0), rng.uniform(-0.3, 0.3), rng.uniform(0.7, 1.2))
    return look_at_camera("synthetic", (0.0, 0.0, height), target, size, focal)


def _vary_arm(joints: np.ndarray, shoulder: int, elbow: int, wrist: int, rng: np.random.Generator) -> None:
    """Rotate one arm about its shoulder and bend it at the elbow, in place on a (23, 3) array."""
    swing = _rotation(rng.normal(size=3), rng.uniform(0.3, 2.0))
    s = joints[shoulder]
    joints[[elbow, wrist]] = (joints[[elbow, wrist]] - s) @ swing.T + s
    bend = _rotation(rng.normal(size=3), rng.uniform(0.0, 1.6))
    joints[wrist] = (joints[wrist] - joints[elbow]) @ bend.T + joints[elbow]


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) about an axis (3,) by an angle (rad), Rodrigues' formula."""
    k = axis / max(np.linalg.norm(axis), 1e-12)
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * cross + (1 - math.cos(angle)) * cross @ cross


def sample_crowd(rng: np.random.Generator, camera: Camera, options: ImageOptions) -> np.ndarray:
    """World COCO-23 joints (P, 23, 3) of a crowd in a wedge of the camera's view, >= 0.5 m apart."""
    focal = camera.K[0, 0]
    half_fov = math.atan(camera.size[0] / 2 / focal)
    spread = rng.uniform(0.3, 1.1) * half_fov
    count = int(rng.integers(options.persons[0], options.persons[1] + 1))
    ground: list[np.ndarray] = []
    for _ in range(50 * count):
        if len(ground) == count:
            break
        depth = focal * STATURE_M / rng.uniform(*options.height_px)
        angle = rng.uniform(-spread, spread)
        point = depth * np.array([math.cos(angle), math.sin(angle)])
        if all(np.hypot(*(point - g)) >= MIN_SPACING_M for g in ground):
            ground.append(point)
    poses = np.zeros((len(ground), NUM_JOINTS, 3))
    for p, (x, y) in enumerate(ground):
        joints = pose_joints(
            sample_body(rng), x, y, rng.uniform(0, 2 * math.pi), rng.uniform(), bool(rng.random() < 0.5)
        )
        for arm in ((5, 7, 9), (6, 8, 10)):
            if rng.random() < 0.6:
                _vary_arm(joints, *arm, rng)
        poses[p] = joints
    return poses


def render_background(rng: np.random.Generator, camera: Camera) -> np.ndarray:
    """A textured background (H, W, 3) uint8: a backdrop, and a floor with tile lines below the horizon."""
    w, h = camera.size
    image = render.backdrop(rng, (w, h))
    horizon = int(np.clip(camera.project(np.array([1e4, 0.0, 0.0]))[1], 0, h))
    if horizon < h:
        floor = render.smooth_field(rng, (w, h - horizon), 3, 40, 200)
        image[horizon:] = cv2.addWeighted(image[horizon:], 0.3, floor, 0.7, 0.0)
        tile, colour = rng.uniform(0.4, 2.0), render.random_colour(rng)
        extent = (1.0, 30.0, -30.0, 30.0)  # tile lines 1..30 m ahead, 30 m to either side
        along_y, along_x = render.grid_lines(np.arange(*extent[:2], tile), np.arange(*extent[2:], tile), extent)
        render.draw_ground_lines(image, camera, np.concatenate([along_x, along_y]), colour)
    return image


def synthetic_image(
    rng: np.random.Generator, options: ImageOptions = ImageOptions(), with_background: bool = False
) -> SyntheticImage:
    """Render one crowded image and its labels; persons with no painted pixel or no joint in view are left out."""
    camera = sample_camera(rng, options.size)
    poses = sample_crowd(rng, camera, options)
    background = render_background(rng, camera)
    image = background.copy()
    render.draw_shadows(image, camera, poses)
    light = rng.normal(size=2) * [1.0, 0.5]
    light[1] = -abs(light[1])  # highlights towards the top
    light /= max(float(np.linalg.norm(light)), 1e-9)
    views = [render.view_person(camera, joints, light) for joints in poses]
    looks: list = [None] * len(views)
    for p in render.painting_order(views):  # drawn in painting order: the stream of the earlier generator
        looks[p] = render.sample_look(rng)
    owner = render.paint_persons(image, views, looks, options.size)
    keypoints, boxes = render.person_labels(camera, poses, views, owner)
    keypoints[..., :2] = np.round(keypoints[..., :2], 2)
    keep = (boxes[:, 2] > 0) & np.any(keypoints[..., 2] > 0, axis=1)
    grain = render.grain_field(rng, options.size)
    empty = render.finish(background, grain) if with_background else None
    return SyntheticImage(render.finish(image, grain), keypoints[keep], boxes[keep], empty)


def image_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of image `index` of a dataset with this seed (independent of the image count)."""
    return np.random.default_rng([int(seed), int(index)])


def generate_dataset(
    out_dir: str | Path, num_images: int, seed: int, options: ImageOptions = ImageOptions(), progress: bool = True
) -> Path:
    """Write out_dir/images/NNNNNN.jpg and out_dir/annotations.json (COCO-23); returns the annotation path."""
    out_dir = Path(out_dir)
    image_dir = out_dir / "images"
    image_dir.mkdir(parents=True, exist_ok=True)
    w, h = options.size
    records = []
    for i in tqdm(range(num_images), desc="synthetic images", unit="img", disable=not progress):
        sample = synthetic_image(image_rng(seed, i), options)
        path = image_dir / f"{i:06d}.jpg"
        if not cv2.imwrite(str(path), sample.image, [cv2.IMWRITE_JPEG_QUALITY, options.jpeg_quality]):
            raise ValueError(f"{path}: cannot write the image")
        boxes = sample.boxes
        records.append(ImageRecord(i + 1, path, w, h, sample.keypoints, boxes, boxes[:, 2] * boxes[:, 3]))
    ann_path = out_dir / "annotations.json"
    info = {"description": "synthetic crowded images (data.pose2d.synthetic_images)", "seed": int(seed)}
    info |= {"num_images": int(num_images), "size": [w, h]}
    write_coco_keypoints(ann_path, records, image_root=image_dir, info=info)
    return ann_path


def draw_annotations(image: np.ndarray, keypoints: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """A copy of image (H, W, 3) with boxes (N, 4), limbs and joints (N, 23, 3): green seen, red hidden."""
    out = image.copy()
    for kps, box in zip(keypoints, boxes):
        x, y, bw, bh = (int(round(v)) for v in box)
        cv2.rectangle(out, (x, y), (x + bw, y + bh), (255, 200, 0), 1)
        for a, b in LIMBS:
            if kps[a, 2] > 0 and kps[b, 2] > 0:
                cv2.line(out, render.ipt(kps[a, :2]), render.ipt(kps[b, :2]), (0, 255, 255), 1, cv2.LINE_AA)
        for x, y, v in kps:
            if v > 0:
                colour, thickness = ((0, 220, 0), -1) if v >= 2 else ((0, 0, 255), 1)  # seen: filled green
                cv2.circle(out, render.ipt(np.array([x, y])), 3, colour, thickness, cv2.LINE_AA)
    return out


def save_preview(
    out_png: str | Path, ann_file: str | Path, image_dir: str | Path, count: int = 6, columns: int = 3
) -> Path:
    """Save a PNG grid of the first `count` images of a COCO-23 file with their labels drawn."""
    records = load_coco23(ann_file, image_dir)[:count]
    if not records:
        raise ValueError(f"{ann_file}: no images to preview")
    tiles = []
    for record in records:
        image = cv2.imread(str(record.file))
        if image is None:
            raise ValueError(f"{record.file}: cannot read the image of image id {record.image_id}")
        tiles.append(draw_annotations(image, record.keypoints, record.boxes))
    h, w = tiles[0].shape[:2]
    tiles = [cv2.resize(t, (w, h)) for t in tiles]
    tiles += [np.zeros_like(tiles[0])] * (-len(tiles) % columns)
    grid = np.vstack([np.hstack(tiles[r : r + columns]) for r in range(0, len(tiles), columns)])
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out_png), grid):
        raise ValueError(f"{out_png}: cannot write the preview")
    return out_png


def parse_size(text: str) -> tuple[int, int]:
    """'640x480' -> (640, 480)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size {text!r} must look like 640x480") from None
    return w, h


def main(argv: Sequence[str] | None = None) -> None:
    """Command line: generate a dataset, optionally save a preview grid."""
    parser = argparse.ArgumentParser(prog="python -m data.pose2d.synthetic_images", description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="output folder")
    parser.add_argument("--num-images", required=True, type=int)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", type=parse_size, default=(640, 480), help="WIDTHxHEIGHT (default 640x480)")
    parser.add_argument("--persons", type=int, nargs=2, default=(4, 12), metavar=("MIN", "MAX"))
    what = "person height range in pixels (default: 1/6 to 5/8 of the image height)"
    parser.add_argument("--height-px", type=float, nargs=2, metavar=("MIN", "MAX"), help=what)
    parser.add_argument("--preview", type=Path, help="also save a PNG grid of the first 6 images here")
    args = parser.parse_args(argv)
    if args.num_images < 1:
        parser.error("--num-images must be >= 1")
    try:
        options = ImageOptions(
            size=args.size, persons=tuple(args.persons), height_px=tuple(args.height_px) if args.height_px else None
        )
    except ValueError as exc:
        parser.error(str(exc))
    ann = generate_dataset(args.out, args.num_images, args.seed, options)
    print(f"wrote {args.num_images} images and {ann}")
    if args.preview:
        print(f"preview: {save_preview(args.preview, ann, args.out / 'images')}")


if __name__ == "__main__":
    main()
