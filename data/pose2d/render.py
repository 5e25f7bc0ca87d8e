"""The one drawing path of the synthetic images: capsule bodies, shading, shadows, ground lines, grain, labels."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from data.geometry.camera import Camera
from data.keypoints import LIMBS, NUM_JOINTS
from data.synthetic.capsules import HEAD_RADIUS_M, body_capsules, capsule_radii, occluded_joints

SHIRT, SLEEVE, TROUSERS, SHIN, SHOES, SKIN, HAIR = range(7)  # part groups of one clothing colour per person
SKIN_TONES = np.array([(185, 205, 240), (150, 180, 225), (110, 150, 205), (80, 115, 170), (50, 75, 120)], float)
HAIR_TONES = np.array([(20, 20, 25), (30, 45, 70), (40, 80, 130), (120, 170, 210), (140, 140, 140)], float)
SHADE_LAYERS = ((1.0, 0.0, 0.62), (0.78, 0.10, 0.84), (0.45, 0.30, 1.0))  # (radius, light shift, brightness)
_SHADE_SCALE, _SHADE_SHIFT, _SHADE_BRIGHT = np.array(SHADE_LAYERS).T
FACE_VISIBLE_COS = -0.2  # a face joint is seen while cos(joint - head centre, camera - head centre) >= this
HAIR_BACK_M, HAIR_UP_M, HAIR_RADIUS_M = 0.03, 0.015, 0.095
SUBPIXEL_SHIFT = 3  # fixed-point bits of the polygon coordinates
MAX_PERSONS = 1000  # the uint16 part-owner map holds persons x 28 parts
NEAR_M = 0.05  # ground lines are clipped to this depth in front of the camera
DISTORTED_STEP_M = 0.25  # ground lines are drawn in pieces this long where the lens distorts

_HEAD = len(LIMBS) + 1  # index of the head sphere in body_capsules


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
    """Which joints (K, 23) bool each drawn part carries: limb ends, torso corners, the face, the ears (hair)."""
    owned = [(a, b) for a, b in LIMBS] + [(5, 6, 11, 12), (0, 1, 2, 3, 4), (3, 4)]
    owns = np.zeros((len(groups), NUM_JOINTS), dtype=bool)
    for k, joints in enumerate(owned):
        owns[k, list(joints)] = True
    return owns


PART_GROUPS = _part_groups()
OWNS = _owns(PART_GROUPS)
PART_GROUPS.flags.writeable = False
OWNS.flags.writeable = False


@dataclass(frozen=True)
class PersonLook:
    """How one person is painted: colours (7, 3) BGR of the part groups, brightness tint (K,) per drawn part."""

    colours: np.ndarray
    tint: np.ndarray


def sample_look(rng: np.random.Generator) -> PersonLook:
    """A random look: clothing, skin and hair colours, then the per-part tints."""
    skin = SKIN_TONES[rng.integers(len(SKIN_TONES))] * rng.uniform(0.9, 1.1)
    shirt = rng.uniform(20, 240, 3)
    trousers = rng.uniform(15, 200, 3)
    sleeve = shirt if rng.random() < 0.6 else skin
    shin = trousers if rng.random() < 0.8 else skin
    shoes = rng.uniform(10, 120, 3)
    hair = HAIR_TONES[rng.integers(len(HAIR_TONES))] * rng.uniform(0.8, 1.2)
    colours = np.clip(np.array([shirt, sleeve, trousers, shin, shoes, skin, hair]), 0, 255)
    return PersonLook(colours, rng.uniform(0.92, 1.08, len(PART_GROUPS)))


def smooth_field(rng: np.random.Generator, size: tuple[int, int], cells: int, low: float, high: float) -> np.ndarray:
    """A smooth random colour field (H, W, 3) uint8, upsampled from a coarse grid (cubic, then linear)."""
    w, h = size
    coarse = rng.uniform(low, high, (cells, cells + 1, 3)).astype(np.float32)
    middle = cv2.resize(coarse, (max(w // 8, 1), max(h // 8, 1)), interpolation=cv2.INTER_CUBIC)
    return cv2.resize(np.clip(middle, 0, 255).astype(np.uint8), (w, h), interpolation=cv2.INTER_LINEAR)


def backdrop(rng: np.random.Generator, size: tuple[int, int]) -> np.ndarray:
    """A textured backdrop (H, W, 3) uint8 of size (w, h): smooth colours, stripes and blobs."""
    w, h = size
    image = smooth_field(rng, (w, h), int(rng.integers(2, 7)), 30, 230)
    for _ in range(int(rng.integers(0, 8))):  # stripes and bars
        p0 = rng.uniform([-w, -h], [2 * w, 2 * h])
        p1 = p0 + rng.normal(0, w, 2)
        cv2.line(image, ipt(p0), ipt(p1), random_colour(rng), int(rng.integers(2, 40)), cv2.LINE_AA)
    for _ in range(int(rng.integers(3, 20))):  # blobs
        axes = (int(rng.integers(4, w // 6)), int(rng.integers(4, h // 6)))
        centre = ipt(rng.uniform([0, 0], [w, h]))
        cv2.ellipse(image, centre, axes, float(rng.uniform(0, 180)), 0, 360, random_colour(rng), -1, cv2.LINE_AA)
    return image


def draw_ground_lines(image: np.ndarray, camera: Camera, ends: np.ndarray, colour: tuple[float, ...]) -> None:
    """Draw ground segments (S, 2, 2) (x, y on z = 0, m) in place on (H, W, 3), clipped in front of the camera."""
    world = np.concatenate([ends, np.zeros(ends.shape[:2] + (1,))], axis=-1)
    depth = camera.depth(world)
    front = np.any(depth > NEAR_M, axis=1)
    world, depth = world[front], depth[front]
    for end in (0, 1):  # move an end behind the camera onto the near plane
        other = 1 - end
        behind = depth[:, end] <= NEAR_M
        frac = (NEAR_M - depth[behind, end]) / (depth[behind, other] - depth[behind, end])
        world[behind, end] += frac[:, None] * (world[behind, other] - world[behind, end])
    if camera.has_distortion:
        _draw_distorted_lines(image, camera, world, colour)
        return
    uv = np.round(np.clip(camera.project(world), -1e5, 1e5))
    for (u0, v0), (u1, v1) in uv.astype(np.int64).tolist():
        cv2.line(image, (u0, v0), (u1, v1), colour, 1, cv2.LINE_AA)


def grid_lines(xs: np.ndarray, ys: np.ndarray, extent: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Ground segments (S, 2, 2) of the lines x = xs over [ymin, ymax], and of y = ys over [xmin, xmax]."""
    xmin, xmax, ymin, ymax = extent
    along_y = np.stack([np.stack([xs, np.full_like(xs, ymin)], 1), np.stack([xs, np.full_like(xs, ymax)], 1)], 1)
    along_x = np.stack([np.stack([np.full_like(ys, xmin), ys], 1), np.stack([np.full_like(ys, xmax), ys], 1)], 1)
    return along_y, along_x


