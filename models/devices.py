"""Torch devices named in configs: auto | cpu | cuda | cuda:N, checked against this machine."""

from __future__ import annotations

import torch

from data.config_checks import fail


def resolve_device(name: str, key: str, local_rank: int = 0) -> torch.device:
    """'auto' (cuda:local_rank if CUDA is available, else cpu), 'cpu', 'cuda', 'cuda:N' -> device; or ConfigError."""
    if name == "auto":
        return torch.device("cuda", local_rank) if torch.cuda.is_available() else torch.device("cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError):
        fail(key, name, "must be auto, cpu, cuda or cuda:N")
    if device.type == "cuda" and not torch.cuda.is_available():
        fail(key, name, "CUDA is not available on this machine (use auto or cpu)")
    if device.type == "cuda" and device.index is not None and device.index >= torch.cuda.device_count():
        fail(key, name, f"this machine has {torch.cuda.device_count()} CUDA device(s)")
    return device
