"""Synthetic crowded images with COCO-23 keypoints, for training the 2D model on a CPU.

Each image shows a crowd from :mod:`data.synthetic` (bodies with COCO-23 joints) seen by one low
camera, so that people hide each other. Bodies are the capsules of :mod:`data.synthetic.capsules`,
projected as tapered capsules, shaded in three layers and painted far to near (persons, then their
parts) over a random textured background. A joint is labelled v = 2 when the painted pixel under it
belongs to a body part of its own person that carries it and no other body is in the way (the capsule
occlusion test), v = 1 when it is hidden (by another person, or by its own body or head), and
v = 0 (x = y = 0) outside the image. The box is that of the person's painted pixels, area = w * h.

CLI: ``python -m data.pose2d.synthetic_images --out DIR --num-images N --seed S [--size 640x480]`` writes
``DIR/images/NNNNNN.jpg`` and ``DIR/annotations.json``; read them with
``data.pose2d.coco_keypoints.load_coco23(DIR / "annotations.json", DIR / "images")``.
"""

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
from data.pose2d.coco_keypoints import load_coco23, write_coco_keypoints
from data.pose2d.records import ImageRecord
from data.synthetic.body import pose_joints, sample_body
from data.synthetic.capsules import HEAD_RADIUS_M, body_capsules, capsule_radii, occluded_joints
from data.synthetic.rigs import look_at_camera

# Part groups that get one clothing colour per person.
SHIRT, SLEEVE, TROUSERS, SHIN, SHOES, SKIN, HAIR = range(7)
SKIN_TONES = np.array([(185, 205, 240), (150, 180, 225), (110, 150, 205), (80, 115, 170), (50, 75, 120)], float)
HAIR_TONES = np.array([(20, 20, 25), (30, 45, 70), (40, 80, 130), (120, 170, 210), (140, 140, 140)], float)
SHADE_LAYERS = ((1.0, 0.0, 0.62), (0.78, 0.10, 0.84), (0.45, 0.30, 1.0))  # (radius, light shift, brightness)
FACE_VISIBLE_COS = -0.2  # a face joint is seen while cos(joint - head centre, camera - head centre) >= this
STATURE_M = 1.7  # stature used to turn the wanted pixel height into a depth
MIN_SPACING_M = 0.5
HAIR_BACK_M, HAIR_UP_M, HAIR_RADIUS_M = 0.03, 0.015, 0.095
SUBPIXEL_SHIFT = 3  # fixed-point bits of the polygon coordinates
MAX_PERSONS = 1000  # the uint16 part-owner map holds persons x 28 parts

_HEAD = len(LIMBS) + 1  # index of the head sphere in body_capsules
_HAIR = len(LIMBS) + 2  # the hair sphere, appended after the capsules


@dataclass(frozen=True)
class ImageOptions:
    """Options of the synthetic images: size (w, h) px, persons (min, max) per image, person
    height_px (min, max) for a stature of 1.7 m (None: 1/6 to 5/8 of the image height, 80-300 px at
    480), JPEG quality."""

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
                1 <= self.persons[0] <= self.persons[1] <= MAX_PERSONS,
                f"must be (min, max), 1 <= min <= max <= {MAX_PERSONS}",
            ),
            ("height_px", 0 < self.height_px[0] <= self.height_px[1], "must be (min, max), 0 < min <= max"),
            ("jpeg_quality", 1 <= self.jpeg_quality <= 100, "must be in 1..100"),
        )
        for key, ok, what in checks:
            if not ok:
                raise ValueError(f"synthetic image option {key}={getattr(self, key)!r} {what}")


@dataclass
class SyntheticImage:
    """One rendered image (H, W, 3) uint8 BGR, its keypoints (N, 23, 3) x, y, v and boxes (N, 4) x, y, w, h.

    background (H, W, 3) uint8 is the same image with no person drawn, when asked for (else None).
    """

    image: np.ndarray
    keypoints: np.ndarray
    boxes: np.ndarray
    background: np.ndarray | None = None


# --- scene ------------------------------------------------------------------------------------------


def _part_groups() -> np.ndarray:
    """Colour group (K,) of every capsule of body_capsules, then the hair; -1: face segments, not drawn."""
    groups = []
    for a, b in LIMBS:
        lo, hi = min(a, b), max(a, b)
        if hi >= 17:
            groups.append(SHOES)
        elif hi <= 4:
            groups.append(-1)
        elif lo <= 4:
            groups.append(SKIN)  # neck sides
        elif (lo, hi) in ((13, 15), (14, 16)):
            groups.append(SHIN)
        elif lo >= 11:
            groups.append(TROUSERS)  # thighs, pelvis
        elif (lo, hi) in ((7, 9), (8, 10)):
            groups.append(SLEEVE)
        else:
            groups.append(SHIRT)  # flanks, shoulders, upper arms
    return np.array(groups + [SHIRT, SKIN, HAIR])


