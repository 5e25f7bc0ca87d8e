"""Heatmaps of a batch of person crops: the network in chunks, optional flip test, float16 autocast on CUDA."""

from __future__ import annotations

import torch
from torch import nn

from data.keypoints import NUM_JOINTS, flip_permutation


def flip_back(heatmaps: torch.Tensor) -> torch.Tensor:
    """Heatmaps (B, 23, h, w) of mirrored crops -> those of the crops (no one-pixel shift: models/heatmap_codec.py)."""
    if heatmaps.shape[1] != NUM_JOINTS:
        raise ValueError(f"flip test needs {NUM_JOINTS} COCO-23 channels, the network gives {heatmaps.shape[1]}")
    return heatmaps.flip(-1).index_select(1, torch.as_tensor(flip_permutation(), device=heatmaps.device))


@torch.no_grad()
def predict_heatmaps(
    model: nn.Module, crops: torch.Tensor, batch_size: int = 32, flip_test: bool = True, amp: bool = False
) -> torch.Tensor:
    """Normalised crops (B, 3, H, W) on the model's device -> float32 heatmaps (B, 23, H/4, W/4) there."""
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    use_amp = bool(amp) and crops.device.type == "cuda"
    out = []
    for chunk in crops.split(batch_size):
        images = torch.cat([chunk, chunk.flip(-1)]) if flip_test else chunk
        with torch.autocast("cuda", dtype=torch.float16, enabled=use_amp):
            heatmaps = model(images).float()
        if flip_test:
            heatmaps = (heatmaps[: len(chunk)] + flip_back(heatmaps[len(chunk) :])) / 2
        out.append(heatmaps)
    return torch.cat(out)  # split gives one empty chunk for no crops: the model maps it to (0, 23, h, w)
