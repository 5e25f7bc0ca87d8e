"""2D evaluation of a train.py checkpoint on a COCO-format keypoint set (``python eval.py checkpoint=...``)."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig
from torch import nn
from torch.utils.data import DataLoader

from data.formats.atomic_io import atomic_write_text
from data.formats.poses2d_io import write_poses2d
from data.formats.strict_json import finite
from data.keypoints import NUM_JOINTS
from data.multiview import ViewDetections
from data.pose2d.coco_eval import evaluate_keypoints, write_coco_results
from data.pose2d.coco_keypoints import load_keypoint_dataset
from data.pose2d.topdown_dataset import EpochSampler, TopDownDataset
from models.checkpoint_io import load_trained_model
from models.devices import resolve_device
from models.heatmap_codec import MultiModalHeatmapCodec
from models.heatmap_inference import predict_heatmaps
from models.pose_decoding import DECODERS, associate_by_image, joint_candidates, person_scores
from models.training import AP_SUBSETS, build_codec, decode_predictions


def build_eval_dataset(
    pose2d: DictConfig, train_cfg: DictConfig, codec: MultiModalHeatmapCodec
) -> tuple[TopDownDataset, Path]:
    """The plain crops of pose2d's annotation file (default: the checkpoint's validation set) and that file."""
    data = train_cfg.data
    kind = pose2d.kind or data.kind
    ann_file = Path(pose2d.ann_file or data.val.ann_file)
    image_dir = Path(pose2d.image_dir or data.val.image_dir)
    det_file = pose2d.det_file
    for p in (ann_file, image_dir, det_file):
        if p is not None and not Path(p).exists():
            raise FileNotFoundError(f"{p} does not exist")
    records = load_keypoint_dataset(kind, ann_file, image_dir, det_file, min_keypoints=int(det_file is None))
    crops = dict(augment=None, train=False, use_det_boxes=det_file is not None, padding=data.padding, cache_size=0)
    return TopDownDataset(records, codec, tuple(data.input_size), **crops), ann_file


def decode_candidates(
    codec: MultiModalHeatmapCodec, heatmaps: torch.Tensor, batch: dict, threshold: float, top_m: int
) -> list[dict]:
    """Heatmaps (B, 23, h, w) -> B crops {image_id, box (4,), score, candidates (23, M, 3) top-M maxima in pixels}."""
    candidates = joint_candidates(codec, heatmaps, batch["affine_inv"], threshold, top_m)
    return [
        {
            "image_id": int(batch["image_id"][i]),
            "box": batch["box"][i].numpy(),
            "score": float(batch["score"][i]),
            "candidates": candidates[i],
        }
        for i in range(len(candidates))
    ]


def associate_crops(crops: list[dict]) -> list[dict]:
    """Crops of decode_candidates -> per crop {image_id, keypoints (23, 3), score, bbox}, associated per image."""
    if not crops:
        return []
    boxes = np.stack([c["box"] for c in crops])
    keypoints = associate_by_image(np.stack([c["candidates"] for c in crops]), boxes, [c["image_id"] for c in crops])
    scores = person_scores(np.array([c["score"] for c in crops]), keypoints)
    return [
        {"image_id": c["image_id"], "keypoints": k, "bbox": c["box"], "score": float(s)}
        for c, k, s in zip(crops, keypoints, scores)
    ]


@torch.no_grad()
def predict(
    model: nn.Module,
    loader: DataLoader,
    codec: MultiModalHeatmapCodec,
    device: torch.device,
    decode: str = "association",
    threshold: float = 0.1,
    top_m: int = 3,
    flip_test: bool = True,
) -> list[dict]:
    """Predictions {image_id, keypoints (23, 3), score, bbox (4,)} for every crop of the loader, in its order."""
    if decode not in DECODERS:
        raise ValueError(f"decode must be one of {DECODERS}, got {decode!r}")
    predictions, crops = [], []
    for batch in loader:
        images = batch["image"].to(device)
        heatmaps = predict_heatmaps(model, images, max(len(images), 1), flip_test).cpu()
        if decode == "single":
            predictions += decode_predictions(codec, heatmaps, batch)
        else:
            crops += decode_candidates(codec, heatmaps, batch, threshold, top_m)
    return predictions if decode == "single" else associate_crops(crops)


def image_views(ann_file: Path) -> dict[int, tuple[int, str]]:
    """{image id: (frame, camera)} of an annotation file's images, from their keys, else (image id, "0")."""
    doc = json.loads(Path(ann_file).read_text())
    return {int(img["id"]): (int(img.get("frame", img["id"])), str(img.get("camera", "0"))) for img in doc["images"]}


def write_predictions_poses2d(
    path: str | Path, predictions: list[dict], views: dict[int, tuple[int, str]]
) -> list[str]:
    """Write predictions as poses2d.json, frame and camera from views; returns the camera names (sorted)."""
    cameras = sorted({views[p["image_id"]][1] for p in predictions} or {"0"})
    grouped: dict[int, list[list[dict]]] = defaultdict(lambda: [[] for _ in cameras])
    for p in predictions:
        frame, camera = views[p["image_id"]]
        grouped[frame][cameras.index(camera)].append(p)
    write_poses2d(path, {f: [_view(dets) for dets in per_camera] for f, per_camera in grouped.items()}, cameras)
    return cameras


def _view(dets: list[dict]) -> ViewDetections:
    """Predictions of one camera in one frame -> ViewDetections (N, 23, 3), no identities."""
    if not dets:
        return ViewDetections.empty(NUM_JOINTS)
    return ViewDetections(
        np.stack([d["keypoints"] for d in dets]),
        np.stack([d["bbox"] for d in dets]),
        np.array([d["score"] for d in dets]),
        np.full(len(dets), -1),
    )


def evaluate_checkpoint(cfg: DictConfig, out_dir: str | Path) -> dict[str, Any]:
    """Evaluate cfg.checkpoint on cfg.coco2d's set, writing its outputs into out_dir -> {"AP_all", "AR_all", ...}."""
    pose2d, out_dir = cfg.coco2d, Path(out_dir)
    device = resolve_device(pose2d.device, "coco2d.device")
    model, train_cfg = load_trained_model(cfg.checkpoint, device)
    codec = build_codec(train_cfg)
    dataset, ann_file = build_eval_dataset(pose2d, train_cfg, codec)
    sampler = EpochSampler(len(dataset), shuffle=False)
    loader = DataLoader(dataset, batch_size=pose2d.batch_size, sampler=sampler, num_workers=pose2d.num_workers)
    predictions = predict(model, loader, codec, device, pose2d.decode, pose2d.threshold, pose2d.top_m, pose2d.flip_test)
    metrics: dict[str, Any] = {}
    for subset in AP_SUBSETS:
        stats = evaluate_keypoints(dataset.records, predictions, subset) if predictions else {"AP": -1, "AR": -1}
        metrics[f"AP_{subset}"], metrics[f"AR_{subset}"] = stats["AP"], stats["AR"]
    write_coco_results(out_dir / pose2d.results_file, predictions)
    cameras = write_predictions_poses2d(out_dir / pose2d.output, predictions, image_views(ann_file))
    run = dict(checkpoint=str(cfg.checkpoint), ann_file=str(ann_file), crops=len(dataset), decode=pose2d.decode)
    run.update(flip_test=pose2d.flip_test, cameras=cameras)
    atomic_write_text(out_dir / cfg.metrics_file, json.dumps(finite({"metrics": metrics, **run}), indent=2))
    return metrics