def _draw_distorted_lines(image: np.ndarray, camera: Camera, world: np.ndarray, colour: tuple[float, ...]) -> None:
    """Segments world (S, 2, 3) drawn as pieces of DISTORTED_STEP_M whose ends are both in the view."""
    for a, b in world:
        count = max(int(math.ceil(np.linalg.norm(b - a) / DISTORTED_STEP_M)), 1)
        points = a + np.linspace(0.0, 1.0, count + 1)[:, None] * (b - a)
        seen = camera.in_view(points, margin=float(max(camera.size)))
        uv = np.round(np.clip(camera.project(points), -1e5, 1e5)).astype(np.int64)
        for i in np.flatnonzero(seen[:-1] & seen[1:]):
            cv2.line(image, tuple(uv[i].tolist()), tuple(uv[i + 1].tolist()), colour, 1, cv2.LINE_AA)


def random_colour(rng: np.random.Generator) -> tuple[float, float, float]:
    """A random BGR colour."""
    return tuple(float(c) for c in rng.uniform(0, 255, 3))


def ipt(p: np.ndarray) -> tuple[int, int]:
    """An integer pixel point of a (2,) array, clamped to a range cv2 accepts."""
    q = np.clip(np.round(p), -1e5, 1e5)
    return int(q[0]), int(q[1])


