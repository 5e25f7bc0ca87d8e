"""The network of a train.py checkpoint with the training config that describes it (input size, padding, codec)."""

from __future__ import annotations

from pathlib import Path

import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torch import nn

from models.checkpoint_io import read_checkpoint


def load_trained_model(path: str | Path, device: torch.device) -> tuple[nn.Module, DictConfig]:
    """The network of a train.py checkpoint or weights file, in eval mode on device, and its training config."""
    checkpoint = read_checkpoint(path)  # a missing or damaged file -> FileNotFoundError / CheckpointError
    train_cfg = OmegaConf.create(checkpoint["config"])
    model = instantiate(train_cfg.model, pretrained=None)  # the weights come from the checkpoint
    model.load_state_dict(checkpoint["model"])
    return model.to(device).eval(), train_cfg
