"""Person boxes from BlazePose's detector (MediaPipe's pose_detection, in its 0.10 wheel), offline, on the whole image."""

from __future__ import annotations

import cv2
import numpy as np
import torch
import torchvision
from scipy.special import expit

from data.config_checks import fail, is_int, is_number
from data.multiview import Frame
from models.detectors.boxes import with_scores
from models.tflite_models import TFLiteModel, mediapipe_model

# MediaPipe's SSD anchors of pose_detection (224 x 224): strides 8, 16, 32 with 2, 2, 6 anchors per cell
ANCHOR_LAYERS = ((8, 2), (16, 2), (32, 6))


def ssd_anchors(size: int) -> np.ndarray:
    """The detector's anchor centres (A, 2) in [0, 1], in its output order (A = 2254 at 224 px)."""
    out = []
    for stride, per_cell in ANCHOR_LAYERS:
        cells = size // stride
        y, x = np.mgrid[:cells, :cells]
        centres = np.stack([(x.ravel() + 0.5) / cells, (y.ravel() + 0.5) / cells], axis=1)
        out.append(np.repeat(centres, per_cell, axis=0))
    return np.concatenate(out)


def tiles(width: int, height: int, grids: tuple[int, ...], overlap: float) -> np.ndarray:
    """Square windows (T, 3) int x, y, side px: per n in ``grids``, sides of max(W, H) / n x (1 + overlap) (n = 1: the
    whole image, centred) stepped across the image."""
    out = []
    for n in grids:
        side = round(max(width, height) / n * (1 + overlap if n > 1 else 1))
        steps = [
            0 if extent <= side else int(np.ceil((extent - side) * (1 + overlap) / side)) for extent in (width, height)
        ]
        xs, ys = (np.linspace(0, e - side, k + 1) if k else [(e - side) / 2] for e, k in zip((width, height), steps))
        out += [(round(x), round(y), side) for y in ys for x in xs]
    return np.array(out, np.int64).reshape(-1, 3)


def window(image: np.ndarray, tile: np.ndarray, size: int) -> np.ndarray:
    """The square window (x, y, side) of a (H, W, 3) BGR image -> (size, size, 3) float32 RGB in [-1, 1], black outside."""
    x, y, side = (int(v) for v in tile)
    h, w = image.shape[:2]
    canvas = np.zeros((side, side, 3), np.uint8)
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + side, w), min(y + side, h)
    canvas[y0 - y : y1 - y, x0 - x : x1 - x] = image[y0:y1, x0:x1]
    small = cv2.resize(canvas, (size, size), interpolation=cv2.INTER_AREA if side > size else cv2.INTER_LINEAR)
    return small[:, :, ::-1].astype(np.float32) / 127.5 - 1.0


def decode(raw: np.ndarray, anchors: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """One image's (A, 12) regressions -> face boxes (A, 4) x1 y1 x2 y2 and body centre, extent point (A, 2, 2) px."""
    centre = raw[:, :2] + anchors * size
    faces = np.concatenate([centre - raw[:, 2:4] / 2, centre + raw[:, 2:4] / 2], axis=1)
    return faces, raw[:, 4:8].reshape(-1, 2, 2) + anchors[:, None] * size  # keypoints 0 (hips), 1 (body circle)


class BlazePoseDetector:
    """BlazePose's person detector: per view (N, 5) x, y, w, h, score; a box is the square around the body circle
    (centred on the hips), found from the face: a person whose face is hidden in a view is missed there."""

    needs_images = True

    def __init__(
        self,
        score_threshold: float = 0.5,
        nms_iou: float = 0.3,
        grids: tuple[int, ...] = (1, 2, 3),
        overlap: float = 0.5,
        threads: int = 1,
    ) -> None:
        if not (is_number(score_threshold) and 0 <= score_threshold <= 1):
            fail("detector.score_threshold", score_threshold, "must be a number in [0, 1]")
        if not (is_number(nms_iou) and 0 < nms_iou <= 1):
            fail("detector.nms_iou", nms_iou, "must be in (0, 1] (1: no suppression)")
        if not (is_int(threads) and threads >= 1):
            fail("detector.threads", threads, "must be an integer >= 1")
        self.model = TFLiteModel(mediapipe_model("pose_detection", "detector=blazepose"), "detector", threads)
        self.size = self.model.input_size[0]
        self.anchors = ssd_anchors(self.size)
        self.score_threshold, self.nms_iou, self.grids, self.overlap = score_threshold, nms_iou, tuple(grids), overlap

    def __call__(self, images: list[np.ndarray], frame: Frame | None = None) -> list[np.ndarray]:
        """Per view (N, 5) x, y, w, h, score of the persons found in (H, W, 3) uint8 BGR ``images``."""
        if not images:
            return []
        out = []
        for image in images:  # one window at a time: the graph's reshapes are built for a batch of 1
            found = [
                self.model(window(image, t, self.size)[None]) + [t]
                for t in tiles(*image.shape[1::-1], self.grids, self.overlap)
            ]
            out.append(self.boxes(found))
        return out

    def boxes(self, found: list) -> np.ndarray:
        """Each window's raw outputs (1, A, 12), (1, A, 1) and (3,) x, y, side -> (N, 5) boxes in image px after NMS."""
        faces, points, scores = [], [], []
        for raw, logits, (x, y, side) in found:
            score = expit(np.clip(logits[0, :, 0].astype(np.float64), -100, 100))
            keep = score >= self.score_threshold
            face, point = decode(raw[0, keep].astype(np.float64), self.anchors[keep], self.size)
            scale, offset = side / self.size, np.array([x, y], np.float64)
            faces.append(face * scale + np.tile(offset, 2))
            points.append(point * scale + offset)
            scores.append(score[keep])
        faces, points, scores = np.concatenate(faces), np.concatenate(points), np.concatenate(scores)
        order = torchvision.ops.nms(torch.from_numpy(faces), torch.from_numpy(scores), self.nms_iou).numpy()
        points = points[order]  # suppression on the face boxes (MediaPipe's), the output is the body
        radius = np.linalg.norm(points[:, 1] - points[:, 0], axis=1)[:, None]
        return with_scores(np.column_stack([points[:, 0] - radius, 2 * radius, 2 * radius]), scores[order])
