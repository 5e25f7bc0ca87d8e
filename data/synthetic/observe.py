"""What one camera's person detector reports on a synthetic frame: noisy, partly hidden 2D poses."""

from __future__ import annotations

import math

import numpy as np

from data.geometry.camera import Camera
from data.keypoints import NUM_JOINTS
from data.multiview import ViewDetections
from data.synthetic.body import pose_joints, sample_body
from data.synthetic.capsules import occluded_joints
from data.synthetic.config import SyntheticConfig

# Joint scores: VISIBLE_SCORE (or OCCLUDED_SCORE for a hidden joint) times exp(-err^2 / (2 s^2)) with err
# the pixel error actually drawn and s = NOISE_SCORE_PX, plus a uniform jitter, clipped to MIN_SCORE..1.
VISIBLE_SCORE = 0.95
OCCLUDED_SCORE = 0.45
NOISE_SCORE_PX = 10.0
SCORE_JITTER = 0.03
MIN_SCORE = 0.05
BBOX_MARGIN = 0.10  # of the keypoint box size, on every side
# False positives: a random person's skeleton drawn side-on at a random place and size.
FP_HEIGHT_FRACTION = (0.15, 0.6)  # skeleton height as a fraction of the image height
FP_SCORE_RANGE = (0.15, 0.55)  # joint scores, uniform
FP_JOINT_DROP = 0.2  # probability that a false-positive joint is missing
FP_NOISE_FRACTION = 0.02  # joint jitter SD as a fraction of the skeleton height


def observe_view(
    camera: Camera, poses: np.ndarray, person_ids: np.ndarray, cfg: SyntheticConfig, rng: np.random.Generator
) -> ViewDetections:
    """Detections of world poses (P, 23, 3) with ids (P,) in one camera, in a shuffled order."""
    poses = np.asarray(poses, dtype=np.float64)
    num = len(poses)
    uv = camera.project(poses)  # (P, 23, 2)
    in_view = camera.in_view(poses)  # (P, 23)
    hidden = occluded_joints(camera.center, poses) if cfg.occlusion and num else np.zeros((num, NUM_JOINTS), bool)
    hidden &= in_view

    depth = np.maximum(camera.depth(poses), 1e-6)
    sigma = cfg.noise_px * (depth / cfg.noise_ref_depth_m) ** cfg.noise_depth_exponent
    sigma = np.where(hidden, sigma * cfg.occluded_noise_scale, sigma)
    noise = rng.normal(size=(num, NUM_JOINTS, 2)) * sigma[..., None]
    dropped = hidden & (rng.random((num, NUM_JOINTS)) < cfg.occluded_drop_prob)
    valid = in_view & ~dropped

    err = np.linalg.norm(noise, axis=-1)
    base = np.where(hidden, OCCLUDED_SCORE, VISIBLE_SCORE)
    jitter = rng.uniform(-SCORE_JITTER, SCORE_JITTER, (num, NUM_JOINTS))
    score = np.clip(base * np.exp(-0.5 * (err / NOISE_SCORE_PX) ** 2) + jitter, MIN_SCORE, 1.0)
    keypoints = np.concatenate([uv + noise, score[..., None]], axis=-1)
    keypoints[~valid] = 0.0

    detected = (valid.sum(axis=1) >= cfg.min_joints_in_view) & (rng.random(num) >= cfg.miss_rate)
    keypoints, hidden = keypoints[detected], hidden[detected]
    ids = np.asarray(person_ids, dtype=np.int64)[detected]

    fp = false_positives(int(rng.poisson(cfg.fp_rate)) if cfg.fp_rate > 0 else 0, camera.size, rng)
    keypoints = np.concatenate([keypoints, fp])
    ids = np.concatenate([ids, np.full(len(fp), -1, dtype=np.int64)])
    hidden = np.concatenate([hidden, np.zeros((len(fp), NUM_JOINTS), dtype=bool)])

    if len(keypoints) == 0:
        return ViewDetections.empty(NUM_JOINTS)
    order = rng.permutation(len(keypoints))
    keypoints, ids, hidden = keypoints[order], ids[order], hidden[order]
    boxes = bbox_from_keypoints(keypoints, camera.size)
    return ViewDetections(keypoints, boxes, keypoints[..., 2].mean(axis=1), ids, hidden)


def bbox_from_keypoints(keypoints: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Box x, y, w, h around the joints with score > 0, a margin added, clipped to the image: (N, 23, 3) -> (N, 4)."""
    keypoints = np.asarray(keypoints, dtype=np.float64)
    corner = np.array(image_size, dtype=np.float64) - 1
    seen = keypoints[..., 2:] > 0
    lo = np.where(seen, keypoints[..., :2], np.inf).min(axis=1)
    hi = np.where(seen, keypoints[..., :2], -np.inf).max(axis=1)
    pad = BBOX_MARGIN * (hi - lo)
    lo, hi = np.clip(lo - pad, 0.0, corner), np.clip(hi + pad, 0.0, corner)
    return np.where(seen.any(axis=1), np.concatenate([lo, hi - lo], axis=1), 0.0)


def false_positives(count: int, image_size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Spurious skeletons at random places with low scores: (count, 23, 3) pixels + score."""
    w, h = image_size
    out = np.zeros((count, NUM_JOINTS, 3))
    for n in range(count):
        walking = bool(rng.random() < 0.5)
        joints = pose_joints(sample_body(rng), 0.0, 0.0, rng.uniform(0, 2 * math.pi), rng.uniform(), walking)
        flat = np.stack([-joints[:, 1], -joints[:, 2]], axis=1)  # seen side-on along +x, image y down
        flat -= flat.min(axis=0)
        height_px = rng.uniform(*FP_HEIGHT_FRACTION) * h
        flat *= height_px / max(flat[:, 1].max(), 1e-9)
        size = flat.max(axis=0)
        offset = rng.uniform([0.0, 0.0], np.maximum([w - 1 - size[0], h - 1 - size[1]], 0.0))
        flat += offset + rng.normal(0.0, FP_NOISE_FRACTION * height_px, flat.shape)
        score = rng.uniform(*FP_SCORE_RANGE, NUM_JOINTS)
        score[rng.random(NUM_JOINTS) < FP_JOINT_DROP] = 0.0
        out[n] = np.column_stack([flat, score])
        out[n, score == 0] = 0.0
    return out
