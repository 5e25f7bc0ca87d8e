"""2D evaluation of a train.py checkpoint on a COCO-format keypoint set (``python eval.py checkpoint=...``).

The checkpoint (``last.ckpt`` or ``best.pth``) holds its training config, which rebuilds the network and
the target codec (input size, sigma). Every person box (ground truth, or a detections file's) is cropped
without augmentation and decoded either with one peak per joint (``decode=single``, as train.py's
validation) or as the paper's joint-candidate SPPE does (``decode=association``): up to ``top_m`` local
maxima per joint (models.candidates), then CrowdPose's global joint association over all boxes of an
image (models.joint_association), so two boxes never claim one joint. Outputs: COCO OKS AP/AR (all 23,
body 17, foot 6) through data.pose2d.coco_eval, the COCO results file and poses2d.json for the
multi-view pipeline (``eval.py dataset=files dataset.poses2d=...``). An image entry of the annotation
file may carry ``frame`` and ``camera``; without them the frame is the image id and the camera "0".
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torch import nn
from torch.utils.data import DataLoader

from data.formats.atomic_io import atomic_write_text
from data.formats.poses2d_io import write_poses2d
from data.keypoints import NUM_JOINTS
from data.multiview import ViewDetections
from data.pose2d.coco_eval import evaluate_keypoints, write_coco_results
from data.pose2d.coco_keypoints import load_keypoint_dataset
from data.pose2d.topdown_dataset import EpochSampler, TopDownDataset
from models.candidates import candidates_to_image, find_candidates
from models.checkpoint_io import read_checkpoint
from models.heatmap_codec import MultiModalHeatmapCodec
from models.joint_association import associate_joints
from models.training import AP_SUBSETS, build_codec, decode_predictions, select_device

DECODERS = ("single", "association")


def load_trained_model(path: str | Path, device: torch.device) -> tuple[nn.Module, DictConfig]:
    """The network of a train.py checkpoint or weights file, in eval mode on device, and its training config."""
    checkpoint = read_checkpoint(path)  # a missing or damaged file -> FileNotFoundError / CheckpointError
    train_cfg = OmegaConf.create(checkpoint["config"])
    model = instantiate(train_cfg.model, pretrained=None)  # the weights come from the checkpoint
    model.load_state_dict(checkpoint["model"])
    return model.to(device).eval(), train_cfg


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
    dataset = TopDownDataset(
        records,
        codec,
        tuple(data.input_size),
        augment=None,
        train=False,
        use_det_boxes=det_file is not None,
        padding=data.padding,
        cache_size=0,
    )
    return dataset, ann_file


def decode_candidates(
    codec: MultiModalHeatmapCodec, heatmaps: torch.Tensor, batch: dict, threshold: float, top_m: int
) -> list[dict]:
    """Heatmaps (B, 23, h, w) of a batch -> B crops {image_id, box (4,), score, candidates (23, M, 3) x, y,
    score in image pixels}: the top-M local maxima of each joint channel."""
    xy, scores = find_candidates(heatmaps, threshold=threshold, top_m=top_m)
    stride = np.array(codec.input_size, dtype=np.float64) / np.array(codec.heatmap_size)
    image_xy = candidates_to_image(xy, batch["affine_inv"].numpy(), stride)
    return [
        {
            "image_id": int(batch["image_id"][i]),
            "box": batch["box"][i].numpy(),
            "score": float(batch["score"][i]),
            "candidates": np.concatenate([image_xy[i], scores[i, ..., None]], -1),
        }
        for i in range(len(xy))
    ]


def associate_crops(crops: list[dict]) -> list[dict]:
    """Crops of :func:`decode_candidates` -> one prediction per crop {image_id, keypoints (23, 3), score, bbox},
    joints assigned by the global joint association over the crops of each image; order kept."""
    by_image: dict[int, list[int]] = defaultdict(list)
    for i, crop in enumerate(crops):
        by_image[crop["image_id"]].append(i)
    out: list[dict | None] = [None] * len(crops)
    for indices in by_image.values():
        cands = np.stack([crops[i]["candidates"] for i in indices])  # (P, 23, M, 3)
        boxes = np.stack([crops[i]["box"] for i in indices])
        keypoints = associate_joints(cands[..., :2], cands[..., 2], boxes)  # (P, 23, 3)
        for i, kps in zip(indices, keypoints):
            out[i] = {
                "image_id": crops[i]["image_id"],
                "keypoints": kps,
                "bbox": crops[i]["box"],
                "score": crops[i]["score"] * float(kps[:, 2].mean()),
            }
    return out  # type: ignore[return-value]


@torch.no_grad()
def predict(
    model: nn.Module,
    loader: DataLoader,
    codec: MultiModalHeatmapCodec,
    device: torch.device,
    decode: str = "association",
    threshold: float = 0.1,
    top_m: int = 3,
) -> list[dict]:
    """Predictions {image_id, keypoints (23, 3), score, bbox (4,)} for every crop of the loader, in its order."""
    if decode not in DECODERS:
        raise ValueError(f"decode must be one of {DECODERS}, got {decode!r}")
    predictions, crops = [], []
    for batch in loader:
        heatmaps = model(batch["image"].to(device)).float().cpu()
        if decode == "single":
            predictions += decode_predictions(codec, heatmaps, batch)
        else:
            crops += decode_candidates(codec, heatmaps, batch, threshold, top_m)
    return predictions if decode == "single" else associate_crops(crops)


def image_views(ann_file: Path) -> dict[int, tuple[int, str]]:
    """{image id: (frame, camera)} of an annotation file's images: their 'frame' and 'camera' keys, else
    (image id, "0")."""
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
    frames = {f: [_view(dets) for dets in per_camera] for f, per_camera in grouped.items()}
    write_poses2d(path, frames, cameras)
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
    """Evaluate cfg.checkpoint on cfg.coco2d's set; write the COCO results, poses2d.json and metrics.json
    into out_dir -> {"AP_all", "AR_all", "AP_body", ...} (-1 where the set has no such joint)."""
    pose2d, out_dir = cfg.coco2d, Path(out_dir)
    device = select_device(pose2d.device)
    model, train_cfg = load_trained_model(cfg.checkpoint, device)
    codec = build_codec(train_cfg)
    dataset, ann_file = build_eval_dataset(pose2d, train_cfg, codec)
    loader = DataLoader(
        dataset,
        batch_size=pose2d.batch_size,
        sampler=EpochSampler(len(dataset), shuffle=False),
        num_workers=pose2d.num_workers,
    )
    predictions = predict(model, loader, codec, device, pose2d.decode, pose2d.threshold, pose2d.top_m)
    metrics: dict[str, Any] = {}
    for subset in AP_SUBSETS:
        stats = evaluate_keypoints(dataset.records, predictions, subset) if predictions else {"AP": -1, "AR": -1}
        metrics[f"AP_{subset}"], metrics[f"AR_{subset}"] = stats["AP"], stats["AR"]
    write_coco_results(out_dir / pose2d.results_file, predictions)
    cameras = write_predictions_poses2d(out_dir / pose2d.output, predictions, image_views(ann_file))
    atomic_write_text(
        out_dir / cfg.metrics_file,
        json.dumps(
            {
                "metrics": metrics,
                "checkpoint": str(cfg.checkpoint),
                "ann_file": str(ann_file),
                "crops": len(dataset),
                "decode": pose2d.decode,
                "cameras": cameras,
            },
            indent=2,
        ),
    )
    return metrics
