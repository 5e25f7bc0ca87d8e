"""The joint-candidate SPPE as the 2D stage of the multi-view pipeline (configs/pose2d/sppe.yaml)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch

from data.config_checks import fail, is_int, is_number
from data.keypoints import NUM_JOINTS
from data.multiview import ViewDetections
from data.pose2d.box_crops import crop_boxes, normalize_crops
from models.checkpoint_io import load_trained_model
from models.devices import resolve_device
from models.heatmap_inference import predict_heatmaps
from models.pose_decoding import (
    DECODERS,
    associate_by_image,
    joint_candidates,
    person_scores,
    separate_pairs,
    single_peaks,
)
from models.pose_nms import find_duplicates, merge_joints
from models.training import build_codec


@dataclass(frozen=True)
class SppeOptions:
    """The stage's settings (configs/pose2d/sppe.yaml documents each); pose_nms_oks None = pose-NMS off."""

    flip_test: bool = True
    decode: str = "association"
    threshold: float = 0.1
    top_m: int = 3
    dist_thresh: float = 1.0
    batch_size: int = 32
    amp: bool = True
    pose_nms_oks: float | None = 0.7
    separate_pairs: bool = False

    def __post_init__(self) -> None:
        for key in ("flip_test", "amp", "separate_pairs"):
            if not isinstance(getattr(self, key), bool):
                fail(f"pose2d.{key}", getattr(self, key), "must be true or false")
        if self.decode not in DECODERS:
            fail("pose2d.decode", self.decode, f"must be one of {', '.join(DECODERS)}")
        for key, minimum in (("threshold", 0.0), ("dist_thresh", 0.0)):
            if not is_number(getattr(self, key)) or getattr(self, key) < minimum:
                fail(f"pose2d.{key}", getattr(self, key), f"must be a number >= {minimum:g}")
        for key in ("top_m", "batch_size"):
            if not is_int(getattr(self, key)) or getattr(self, key) < 1:
                fail(f"pose2d.{key}", getattr(self, key), "must be an integer >= 1")
        oks = self.pose_nms_oks
        if oks is not None and not (is_number(oks) and 0 < oks < 1):
            fail("pose2d.pose_nms.oks", oks, "must be a number in (0, 1)")


def nms_threshold(pose_nms_cfg: Mapping | None) -> float | None:
    """The pose_nms config block {enabled, oks} -> the OKS threshold, None when off; no block: on, OKS 0.7."""
    if pose_nms_cfg is None:
        return SppeOptions.pose_nms_oks
    enabled = pose_nms_cfg.get("enabled", True)
    if not isinstance(enabled, bool):
        fail("pose2d.pose_nms.enabled", enabled, "must be true or false")
    return pose_nms_cfg.get("oks", SppeOptions.pose_nms_oks) if enabled else None


