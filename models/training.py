"""Training pieces of the top-down SPPE used by train.py: builders, one epoch, validation, checkpoints, distributed."""

from __future__ import annotations

import logging
import os
import random
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
import torch.distributed as dist
from omegaconf import DictConfig
from torch import nn
from torch.utils.data import DataLoader, Sampler
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from data.config_checks import ConfigError
from data.pose2d.coco_eval import evaluate_keypoints
from data.pose2d.coco_keypoints import load_keypoint_dataset
from data.pose2d.crop_transforms import CropAugmentation
from data.pose2d.records import ImageRecord
from data.pose2d.topdown_dataset import TopDownDataset, denormalize_image
from models.checkpoint_io import read_checkpoint, write_checkpoint
from models.devices import resolve_device
from models.heatmap_codec import MultiModalHeatmapCodec
from models.heatmap_inference import flip_back
from models.pose_decoding import person_scores, single_peaks
from models.show_targets import GREEN, RED, tile_grid, tint
from models.train_config import HEATMAP_STRIDE, INPUT_MULTIPLE

log = logging.getLogger(__name__)

AP_SUBSETS = ("all", "body", "foot")


@dataclass
class TrainState:
    """Where training stands: the epoch in progress (or next), optimizer steps done in it and in all, best AP."""

    epoch: int = 0
    step_in_epoch: int = 0
    global_step: int = 0
    best_ap: float = -1.0


@dataclass
class Validation:
    """Validation outcome: metrics (loss, AP_* and AR_* per subset), COCO-style predictions, a picture."""

    metrics: dict[str, float]
    predictions: list[dict]
    grid: np.ndarray | None


def setup_distributed(device_name: str) -> tuple[int, int, torch.device]:
    """(rank, world size, device); initialises the process group when torchrun set WORLD_SIZE > 1."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1, resolve_device(device_name, "trainer.device")
    rank, local_rank = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    device = resolve_device(device_name, "trainer.device", local_rank)
    if device.type == "cuda":
        torch.cuda.set_device(device)
    dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    return rank, world, device


def build_codec(cfg: DictConfig) -> MultiModalHeatmapCodec:
    """The target codec: input_size and sigma from cfg.data, heatmaps a quarter of the input, mu from cfg.loss."""
    w, h = (int(v) for v in cfg.data.input_size)
    if w % INPUT_MULTIPLE or h % INPUT_MULTIPLE:
        raise ConfigError(f"data.input_size={[w, h]}: must be multiples of {INPUT_MULTIPLE} (FastPose)")
    return MultiModalHeatmapCodec((w, h), (w // HEATMAP_STRIDE, h // HEATMAP_STRIDE), cfg.data.sigma, cfg.loss.mu)


def build_dataset(cfg: DictConfig, codec: MultiModalHeatmapCodec, split: str) -> TopDownDataset:
    """The TopDownDataset of split 'train' (augmented) or 'val' (plain, det boxes if configured)."""
    data, train, part = cfg.data, split == "train", cfg.data[split]
    det_file = None if train else part.get("det_file")
    for path in (part.ann_file, part.image_dir, det_file):
        if path is not None and not Path(path).exists():
            raise FileNotFoundError(f"data.{split}: {path} does not exist (configs/data/ says how to get it)")
    # evaluation on detector boxes keeps every image (detections where nobody is annotated are false
    # positives, as in COCO's protocol); on ground-truth boxes images without a labelled person add nothing
    min_keypoints = data.min_keypoints if train else int(not data.use_det_boxes)
    augment = CropAugmentation(**data.augment) if train and data.get("augment") else None
    return TopDownDataset(
        load_keypoint_dataset(data.kind, part.ann_file, part.image_dir, det_file, min_keypoints=min_keypoints),
        codec,
        tuple(data.input_size),
        augment,
        train=train,
        min_keypoints=data.min_keypoints,
        use_det_boxes=data.use_det_boxes and not train,
        padding=data.padding,
        seed=cfg.trainer.seed,
        cache_size=data.cache_images,
    )


def build_loader(
    dataset: TopDownDataset, batch_size: int, num_workers: int, sampler: Sampler, device: torch.device
) -> DataLoader:
    """A DataLoader in the sampler's order; workers not persistent (the default): each epoch draws its augmentation."""
    return DataLoader(dataset, batch_size, sampler=sampler, num_workers=num_workers, pin_memory=device.type == "cuda")


def train_one_epoch(
    model: nn.Module,
    loader: DataLoader,
    loss_fn: nn.Module,
    optimizer: torch.optim.Optimizer,
    device: torch.device,
    state: TrainState,
    max_steps: int | None = None,
    writer: SummaryWriter | None = None,
    log_every: int = 50,
    progress: bool = False,
) -> list[float]:
    """Train the rest of state.epoch (or up to max_steps), logging every log_every steps -> the loss of each step."""
    model.train()
    losses: list[float] = []
    if max_steps is not None and state.global_step >= max_steps:
        return losses
    bar = tqdm(loader, desc=f"epoch {state.epoch}", disable=not progress, leave=False)
    for batch in bar:
        out = loss_fn(
            model(batch["image"].to(device, non_blocking=True)),
            batch["target"].to(device, non_blocking=True),
            batch["weight"].to(device, non_blocking=True),
        )
        optimizer.zero_grad(set_to_none=True)
        out["loss"].backward()
        optimizer.step()
        state.step_in_epoch += 1
        state.global_step += 1
        losses.append(float(out["loss"].item()))
        bar.set_postfix(loss=f"{losses[-1]:.3g}")
        if writer is not None and state.global_step % log_every == 0:
            for key, value in out.items():
                writer.add_scalar(f"train/{key}", float(value.item()), state.global_step)
            writer.add_scalar("train/lr", optimizer.param_groups[0]["lr"], state.global_step)
        if max_steps is not None and state.global_step >= max_steps:
            break
    return losses