def grain_field(rng: np.random.Generator, size: tuple[int, int]) -> np.ndarray:
    """Sensor grain (H, W, 3) float32 for an image of size (w, h): half-resolution noise, upsampled."""
    w, h = size
    grain = rng.normal(0, rng.uniform(1, 5), (h // 2, w // 2)).astype(np.float32)
    return cv2.resize(cv2.merge([grain] * 3), (w, h))


def finish(image: np.ndarray, grain: np.ndarray) -> np.ndarray:
    """Add grain (H, W, 3) float32 to an image (H, W, 3) uint8: a new (H, W, 3) uint8, saturated."""
    return cv2.add(image, grain, dtype=cv2.CV_8U)


def draw_shadows(image: np.ndarray, camera: Camera, poses: np.ndarray) -> None:
    """Darken the ground under every person (P, 23, 3), a disc of 0.3 m radius, in place on (H, W, 3)."""
    t = np.linspace(0, 2 * math.pi, 16, endpoint=False)
    mask = np.zeros(image.shape[:2], np.uint8)
    for joints in poses:
        foot = joints[[15, 16, 19, 22], :2].mean(axis=0)
        ring = np.column_stack([foot[0] + 0.3 * np.cos(t), foot[1] + 0.3 * np.sin(t), np.zeros_like(t)])
        if np.all(camera.depth(ring) > 0.1):
            cv2.fillConvexPoly(mask, _fixed(camera.project(ring)), 1, cv2.LINE_8, SUBPIXEL_SHIFT)
    shade = mask > 0
    image[shade] = (image[shade] * 0.6).astype(np.uint8)


def capsule_outlines(a: np.ndarray, b: np.ndarray, ra: np.ndarray, rb: np.ndarray, n: int = 7) -> np.ndarray:
    """Outlines (..., 2n, 2) of tapered 2D capsules from a (..., 2) radius ra (...) to b (..., 2) radius rb."""
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
class PersonView:
    """A person in a camera: outlines (K, L, 2n, 2), part depths (K,), uv (23, 2), face_seen (23,), dot size."""

    outlines: np.ndarray
    depth: np.ndarray
    uv: np.ndarray
    face_seen: np.ndarray
    facing: bool
    dot_px: float
    person_depth: float


def view_person(camera: Camera, joints: np.ndarray, light: np.ndarray) -> PersonView:
    """Project one person's (23, 3) capsules, hair and joints; light (2,) is the image direction of highlights."""
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
    shift = _SHADE_SHIFT[None, :, None] * np.maximum(ra, rb)[:, None, None] * light
    uv_a, uv_b = camera.project(ends_a)[:, None] + shift, camera.project(ends_b)[:, None] + shift
    outlines = capsule_outlines(uv_a, uv_b, ra[:, None] * _SHADE_SCALE, rb[:, None] * _SHADE_SCALE)
    rel = joints - head
    cos = rel @ to_cam / np.maximum(np.linalg.norm(rel, axis=1) * np.linalg.norm(to_cam), 1e-12)
    face_seen = np.ones(NUM_JOINTS, dtype=bool)
    face_seen[:5] = cos[:5] >= FACE_VISIBLE_COS
    dot_px, person_depth = max(0.12 * focal * HEAD_RADIUS_M / da[_HEAD], 0.8), float(np.mean(camera.depth(joints)))
    facing = bool(forward @ to_cam > 0)
    return PersonView(_fixed(outlines), (da + db) / 2, camera.project(joints), face_seen, facing, dot_px, person_depth)


def painting_order(views: list[PersonView]) -> np.ndarray:
    """Person indices (P,) far to near: the order they are painted in."""
    return np.argsort([-v.person_depth for v in views], kind="stable")


def paint_persons(
    image: np.ndarray | None, views: list[PersonView], looks: list[PersonLook], size: tuple[int, int]
) -> np.ndarray:
    """Paint persons far to near in place on image (H, W, 3) or None; returns the owner map (H, W) uint16."""
    w, h = size
    owner = np.zeros((h, w), np.uint16)
    for p in painting_order(views):
        _draw_person(image, owner, views[p], looks[p], 1 + p * len(PART_GROUPS))
    return owner


def _draw_person(
    image: np.ndarray | None, owner: np.ndarray, view: PersonView, look: PersonLook, first_id: int
) -> None:
    """Paint one person's parts far to near in place; the owner map gets first_id + part index."""
    groups = PART_GROUPS
    layer_colours = np.clip(
        look.colours[groups][:, None] * look.tint[:, None, None] * _SHADE_BRIGHT[None, :, None], 0, 255
    ).tolist()
    for k in np.argsort(-view.depth, kind="stable"):
        if groups[k] < 0:
            continue
        cv2.fillConvexPoly(owner, view.outlines[k, 0], int(first_id + k), cv2.LINE_8, SUBPIXEL_SHIFT)
        if image is None:
            continue
        for layer, colour in enumerate(layer_colours[k]):
            cv2.fillConvexPoly(image, view.outlines[k, layer], colour, cv2.LINE_AA, SUBPIXEL_SHIFT)
        if k == _HEAD and view.facing:
            _draw_face(image, view, look.colours[SKIN])


def _draw_face(image: np.ndarray, view: PersonView, skin: np.ndarray) -> None:
    """Eyes and nose dots on a head that faces the camera, in place."""
    for j, colour, size in ((1, (30, 30, 30), 1.0), (2, (30, 30, 30), 1.0), (0, (skin * 0.7).tolist(), 1.4)):
        if view.face_seen[j]:
            centre, radius = _fixed(view.uv[j]).tolist(), int(round(view.dot_px * size * (1 << SUBPIXEL_SHIFT)))
            cv2.circle(image, tuple(centre), radius, colour, -1, cv2.LINE_AA, SUBPIXEL_SHIFT)


def person_labels(
    camera: Camera, poses: np.ndarray, views: list[PersonView], owner: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints (P, 23, 3) x, y, v and boxes (P, 4) x, y, w, h of painted persons (P, 23, 3) (docs/design.md)."""
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
    keypoints = np.concatenate([uv, np.where(seen, 2.0, 1.0)[..., None]], axis=-1)
    keypoints[~inside] = 0.0
    return keypoints, painted_boxes(owner, num)


def painted_boxes(owner: np.ndarray, num: int) -> np.ndarray:
    """Boxes (P, 4) x, y, w, h of each of num persons' painted pixels of an owner map (H, W); zeros if none."""
    parts = len(PART_GROUPS)
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
