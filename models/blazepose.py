"""BlazePose (MediaPipe's pose_landmark_full, shipped in its 0.10 wheel) run top-down on person boxes: COCO-23 poses."""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np
from scipy.special import expit

from data.config_checks import fail, is_int, is_number
from data.formats.boxes_from_poses import pose_box
from data.keypoints import BLAZEPOSE33_NAMES, BLAZEPOSE33_TO_COCO23, flip_permutation, to_coco23
from data.multiview import ViewDetections
from models.pose_nms import pose_nms
from models.sppe_stage import nms_threshold
from models.tflite_models import TFLiteModel, mediapipe_model

NUM_LANDMARKS = 33
HIP_CENTRE, BODY_EXTENT = 33, 34  # auxiliary landmarks: the next crop's centre and its half size (MediaPipe's ROI)
ROI_SCALE = 1.25  # MediaPipe's crop side around the body circle: 1.25 x its diameter (what the model was trained on)
LEFT_RIGHT = np.append(flip_permutation(BLAZEPOSE33_NAMES), [HIP_CENTRE, BODY_EXTENT])  # the auxiliary two: central


def box_rois(boxes: np.ndarray, scale: float) -> np.ndarray:
    """Person boxes (N, >=4) x, y, w, h -> square upright crops (N, 4) centre x, centre y, side, angle 0."""
    boxes = np.asarray(boxes, np.float64)
    side = np.maximum(boxes[:, 2], boxes[:, 3]) * scale
    return np.column_stack([boxes[:, 0] + boxes[:, 2] / 2, boxes[:, 1] + boxes[:, 3] / 2, side, np.zeros(len(boxes))])


def aligned_rois(centre: np.ndarray, extent: np.ndarray, scale: float) -> np.ndarray:
    """Body centre (N, 2) and extent point (N, 2) px -> crops (N, 4) with the extent point straight above the centre."""
    d = np.asarray(extent, np.float64) - centre
    angle = np.arctan2(d[:, 0], -d[:, 1])
    return np.column_stack([centre, 2 * np.hypot(d[:, 0], d[:, 1]) * scale, angle])


def crop_to_image(roi: np.ndarray, size: int) -> np.ndarray:
    """The (2, 3) affine of one crop (cx, cy, side, angle) from its size x size pixels to image pixels."""
    cx, cy, side, angle = roi
    c, s = np.cos(angle) * side / size, np.sin(angle) * side / size
    rot = np.array([[c, -s], [s, c]])
    return np.column_stack([rot, np.array([cx, cy]) - rot @ np.array([size / 2, size / 2])])


def crops(image: np.ndarray, rois: np.ndarray, size: int) -> np.ndarray:
    """(H, W, 3) uint8 BGR image and (N, 4) crops -> (N, size, size, 3) float32 RGB in [0, 1] (zero outside)."""
    rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    out = np.empty((len(rois), size, size, 3), np.float32)
    for i, roi in enumerate(rois):
        warp = cv2.invertAffineTransform(crop_to_image(roi, size))
        out[i] = cv2.warpAffine(rgb, warp, (size, size), flags=cv2.INTER_LINEAR, borderValue=0) / 255.0
    return out


def refine_from_heatmap(xy: np.ndarray, heatmaps: np.ndarray, size: int, kernel: int = 7) -> np.ndarray:
    """Landmarks (B, L, 2) crop px -> the sigmoid-weighted mean over a kernel window of heatmaps (B, h, w, >=L)."""
    b, h, w, _ = heatmaps.shape
    cell = size / w
    half = kernel // 2
    centre = np.clip(np.floor(xy / cell).astype(int), 0, w - 1)
    offsets = np.arange(-half, half + 1)
    cols = np.clip(centre[..., 0, None] + offsets, 0, w - 1)  # (B, L, k)
    rows = np.clip(centre[..., 1, None] + offsets, 0, h - 1)
    bi, li = np.arange(b)[:, None, None, None], np.arange(xy.shape[1])[None, :, None, None]
    conf = expit(heatmaps[bi, rows[..., :, None], cols[..., None, :], li])  # (B, L, k, k)
    total = conf.sum(axis=(2, 3))
    mean_x = (conf.sum(axis=2) * cols).sum(axis=2) / total * cell
    mean_y = (conf.sum(axis=3) * rows).sum(axis=2) / total * cell
    refine = (conf.max(axis=(2, 3)) >= 0.5)[..., None]
    return np.where(refine, np.stack([mean_x, mean_y], axis=-1), xy)


