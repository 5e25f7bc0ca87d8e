"""The training loop of train.py (data, model, optimizer, resume, epochs, validation, checkpoints); also in-process."""

from __future__ import annotations

import json
import logging
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader
from torch.utils.tensorboard import SummaryWriter

from data.formats.atomic_io import atomic_write_text
from data.formats.strict_json import finite
from data.pose2d.coco_eval import write_coco_results
from data.pose2d.topdown_dataset import EpochSampler
from models.checkpoint_io import read_checkpoint
from models.loss import WeightedHeatmapLoss
from models.train_config import check_train_config
from models.training import (
    TrainState,
    build_codec,
    build_dataset,
    build_loader,
    load_checkpoint,
    save_checkpoint,
    save_weights,
    setup_distributed,
    train_one_epoch,
    validate,
)

log = logging.getLogger(__name__)


def _reached(state: TrainState, max_steps: int | None) -> bool:
    """Whether the step budget is used up."""
    return max_steps is not None and state.global_step >= max_steps


@dataclass
class _Run:
    """What the epochs, validations and checkpoints of one run share."""

    cfg: DictConfig
    run_dir: Path
    model: nn.Module
    net: nn.Module  # the model, wrapped by DistributedDataParallel when several processes train
    loss_fn: nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: Any
    device: torch.device
    state: TrainState
    writer: SummaryWriter | None
    rank: int


def run(cfg: DictConfig, run_dir: Path, checkpoint: dict | None = None, choices: dict[str, str] | None = None) -> dict:
    """Train (or resume) into run_dir -> {"losses": {step: loss}, "metrics", "state"}; choices go into checkpoints."""
    check_train_config(cfg)
    if cfg.resume and checkpoint is None:
        checkpoint = read_checkpoint(cfg.resume, "resume")
    trainer, run_dir = cfg.trainer, Path(run_dir)
    rank, world, device = setup_distributed(trainer.device)
    if trainer.threads:
        torch.set_num_threads(trainer.threads)
    random.seed(trainer.seed)
    np.random.seed(trainer.seed)
    torch.manual_seed(trainer.seed)
    codec = build_codec(cfg)
    train_set, val_set = build_dataset(cfg, codec, "train"), build_dataset(cfg, codec, "val")
    if not len(train_set):
        raise ValueError(f"{cfg.data.train.ann_file}: no training person")
    sampler = EpochSampler(len(train_set), trainer.seed, shuffle=True, rank=rank, world_size=world)
    train_loader = build_loader(train_set, trainer.batch_size, trainer.num_workers, sampler, device)
    val_sampler = EpochSampler(len(val_set), shuffle=False)
    val_loader = build_loader(val_set, trainer.val_batch_size, trainer.num_workers, val_sampler, device)
    model = instantiate(cfg.model).to(device)  # e.g. models.fastpose.FastPose
    loss_fn = WeightedHeatmapLoss(cfg.loss.foot_weight)  # Eq. 1's lambda; mu is in the codec
    optimizer = instantiate(cfg.optimizer, _convert_="all")(params=model.parameters())
    scheduler = instantiate(cfg.scheduler, _convert_="all")(optimizer=optimizer)  # stepped per epoch
    state = load_checkpoint(checkpoint, model, optimizer, scheduler) if checkpoint else TrainState()
    net = DistributedDataParallel(model, device_ids=[device] if device.type == "cuda" else None) if world > 1 else model
    writer = SummaryWriter(str(run_dir)) if rank == 0 else None
    r = _Run(cfg, run_dir, model, net, loss_fn, optimizer, scheduler, device, state, writer, rank)
    config = OmegaConf.to_container(cfg, resolve=True)
    sizes = (len(train_set), len(val_set), device, world, state.epoch, state.global_step)
    log.info("%d training crops, %d validation crops, device %s x %d, from epoch %d step %d", *sizes)
    losses: dict[int, float] = {}
    metrics: dict[str, float] = {}
    while state.epoch < trainer.epochs and not _reached(state, trainer.max_steps):
        finished = _epoch(r, train_loader, losses)
        if finished:
            scheduler.step()
        last = state.epoch >= trainer.epochs or _reached(state, trainer.max_steps)
        if rank == 0:
            if last or (finished and state.epoch % trainer.val_every == 0):
                metrics = _validate(r, val_loader)
            _save(r, config, metrics, choices)
        if world > 1:
            dist.barrier()
    if writer is not None:
        writer.close()
    if world > 1:
        dist.destroy_process_group()
    return {"losses": losses, "metrics": metrics, "state": state}


def _epoch(r: _Run, loader: DataLoader, losses: dict[int, float]) -> bool:
    """Train the rest of the current epoch (or up to max_steps), adding {global step: loss} to losses -> finished."""
    trainer, state = r.cfg.trainer, r.state
    loader.dataset.set_epoch(state.epoch)
    loader.sampler.set_epoch(state.epoch, start=state.step_in_epoch * trainer.batch_size)
    remaining, first_step, progress = len(loader), state.global_step + 1, trainer.progress and r.rank == 0
    epoch_losses = train_one_epoch(
        r.net, loader, r.loss_fn, r.optimizer, r.device, state, trainer.max_steps, r.writer, trainer.log_every, progress
    )
    losses.update(zip(range(first_step, state.global_step + 1), epoch_losses))
    finished = len(epoch_losses) == remaining
    if finished:
        state.epoch, state.step_in_epoch = state.epoch + 1, 0
    args = (state.epoch - finished, "" if finished else " (stopped)", np.mean(epoch_losses) if epoch_losses else np.nan)
    log.info("epoch %d%s: mean loss %.6g over %d steps (global step %d)", *args, len(epoch_losses), state.global_step)
    return finished


def _validate(r: _Run, loader: DataLoader) -> dict[str, float]:
    """Validate, log to TensorBoard, write the predictions JSON -> the metrics."""
    dataset, writer, step = loader.dataset, r.writer, r.state.global_step
    t = r.cfg.trainer  # val_flip_test: absent from a resumed run stored before the key existed
    flip = t.get("val_flip_test", False)
    result = validate(
        r.model, loader, dataset.codec, dataset.records, r.loss_fn, r.device, t.grid_images, t.progress, flip
    )
    for key, value in result.metrics.items():
        writer.add_scalar(f"val/{key}", value, step)
    if result.grid is not None:
        writer.add_image("val/heatmaps", result.grid, step, dataformats="HWC")
    writer.flush()
    write_coco_results(r.run_dir / r.cfg.predictions_file, result.predictions)
    latest = {"metrics": result.metrics, "step": step, "epoch": r.state.epoch}  # for sweep tables
    atomic_write_text(r.run_dir / "metrics.json", json.dumps(finite(latest), indent=2))
    log.info("validation at step %d: %s", step, ", ".join(f"{k} {v:.4f}" for k, v in result.metrics.items()))
    return result.metrics


def _save(r: _Run, config: dict, metrics: dict[str, float], choices: dict[str, str] | None) -> None:
    """Write checkpoints/last.ckpt, and best.pth when the latest validation beat the best AP (all joints)."""
    folder, state = r.run_dir / r.cfg.checkpoint_dir, r.state
    improved = metrics.get("AP_all", -1.0) > state.best_ap
    if improved:
        state.best_ap = metrics["AP_all"]
    save_checkpoint(folder / "last.ckpt", r.model, r.optimizer, r.scheduler, state, config, choices)
    if improved:
        save_weights(folder / "best.pth", r.model, state, metrics, config)
