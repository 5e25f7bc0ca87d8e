"""Checks of train.py's config, without torch: a wrong value stops with one ConfigError naming the key."""

from __future__ import annotations

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


def check_train_config(cfg: DictConfig) -> None:
    """One ConfigError naming the key for a trainer, data, loss or optimizer value of the wrong type or range."""
    for key, minimum, nullable in TRAINER_INTS:
        check_int(cfg, key, minimum, nullable)
    check_bool(cfg, "trainer.progress")
    device = value_of(cfg, "trainer.device")
    if device not in ("auto", "cpu"):  # always available: no need to import torch to say so
        from models.devices import resolve_device

        resolve_device(device, "trainer.device")
    size = value_of(cfg, "data.input_size")
    size = OmegaConf.to_container(size) if isinstance(size, ListConfig) else size
    if not (isinstance(size, list) and len(size) == 2 and all(is_int(v) and v > 0 for v in size)):
        fail("data.input_size", size, "must be [width, height] in pixels")
    if any(v % INPUT_MULTIPLE for v in size):
        fail("data.input_size", size, f"width and height must be multiples of {INPUT_MULTIPLE} (FastPose's stride)")
    check_number(cfg, "data.sigma")
    check_number(cfg, "optimizer.lr")
    check_number(cfg, "loss.mu", strict=False)
    check_number(cfg, "loss.foot_weight", strict=False)
