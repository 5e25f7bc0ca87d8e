"""Checks of train.py's config, without torch: a wrong type or range stops with one ConfigError naming the
key before torch, the data or the model are loaded."""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from data.config_checks import check_bool, check_int, check_number, fail, is_int, value_of

HEATMAP_STRIDE = 4  # FastPose's output stride
INPUT_MULTIPLE = 32  # FastPose's trunk stride: the input width and height must be multiples of it
TRAINER_INTS = (  # (key, minimum, may be null)
    ("trainer.epochs", 1, False),
    ("trainer.max_steps", 1, True),
    ("trainer.batch_size", 1, False),
    ("trainer.val_batch_size", 1, False),
    ("trainer.num_workers", 0, False),
    ("trainer.seed", 0, False),
    ("trainer.threads", 1, True),
    ("trainer.log_every", 1, False),
    ("trainer.val_every", 1, False),
    ("trainer.grid_images", 0, False),
)


def _plain(value: Any) -> Any:
    """Containers as plain python."""
    return OmegaConf.to_container(value) if isinstance(value, (DictConfig, ListConfig)) else value


def check_device(cfg: DictConfig, key: str) -> None:
    """cfg[key] names a device this machine has: auto, cpu, cuda, cuda:N (N < the CUDA device count)."""
    name = value_of(cfg, key)
    if name in ("auto", "cpu"):  # always available: no need to import torch to say so
        return
    from models.devices import resolve_device

    resolve_device(name, key)


def check_input_size(cfg: DictConfig, key: str = "data.input_size") -> None:
    """cfg[key] is [w, h], positive multiples of INPUT_MULTIPLE (what FastPose's strides need)."""
    size = _plain(value_of(cfg, key))
    if not (isinstance(size, list) and len(size) == 2 and all(is_int(v) and v > 0 for v in size)):
        fail(key, size, "must be [width, height] in pixels")
    if any(v % INPUT_MULTIPLE for v in size):
        fail(key, size, f"width and height must be multiples of {INPUT_MULTIPLE} (FastPose's stride)")


def check_train_config(cfg: DictConfig) -> None:
    """Stop with one ConfigError naming the key when a trainer, data, loss or optimizer value is of the wrong
    type or range (before any data is read)."""
    for key, minimum, nullable in TRAINER_INTS:
        check_int(cfg, key, minimum, nullable)
    check_bool(cfg, "trainer.progress")
    check_device(cfg, "trainer.device")
    check_input_size(cfg)
    check_number(cfg, "data.sigma")
    check_number(cfg, "optimizer.lr")
    check_number(cfg, "loss.mu", strict=False)
    check_number(cfg, "loss.foot_weight", strict=False)