class SppeStage:
    """Person boxes of every view of a frame -> COCO-23 poses per view, by a train.py FastPose checkpoint."""

    needs_boxes = True

    def __init__(
        self, checkpoint: str | Path, device: str = "auto", pose_nms: Mapping | None = None, **options: Any
    ) -> None:
        """options: the fields of SppeOptions but pose_nms_oks, which the pose_nms block {enabled, oks} gives."""
        self.options = SppeOptions(**options, pose_nms_oks=nms_threshold(pose_nms))
        self.device = resolve_device(device, "pose2d.device")
        self.model, train_cfg = load_trained_model(checkpoint, self.device)
        self.codec, self.padding = build_codec(train_cfg), float(train_cfg.data.padding)
        self.last_timings: dict[str, float] = {}  # seconds of the last call: crop, network, decode

    def __call__(self, images: list[np.ndarray], boxes: list[np.ndarray]) -> list[ViewDetections]:
        """Images (H, W, 3) uint8 BGR and boxes (N_v, 5) x, y, w, h, score per view -> ViewDetections per view."""
        if len(images) != len(boxes):
            raise ValueError(f"SPPE stage: {len(images)} images but {len(boxes)} box arrays (one of each per view)")
        boxes = [_checked_boxes(b, v) for v, b in enumerate(boxes)]
        start = time.perf_counter()
        pixels, affines = self._crops(images, boxes)
        if len(affines) == 0:
            return [ViewDetections.empty(NUM_JOINTS) for _ in boxes]
        network = time.perf_counter()
        o = self.options
        heatmaps = predict_heatmaps(self.model, normalize_crops(pixels), o.batch_size, o.flip_test, o.amp)
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)  # the network's share of last_timings, not the decoding's
        decode = time.perf_counter()
        views = np.repeat(np.arange(len(boxes)), [len(b) for b in boxes])
        out = self.decode(heatmaps, affines, np.concatenate(boxes), views, len(boxes))
        end = time.perf_counter()
        self.last_timings = {"crop": network - start, "network": decode - network, "decode": end - decode}
        return out

    def _crops(self, images: list[np.ndarray], boxes: list[np.ndarray]) -> tuple[torch.Tensor, np.ndarray]:
        """RGB uint8 crops (B, h, w, 3) of every box of every view on the device, crop-to-image affines (B, 2, 3)."""
        crops = [
            crop_boxes(_checked_image(image, v), b[:, :4], self.codec.input_size, self.padding)
            for v, (image, b) in enumerate(zip(images, boxes))
        ]
        pixels = torch.from_numpy(np.concatenate([c for c, _ in crops])).to(self.device)
        return pixels, np.concatenate([a for _, a in crops])

    def decode(
        self, heatmaps: torch.Tensor, affines: np.ndarray, boxes: np.ndarray, views: np.ndarray, n_views: int
    ) -> list[ViewDetections]:
        """Heatmaps (B, 23, h, w), affines (B, 2, 3), boxes (B, 5), views (B,) -> ViewDetections per view."""
        o = self.options
        if o.decode == "single":
            candidates, poses = None, single_peaks(self.codec, heatmaps, affines)
        else:
            candidates = joint_candidates(self.codec, heatmaps, affines, o.threshold, o.top_m)
            poses = candidates[:, :, 0]  # each box's own best candidate per joint (slots are sorted best first)
        groups = self._duplicates(poses, boxes, views)
        kept = np.array([k for k, _ in groups], dtype=int)
        if candidates is None:
            final = poses[kept]
        else:
            final = associate_by_image(candidates[kept], boxes[kept, :4], views[kept], o.dist_thresh)
        if o.pose_nms_oks is not None:
            areas = boxes[kept, 2] * boxes[kept, 3]
            final = [merge_joints(f, poses[d], a, o.pose_nms_oks) for f, (_, d), a in zip(final, groups, areas)]
            final = np.stack(final)
        if candidates is not None and o.separate_pairs:
            final = separate_pairs(final, candidates[kept], boxes[kept, :4])
        return [_view(final[views[kept] == v], boxes[kept][views[kept] == v]) for v in range(n_views)]

    def _duplicates(self, poses: np.ndarray, boxes: np.ndarray, views: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Per-view pose-NMS of poses (B, 23, 3), boxes (B, 5) -> (kept crop, its duplicates (D,)) in crop order."""
        oks = self.options.pose_nms_oks
        if oks is None:
            return [(i, np.zeros(0, dtype=int)) for i in range(len(poses))]
        groups = []
        for v in np.unique(views):
            idx = np.nonzero(views == v)[0]
            scores = person_scores(boxes[idx, 4], poses[idx])
            groups += [(int(idx[a]), idx[d]) for a, d in find_duplicates(poses[idx], boxes[idx, :4], scores, oks)]
        return groups


def _view(keypoints: np.ndarray, boxes: np.ndarray) -> ViewDetections:
    """One view's final keypoints (N, 23, 3) and boxes (N, 5) -> ViewDetections with the person scores."""
    return ViewDetections(keypoints, boxes[:, :4], person_scores(boxes[:, 4], keypoints), np.full(len(boxes), -1))


def _checked_boxes(boxes: np.ndarray, view: int) -> np.ndarray:
    """One view's boxes as (N, 5) float64, or a ValueError naming the view and the box."""
    array = np.asarray(boxes, dtype=np.float64)
    if array.size == 0:
        return np.zeros((0, 5))
    if array.ndim != 2 or array.shape[1] != 5:
        raise ValueError(f"SPPE stage: view {view}: boxes must be (N, 5) x, y, w, h, score, got shape {array.shape}")
    bad = np.nonzero(~np.isfinite(array).all(axis=1) | (array[:, 2] <= 0) | (array[:, 3] <= 0))[0]
    if len(bad):
        raise ValueError(
            f"SPPE stage: view {view}: box {bad[0]} {array[bad[0]].tolist()} is not finite or has w or h <= 0"
        )
    return array


def _checked_image(image: np.ndarray, view: int) -> np.ndarray:
    """One view's image, or a ValueError naming the view."""
    if not (isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3):
        shape, dtype = getattr(image, "shape", None), getattr(image, "dtype", type(image).__name__)
        raise ValueError(f"SPPE stage: view {view}: the image must be (H, W, 3) uint8 BGR, got {shape} {dtype}")
    return image
