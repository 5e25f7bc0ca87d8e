"""Other detectors' 2D made from the dev sets (real_inputs' ``variants``): scores, repeats, detector-like errors."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from data.keypoints import joint_indices
from data.multiview import Sequence, ViewDetections

ARM = joint_indices(f"{side}_{n}" for side in ("left", "right") for n in ("shoulder", "elbow", "wrist"))
LEG = joint_indices(
    f"{side}_{n}" for side in ("left", "right") for n in ("knee", "ankle", "big_toe", "small_toe", "heel")
)
HIPS = joint_indices(("left_hip", "right_hip"))


def each_view(sequence: Sequence, change: Callable[[ViewDetections, np.random.Generator], ViewDetections]) -> Sequence:
    """The sequence with change(view, rng) applied to every view (a seeded rng; the caller's data left as it is)."""
    rng = np.random.default_rng(0)
    frames = [replace(f, views=[change(v, rng) for v in f.views]) for f in sequence.frames]
    return replace(sequence, frames=frames)


def rescored(sequence: Sequence, scale: Callable[[np.ndarray], np.ndarray]) -> Sequence:
    """Every joint score s and detection score replaced by scale(s) (e.g. 4 s, s ** 3)."""

    def change(v: ViewDetections, rng: np.random.Generator) -> ViewDetections:
        keypoints = np.concatenate([v.keypoints[..., :2], scale(v.keypoints[..., 2:])], axis=-1)
        return replace(v, keypoints=keypoints, scores=scale(v.scores))

    return each_view(sequence, change)


def doubled(sequence: Sequence, shift_px: float = 0.3) -> Sequence:
    """Each detection repeated with its keypoints shifted by shift_px in x and y (a detector run twice)."""

    def change(v: ViewDetections, rng: np.random.Generator) -> ViewDetections:
        shifted = v.keypoints + np.array([shift_px, shift_px, 0.0])
        twice = lambda a: None if a is None else np.concatenate([a, a])  # noqa: E731
        return ViewDetections(
            np.concatenate([v.keypoints, shifted]),
            twice(v.bboxes),
            twice(v.scores),
            twice(v.person_ids),
            twice(v.occluded),
        )

    return each_view(sequence, change)


def detector_like(sequence: Sequence, sigma_px: float = 5.0, swaps: float = 0.05, drops: float = 0.1) -> Sequence:
    """Exact 2D made detector-like: errors growing from the hips, limb side swaps, dropped joints, uniform scores."""

    def change(v: ViewDetections, rng: np.random.Generator) -> ViewDetections:
        kp, seen = v.keypoints.copy(), v.keypoints[..., 2] > 0
        hip = kp[:, HIPS, :2].mean(axis=1, keepdims=True)
        far = np.linalg.norm(kp[..., :2] - hip, axis=-1)
        scale = np.nanmedian(np.where(seen, far, np.nan), axis=1, keepdims=True)
        kp[..., :2] += rng.normal(size=far.shape + (2,)) * (sigma_px * (0.25 + far / np.maximum(scale, 1.0)))[..., None]
        for limb in (ARM, LEG):
            left, right = limb[: len(limb) // 2], limb[len(limb) // 2 :]
            for n in np.flatnonzero(rng.random(len(kp)) < swaps):
                kp[n, list(left + right)] = kp[n, list(right + left)]
        kp[..., 2] = np.where(seen & (rng.random(seen.shape) >= drops), rng.uniform(0.2, 1.0, seen.shape), 0.0)
        return replace(v, keypoints=kp)

    return each_view(sequence, change)