class BlazePose:
    """``stage(images, boxes) -> list[ViewDetections]``: BlazePose on every person box of every view, all crops batched."""

    needs_boxes = True

    def __init__(
        self,
        flip_test: bool = True,
        passes: int = 3,
        box_scale: float = 1.25,
        refine: bool = True,
        min_presence: float = 0.5,
        batch_size: int = 16,
        threads: int = 1,
        pose_nms: Mapping | None = None,
    ) -> None:
        if not (is_int(passes) and passes >= 1):
            fail("pose2d.passes", passes, "must be an integer >= 1")
        if not (is_number(box_scale) and box_scale > 0):
            fail("pose2d.box_scale", box_scale, "must be a number > 0")
        if not (is_number(min_presence) and 0 <= min_presence <= 1):
            fail("pose2d.min_presence", min_presence, "must be a number in [0, 1]")
        for key, value in (("batch_size", batch_size), ("threads", threads)):
            if not (is_int(value) and value >= 1):
                fail(f"pose2d.{key}", value, "must be an integer >= 1")
        self.model = TFLiteModel(mediapipe_model("pose_landmark_full", "pose2d=blazepose"), "pose2d", threads)
        self.size = self.model.input_size[0]
        self.flip_test, self.passes, self.box_scale, self.refine = bool(flip_test), passes, box_scale, bool(refine)
        self.min_presence, self.batch_size, self.nms_oks = min_presence, batch_size, nms_threshold(pose_nms)

    def landmarks(self, batch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Crops (B, S, S, 3) -> landmarks (B, 35, 3) crop x, y, visibility in [0, 1] and pose presence (B,)."""
        out = []
        for start in range(0, len(batch), self.batch_size):
            raw, flag, _, heatmaps, _ = self.model(batch[start : start + self.batch_size])
            raw = raw.reshape(len(raw), -1, 5)
            xy = refine_from_heatmap(raw[:, :, :2], heatmaps, self.size) if self.refine else raw[:, :, :2]
            out.append((np.concatenate([xy, expit(raw[:, :, 3:4])], axis=2), flag.reshape(-1)))
        return np.concatenate([o[0] for o in out])[:, :35], np.concatenate([o[1] for o in out])

    def run_crops(self, batch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Crops (B, S, S, 3) -> landmarks (B, 35, 3) and presence (B,), averaged with the mirrored crop (flip test)."""
        marks, presence = self.landmarks(batch)
        if not self.flip_test:
            return marks, presence
        mirrored, flipped_presence = self.landmarks(batch[:, :, ::-1])
        mirrored = mirrored[:, LEFT_RIGHT]
        mirrored[:, :, 0] = self.size - mirrored[:, :, 0]
        weight = np.stack([marks[:, :, 2], mirrored[:, :, 2]]) + 1e-6
        xy = (weight[0, ..., None] * marks[:, :, :2] + weight[1, ..., None] * mirrored[:, :, :2]) / weight.sum(0)[
            ..., None
        ]
        score = (marks[:, :, 2] + mirrored[:, :, 2]) / 2
        return np.concatenate([xy, score[..., None]], axis=2), (presence + flipped_presence) / 2

    def __call__(self, images: list[np.ndarray], boxes: list[np.ndarray] | None) -> list[ViewDetections]:
        """Images (H, W, 3) uint8 BGR and boxes (N, 5) x, y, w, h, score per view -> ViewDetections (N', 23, 3)."""
        if boxes is None:
            raise ValueError("pose2d=blazepose runs on person boxes: give it a detector")
        rois = [box_rois(b, self.box_scale) for b in boxes]
        for step in range(self.passes):
            batch = np.concatenate([crops(im, r, self.size) for im, r in zip(images, rois)] or [np.zeros((0,))])
            marks, presence = self.run_crops(batch) if len(batch) else (np.zeros((0, 35, 3)), np.zeros(0))
            affines = [crop_to_image(roi, self.size) for r in rois for roi in r]
            image_xy = np.array([m[:, :2] @ a[:, :2].T + a[:, 2] for m, a in zip(marks, affines)]).reshape(-1, 35, 2)
            if step + 1 < self.passes:
                aligned = aligned_rois(image_xy[:, HIP_CENTRE], image_xy[:, BODY_EXTENT], ROI_SCALE)
                rois = np.split(aligned, np.cumsum([len(r) for r in rois])[:-1])
        keypoints = np.concatenate([image_xy, marks[:, :, 2:]], axis=2)[:, :NUM_LANDMARKS]
        size = np.concatenate(
            [np.tile(im.shape[1::-1], (len(r), 1)) for im, r in zip(images, rois)] or [np.zeros((0, 2))]
        )
        outside = np.any((keypoints[:, :, :2] < 0) | (keypoints[:, :, :2] >= size[:, None]), axis=2)
        keypoints[:, :, 2] *= ~outside  # a landmark guessed beyond the image is no measurement
        return self.to_views(keypoints, presence, boxes)

    def to_views(self, keypoints: np.ndarray, presence: np.ndarray, boxes: list[np.ndarray]) -> list[ViewDetections]:
        """All crops' landmarks (B, 33, 3) image px and presence (B,) -> one ViewDetections per view (COCO-23)."""
        coco = to_coco23(keypoints, BLAZEPOSE33_TO_COCO23)
        out, start = [], 0
        for view_boxes in boxes:
            n = len(view_boxes)
            keep = presence[start : start + n] >= self.min_presence
            poses, score = coco[start : start + n][keep], view_boxes[keep, 4] * presence[start : start + n][keep]
            if self.nms_oks is not None and len(poses) > 1:  # two boxes that led to one person
                kept, poses = pose_nms(poses, tight_boxes(poses), score, self.nms_oks)
                score = score[kept]
            out.append(ViewDetections(poses, tight_boxes(poses), score, np.full(len(poses), -1)))
            start += n
        return out


def tight_boxes(poses: np.ndarray) -> np.ndarray:
    """COCO-23 poses (N, 23, 3) -> (N, 4) x, y, w, h around their joints with a score > 0 (zeros: none scored)."""
    boxes = [pose_box(pose, 0.0) for pose in poses]
    return np.array([np.zeros(4) if b is None else b for b in boxes]).reshape(len(poses), 4)
