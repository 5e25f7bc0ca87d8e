"""Person boxes from the ground truth: the 2D boxes a dataset's frames carry (rendered synthetic scenes)."""

from __future__ import annotations

import numpy as np

from data.config_checks import fail, is_int, is_number
from data.multiview import Frame
from models.detectors.boxes import clip_xywh, with_scores


class GroundTruthDetector:
    """``frame.views[v].bboxes`` as person boxes, score 1, optionally jittered reproducibly per (seed, frame, view)."""

    needs_images = False
    reads_ground_truth = True  # a dataset without ground-truth persons (real images) cannot feed it

    def __init__(self, jitter: float = 0.0, jitter_clip: float = 3.0, min_joints: int = 1, seed: int = 0) -> None:
        if not (is_number(jitter) and jitter >= 0):
            fail("detector.jitter", jitter, "must be a number >= 0 (a fraction of the box size)")
        if not (is_number(jitter_clip) and jitter_clip > 0):
            fail("detector.jitter_clip", jitter_clip, "must be a number > 0 (standard deviations)")
        if not (is_int(min_joints) and min_joints >= 0):
            fail("detector.min_joints", min_joints, "must be an integer >= 0")
        if not is_int(seed):
            fail("detector.seed", seed, "must be an integer")
        self.jitter, self.jitter_clip, self.min_joints, self.seed = jitter, jitter_clip, min_joints, seed

    def jittered(self, boxes: np.ndarray, frame_index: int, view: int) -> np.ndarray:
        """(N, 4) x, y, w, h -> (N, 4) with this detector's deterministic jitter for (frame, view)."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        if self.jitter == 0:
            return boxes.copy()
        rng = np.random.default_rng([self.seed, frame_index, view])
        z = np.clip(rng.standard_normal((len(boxes), 4)), -self.jitter_clip, self.jitter_clip)
        size = boxes[:, 2:]
        centre = boxes[:, :2] + size / 2 + self.jitter * size * z[:, :2]
        new_size = size * np.exp(self.jitter * z[:, 2:])
        return np.column_stack([centre - new_size / 2, new_size])

    def __call__(self, images: list[np.ndarray] | None, frame: Frame) -> list[np.ndarray]:
        """Per view (N, 5) x, y, w, h, score=1 from the frame's ground-truth boxes; images (H, W, 3) or None."""
        out = []
        for v, view in enumerate(frame.views):
            labelled = np.sum(view.keypoints[:, :, 2] > 0, axis=1)
            boxes = self.jittered(view.bboxes[labelled >= self.min_joints], frame.index, v)
            if images:
                height, width = images[v].shape[:2]
                boxes = clip_xywh(boxes, width, height)
                boxes = boxes[(boxes[:, 2] > 0) & (boxes[:, 3] > 0)]
            out.append(with_scores(boxes, np.ones(len(boxes))))
        return out