def _owns(groups: np.ndarray) -> np.ndarray:
    """Which joints each drawn part of (K,) groups carries: (K, 23) bool.

    A limb capsule carries its two ends, the torso its corners, the head the face, the hair the ears.
    """
    owned = [(a, b) for a, b in LIMBS] + [(5, 6, 11, 12), (0, 1, 2, 3, 4), (3, 4)]
    owns = np.zeros((len(groups), NUM_JOINTS), dtype=bool)
    for k, joints in enumerate(owned):
        owns[k, list(joints)] = True
    return owns


PART_GROUPS = _part_groups()
OWNS = _owns(PART_GROUPS)
PART_GROUPS.flags.writeable = False
OWNS.flags.writeable = False


def sample_camera(rng: np.random.Generator, size: tuple[int, int]) -> Camera:
    """A low camera at (0, 0, h) looking along +x, focal 0.75..1.1 x width: people hide each other."""
    w, _ = size
    focal = rng.uniform(0.75, 1.1) * w
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
    w, _ = camera.size
    focal = camera.K[0, 0]
    half_fov = math.atan(w / 2 / focal)
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


# --- background -------------------------------------------------------------------------------------


def _smooth_field(rng: np.random.Generator, size: tuple[int, int], cells: int, low: float, high: float) -> np.ndarray:
    """A smooth random colour field (H, W, 3) uint8, upsampled from a coarse grid (cubic, then linear)."""
    w, h = size
    coarse = rng.uniform(low, high, (cells, cells + 1, 3)).astype(np.float32)
    middle = cv2.resize(coarse, (max(w // 8, 1), max(h // 8, 1)), interpolation=cv2.INTER_CUBIC)
    return cv2.resize(np.clip(middle, 0, 255).astype(np.uint8), (w, h), interpolation=cv2.INTER_LINEAR)


def render_background(rng: np.random.Generator, camera: Camera) -> np.ndarray:
    """A textured background (H, W, 3) uint8: smooth colours, stripes, blobs, a tiled floor below the horizon."""
    w, h = camera.size
    image = _smooth_field(rng, (w, h), int(rng.integers(2, 7)), 30, 230)
    for _ in range(int(rng.integers(0, 8))):  # stripes and bars
        p0 = rng.uniform([-w, -h], [2 * w, 2 * h])
        p1 = p0 + rng.normal(0, w, 2)
        cv2.line(image, _ipt(p0), _ipt(p1), _colour(rng), int(rng.integers(2, 40)), cv2.LINE_AA)
    for _ in range(int(rng.integers(3, 20))):  # blobs
        axes = (int(rng.integers(4, w // 6)), int(rng.integers(4, h // 6)))
        cv2.ellipse(
            image,
            _ipt(rng.uniform([0, 0], [w, h])),
            axes,
            float(rng.uniform(0, 180)),
            0,
            360,
            _colour(rng),
            -1,
            cv2.LINE_AA,
        )
    horizon = int(np.clip(camera.project(np.array([1e4, 0.0, 0.0]))[1], 0, h))
    if horizon < h:
        floor = _smooth_field(rng, (w, h - horizon), 3, 40, 200)
        image[horizon:] = cv2.addWeighted(image[horizon:], 0.3, floor, 0.7, 0.0)
        _draw_floor_grid(image, camera, rng)
    return image


def _draw_floor_grid(image: np.ndarray, camera: Camera, rng: np.random.Generator) -> None:
    """Tile lines of the ground plane z = 0 in perspective, 1..30 m ahead, in place on (H, W, 3)."""
    tile = rng.uniform(0.4, 2.0)
    colour = _colour(rng)
    near, far, side = 1.0, 30.0, 30.0
    ys = np.arange(-side, side, tile)
    xs = np.arange(near, far, tile)
    ends = np.concatenate(
        [
            np.stack([np.stack([np.full_like(ys, near), ys], 1), np.stack([np.full_like(ys, far), ys], 1)], 1),
            np.stack([np.stack([xs, np.full_like(xs, -side)], 1), np.stack([xs, np.full_like(xs, side)], 1)], 1),
        ]
    )
    uv = np.round(np.clip(camera.project(np.concatenate([ends, np.zeros(ends.shape[:2] + (1,))], -1)), -1e5, 1e5))
    for (u0, v0), (u1, v1) in uv.astype(np.int64).tolist():
        cv2.line(image, (u0, v0), (u1, v1), colour, 1, cv2.LINE_AA)


def _colour(rng: np.random.Generator) -> tuple[float, float, float]:
    """A random BGR colour."""
    return tuple(float(c) for c in rng.uniform(0, 255, 3))


def _ipt(p: np.ndarray) -> tuple[int, int]:
    """An integer pixel point of a (2,) array, clamped to a range cv2 accepts."""
    q = np.clip(np.round(p), -1e5, 1e5)
    return int(q[0]), int(q[1])


# --- bodies -----------------------------------------------------------------------------------------


def _person_colours(rng: np.random.Generator) -> np.ndarray:
    """BGR colour (7, 3) of each part group of one person: shirt, sleeve, trousers, shin, shoes, skin, hair."""
    skin = SKIN_TONES[rng.integers(len(SKIN_TONES))] * rng.uniform(0.9, 1.1)
    shirt = rng.uniform(20, 240, 3)
    trousers = rng.uniform(15, 200, 3)
    sleeve = shirt if rng.random() < 0.6 else skin
    shin = trousers if rng.random() < 0.8 else skin
    shoes = rng.uniform(10, 120, 3)
    hair = HAIR_TONES[rng.integers(len(HAIR_TONES))] * rng.uniform(0.8, 1.2)
    return np.clip(np.array([shirt, sleeve, trousers, shin, shoes, skin, hair]), 0, 255)


def capsule_outlines(a: np.ndarray, b: np.ndarray, ra: np.ndarray, rb: np.ndarray, n: int = 7) -> np.ndarray:
    """Outlines of tapered 2D capsules from a (..., 2) radius ra (...) to b (..., 2) radius rb: (..., 2n, 2).

    A point capsule (a = b) is a circle.
    """
    d = b - a
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    unit = np.where(length > 1e-6, d / np.maximum(length, 1e-6), [1.0, 0.0])
    perp = np.stack([-unit[..., 1], unit[..., 0]], axis=-1)
    t = np.linspace(-math.pi / 2, math.pi / 2, n)[:, None]
    front = np.cos(t) * unit[..., None, :] + np.sin(t) * perp[..., None, :]  # (..., n, 2)
    return np.concatenate(
        [b[..., None, :] + rb[..., None, None] * front, a[..., None, :] - ra[..., None, None] * front], axis=-2
    )


def _fixed(points: np.ndarray) -> np.ndarray:
    """Pixel coordinates (..., 2) as int32 fixed point with SUBPIXEL_SHIFT fractional bits."""
    return np.round(np.clip(points, -1e5, 1e5) * (1 << SUBPIXEL_SHIFT)).astype(np.int32)


@dataclass
class _PersonView:
    """One person as the camera sees it: shading layer outlines (K, L, 2n, 2) fixed point, part depths
    (K,), joint pixels uv (23, 2), face joints seen (23,), facing the camera, eye dot radius (px)."""

    outlines: np.ndarray
    depth: np.ndarray
    uv: np.ndarray
    face_seen: np.ndarray
    facing: bool
    dot_px: float
    person_depth: float


def _view_person(camera: Camera, joints: np.ndarray, light: np.ndarray) -> _PersonView:
    """Project one person's (23, 3) capsules plus a hair sphere, and its joints, into the camera."""
    ends_a, ends_b = (e[0] for e in body_capsules(joints[None]))
    head = ends_a[_HEAD]
    to_cam = camera.center - head
    forward = joints[0] - head
    forward[2] = 0.0
    forward /= max(np.linalg.norm(forward), 1e-9)
    hair = head - HAIR_BACK_M * forward + np.array([0.0, 0.0, HAIR_UP_M])
    ends_a, ends_b = np.vstack([ends_a, hair]), np.vstack([ends_b, hair])
    radii = np.append(capsule_radii(), HAIR_RADIUS_M)
    focal = camera.K[0, 0]
    da, db = camera.depth(ends_a), camera.depth(ends_b)
    ra, rb = np.maximum(focal * radii / da, 1.0), np.maximum(focal * radii / db, 1.0)
    scale = np.array([f for f, _, _ in SHADE_LAYERS])
    shift = np.array([s for _, s, _ in SHADE_LAYERS])[None, :, None] * np.maximum(ra, rb)[:, None, None] * light
    outlines = capsule_outlines(
        camera.project(ends_a)[:, None] + shift,
        camera.project(ends_b)[:, None] + shift,
        ra[:, None] * scale,
        rb[:, None] * scale,
    )
    rel = joints - head
    cos = rel @ to_cam / np.maximum(np.linalg.norm(rel, axis=1) * np.linalg.norm(to_cam), 1e-12)
    face_seen = np.ones(NUM_JOINTS, dtype=bool)
    face_seen[:5] = cos[:5] >= FACE_VISIBLE_COS
    return _PersonView(
        _fixed(outlines),
        (da + db) / 2,
        camera.project(joints),
        face_seen,
        bool(forward @ to_cam > 0),
        max(0.12 * focal * HEAD_RADIUS_M / da[_HEAD], 0.8),
        float(np.mean(camera.depth(joints))),
    )


def _draw_person(
    image: np.ndarray,
    owner: np.ndarray,
    view: _PersonView,
    colours: np.ndarray,
    first_id: int,
    rng: np.random.Generator,
) -> None:
    """Paint one person's parts far to near in place; the owner map gets first_id + part index."""
    groups = PART_GROUPS
    bright = np.array([b for _, _, b in SHADE_LAYERS])
    tint = rng.uniform(0.92, 1.08, len(groups))
    layer_colours = np.clip(colours[groups][:, None] * tint[:, None, None] * bright[None, :, None], 0, 255).tolist()
    for k in np.argsort(-view.depth, kind="stable"):
        if groups[k] < 0:
            continue
        cv2.fillConvexPoly(owner, view.outlines[k, 0], int(first_id + k), cv2.LINE_8, SUBPIXEL_SHIFT)
        for layer, colour in enumerate(layer_colours[k]):
            cv2.fillConvexPoly(image, view.outlines[k, layer], colour, cv2.LINE_AA, SUBPIXEL_SHIFT)
        if k == _HEAD and view.facing:
            _draw_face(image, view, colours[SKIN])


def _draw_face(image: np.ndarray, view: _PersonView, skin: np.ndarray) -> None:
    """Eyes and nose dots on a head that faces the camera, in place."""
    for j, colour, size in ((1, (30, 30, 30), 1.0), (2, (30, 30, 30), 1.0), (0, (skin * 0.7).tolist(), 1.4)):
        if view.face_seen[j]:
            centre = _fixed(view.uv[j])
            cv2.circle(
                image,
                (int(centre[0]), int(centre[1])),
                int(round(view.dot_px * size * (1 << SUBPIXEL_SHIFT))),
                colour,
                -1,
                cv2.LINE_AA,
                SUBPIXEL_SHIFT,
            )


def _draw_shadows(image: np.ndarray, camera: Camera, poses: np.ndarray) -> None:
    """Darken the ground under every person (P, 23, 3), a disc of 0.3 m radius, in place."""
    t = np.linspace(0, 2 * math.pi, 16, endpoint=False)
    mask = np.zeros(image.shape[:2], np.uint8)
    for joints in poses:
        foot = joints[[15, 16, 19, 22], :2].mean(axis=0)
        ring = np.column_stack([foot[0] + 0.3 * np.cos(t), foot[1] + 0.3 * np.sin(t), np.zeros_like(t)])
        if np.all(camera.depth(ring) > 0.1):
            cv2.fillConvexPoly(mask, _fixed(camera.project(ring)), 1, cv2.LINE_8, SUBPIXEL_SHIFT)
    shade = mask > 0
    image[shade] = (image[shade] * 0.6).astype(np.uint8)


# --- labels -----------------------------------------------------------------------------------------


def _labels(
    camera: Camera, poses: np.ndarray, views: list[_PersonView], owner: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints (P, 23, 3) x, y, v and boxes (P, 4) of the painted persons (see the module docstring)."""
    w, h = camera.size
    num, parts = len(poses), len(PART_GROUPS)
    uv = np.array([v.uv for v in views]).reshape(num, NUM_JOINTS, 2)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] <= w - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= h - 1)
    inside &= camera.depth(poses) > 0
    px = np.clip(np.round(uv).astype(np.int64), 0, [w - 1, h - 1])
    top = owner[px[..., 1], px[..., 0]].astype(np.int64) - 1  # part id, -1 = none
    top_person = np.where(top >= 0, top // parts, -1)
    top_part = np.where(top >= 0, top % parts, 0)
    hidden = occluded_joints(camera.center, poses) if num else np.zeros((0, NUM_JOINTS), bool)
    face_seen = np.array([v.face_seen for v in views]).reshape(num, NUM_JOINTS)
    seen = (top_person == np.arange(num)[:, None]) & OWNS[top_part, np.arange(NUM_JOINTS)] & face_seen & ~hidden
    keypoints = np.concatenate([np.round(uv, 2), np.where(seen, 2.0, 1.0)[..., None]], axis=-1)
    keypoints[~inside] = 0.0
    return keypoints, _painted_boxes(owner, num, parts)


def _painted_boxes(owner: np.ndarray, num: int, parts: int) -> np.ndarray:
    """Boxes (P, 4) x, y, w, h of each person's painted pixels of an owner map (H, W); zeros if none."""
    ys, xs = np.nonzero(owner)
    person = (owner[ys, xs].astype(np.int64) - 1) // parts
    rows = np.zeros((num, owner.shape[0]), dtype=bool)
    cols = np.zeros((num, owner.shape[1]), dtype=bool)
    rows[person, ys] = True
    cols[person, xs] = True
    boxes = np.zeros((num, 4))
    for p in np.flatnonzero(rows.any(axis=1)):
        r, c = np.flatnonzero(rows[p]), np.flatnonzero(cols[p])
        boxes[p] = (c[0], r[0], c[-1] + 1 - c[0], r[-1] + 1 - r[0])
    return boxes


# --- images -----------------------------------------------------------------------------------------


def synthetic_image(
    rng: np.random.Generator, options: ImageOptions = ImageOptions(), with_background: bool = False
) -> SyntheticImage:
    """Render one crowded image and its labels; persons with no painted pixel or no joint in view are left out."""
    camera = sample_camera(rng, options.size)
    poses = sample_crowd(rng, camera, options)
    background = render_background(rng, camera)
    image = background.copy()
    _draw_shadows(image, camera, poses)
    w, h = options.size
    owner = np.zeros((h, w), np.uint16)
    light = rng.normal(size=2) * [1.0, 0.5]
    light[1] = -abs(light[1])  # highlights towards the top
    light /= max(float(np.linalg.norm(light)), 1e-9)
    views = [_view_person(camera, joints, light) for joints in poses]
    for p in np.argsort([-v.person_depth for v in views], kind="stable"):
        _draw_person(image, owner, views[p], _person_colours(rng), 1 + p * len(PART_GROUPS), rng)
    keypoints, boxes = _labels(camera, poses, views, owner)
    keep = (boxes[:, 2] > 0) & np.any(keypoints[..., 2] > 0, axis=1)
    grain = rng.normal(0, rng.uniform(1, 5), (h // 2, w // 2)).astype(np.float32)
    grain = cv2.resize(cv2.merge([grain] * 3), (w, h))
    return SyntheticImage(
        _finish(image, grain), keypoints[keep], boxes[keep], _finish(background, grain) if with_background else None
    )


def _finish(image: np.ndarray, grain: np.ndarray) -> np.ndarray:
    """Add grain (H, W, 3) float32 to an image (H, W, 3) uint8: a new (H, W, 3) uint8, saturated."""
    return cv2.add(image, grain, dtype=cv2.CV_8U)


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
    info = {
        "description": "synthetic crowded images (data.pose2d.synthetic_images)",
        "seed": int(seed),
        "num_images": int(num_images),
        "size": [w, h],
    }
    write_coco_keypoints(ann_path, records, image_root=image_dir, info=info)
    return ann_path


# --- preview ----------------------------------------------------------------------------------------


def draw_annotations(image: np.ndarray, keypoints: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """A copy of image (H, W, 3) with boxes (N, 4), limbs and joints (N, 23, 3): green seen, red hidden."""
    out = image.copy()
    for kps, box in zip(keypoints, boxes):
        x, y, bw, bh = (int(round(v)) for v in box)
        cv2.rectangle(out, (x, y), (x + bw, y + bh), (255, 200, 0), 1)
        for a, b in LIMBS:
            if kps[a, 2] > 0 and kps[b, 2] > 0:
                cv2.line(out, _ipt(kps[a, :2]), _ipt(kps[b, :2]), (0, 255, 255), 1, cv2.LINE_AA)
        for x, y, v in kps:
            if v > 0:
                cv2.circle(
                    out,
                    _ipt(np.array([x, y])),
                    3,
                    (0, 220, 0) if v >= 2 else (0, 0, 255),
                    -1 if v >= 2 else 1,
                    cv2.LINE_AA,
                )
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


# --- CLI --------------------------------------------------------------------------------------------


def _size(text: str) -> tuple[int, int]:
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
    parser.add_argument("--size", type=_size, default=(640, 480), help="WIDTHxHEIGHT (default 640x480)")
    parser.add_argument("--persons", type=int, nargs=2, default=(4, 12), metavar=("MIN", "MAX"))
    parser.add_argument(
        "--height-px",
        type=float,
        nargs=2,
        metavar=("MIN", "MAX"),
        help="person height range in pixels (default: 1/6 to 5/8 of the image height)",
    )
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