def decode_predictions(codec: MultiModalHeatmapCodec, heatmaps: torch.Tensor, batch: dict) -> list[dict]:
    """Heatmaps (B, 23, h, w) of a batch -> B dicts {image_id, keypoints (23, 3) image px, score, bbox (4,)}."""
    keypoints = single_peaks(codec, heatmaps, batch["affine_inv"])
    scores = person_scores(batch["score"].numpy(), keypoints)
    rows = zip(batch["image_id"], keypoints, scores, batch["box"])
    return [{"image_id": int(i), "keypoints": k, "score": float(s), "bbox": b.numpy()} for i, k, s, b in rows]


def heatmap_grid(
    images: torch.Tensor, targets: torch.Tensor, heatmaps: torch.Tensor, min_width: int = 192
) -> np.ndarray:
    """Crops (N, 3, H, W), targets and heatmaps (N, 23, h, w) -> RGB (rows, cols, 3) uint8, [target | prediction]."""
    tiles = []
    for image, target, heatmap in zip(images, targets, heatmaps):
        rgb = denormalize_image(image)
        factor = max(1, -(-min_width // rgb.shape[1]))
        rgb = cv2.resize(rgb, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST)
        tiles.append(tint(rgb, target.amax(0).cpu().numpy(), GREEN))
        tiles.append(tint(rgb, heatmap.amax(0).clamp(0, 1).cpu().numpy(), RED))
    return tile_grid(tiles, columns=2)


@torch.no_grad()
def validate(
    model: nn.Module,
    loader: DataLoader,
    codec: MultiModalHeatmapCodec,
    records: list[ImageRecord],
    loss_fn: nn.Module,
    device: torch.device,
    grid_images: int = 4,
    progress: bool = False,
    flip_test: bool = False,
) -> Validation:
    """Loss, COCO OKS AP/AR (all, body, foot), AP50/AP75/APm/APl on an unshuffled loader -> Validation."""
    model.eval()
    predictions: list[dict] = []
    total, count, grid = 0.0, 0, None
    for batch in tqdm(loader, desc="validate", disable=not progress, leave=False):
        images = batch["image"].to(device, non_blocking=True)
        heatmaps = model(images)
        target, weight = batch["target"].to(device), batch["weight"].to(device)
        total += float(loss_fn(heatmaps, target, weight)["loss"].item()) * len(heatmaps)
        count += len(heatmaps)
        # with flip_test the scored poses come from the flip-tested heatmaps, the loss and picture from the plain ones
        scored = 0.5 * (heatmaps + flip_back(model(images.flip(-1)))) if flip_test else heatmaps
        predictions += decode_predictions(codec, scored, batch)
        if grid is None and grid_images > 0:
            grid = heatmap_grid(batch["image"][:grid_images], batch["target"][:grid_images], heatmaps[:grid_images])
    metrics = {"loss": total / max(count, 1)}
    for subset in AP_SUBSETS:
        stats = evaluate_keypoints(records, predictions, subset) if predictions else {"AP": -1.0, "AR": -1.0}
        metrics[f"AP_{subset}"], metrics[f"AR_{subset}"] = stats["AP"], stats["AR"]
        if subset == "all":  # the COCO breakdown of the headline number: OKS 0.5 / 0.75, medium / large persons
            metrics.update({f"{k}_all": stats.get(k, -1.0) for k in ("AP50", "AP75", "APm", "APl")})
    return Validation(metrics, predictions, grid)


def save_checkpoint(
    path: str | Path,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    scheduler: Any,
    state: TrainState,
    config: dict,
    choices: dict[str, str] | None = None,
) -> None:
    """Write model, optimizer, scheduler, position, RNG states, config and chosen config groups to path atomically."""
    rng = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if torch.cuda.is_available():
        rng["cuda"] = torch.cuda.get_rng_state_all()
    write_checkpoint(
        {
            "model": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "scheduler": scheduler.state_dict(),
            **asdict(state),
            "rng": rng,
            "config": config,
            "choices": choices,
        },
        path,
        "resume",
    )


def save_weights(
    path: str | Path, model: nn.Module, state: TrainState, metrics: dict[str, float], config: dict
) -> None:
    """Write the model weights with the position, validation metrics and config (no optimizer) atomically."""
    write_checkpoint(
        {"model": model.state_dict(), **asdict(state), "metrics": dict(metrics), "config": config}, path, "weights"
    )


def load_checkpoint(
    checkpoint: str | Path | dict,
    model: nn.Module,
    optimizer: torch.optim.Optimizer | None = None,
    scheduler: Any = None,
    restore_rng: bool = True,
) -> TrainState:
    """Load a :func:`save_checkpoint` file into model, optimizer, scheduler, RNGs -> state."""
    if not isinstance(checkpoint, dict):
        checkpoint = read_checkpoint(checkpoint, "resume")
    model.load_state_dict(checkpoint["model"])
    if optimizer is not None:
        optimizer.load_state_dict(checkpoint["optimizer"])
    if scheduler is not None:
        scheduler.load_state_dict(checkpoint["scheduler"])
    if restore_rng:
        rng = checkpoint["rng"]
        torch.set_rng_state(rng["torch"])
        np.random.set_state(rng["numpy"])
        random.setstate(rng["python"])
        if "cuda" in rng and torch.cuda.is_available():
            torch.cuda.set_rng_state_all(rng["cuda"])
    return TrainState(**{k: checkpoint[k] for k in ("epoch", "step_in_epoch", "global_step", "best_ap")})
