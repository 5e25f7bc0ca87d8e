"""Eq. 1 of the paper: the body/foot weighted heatmap MSE."""

from __future__ import annotations

import torch
from torch import nn

from data.keypoints import BODY_JOINTS, FOOT_JOINTS, NUM_JOINTS


class WeightedHeatmapLoss(nn.Module):
    """Per-channel heatmap MSE (B, 23, h, w), Eq. 1: (17 body + 6 lambda foot) / (17 + 6 lambda)."""

    def __init__(self, foot_weight: float = 1.5) -> None:
        super().__init__()
        self.foot_weight = float(foot_weight)

    def forward(self, pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> dict[str, torch.Tensor]:
        """pred, target (B, 23, h, w), weight (B, 23) -> {"loss", "body", "foot"} scalar tensors."""
        if pred.shape != target.shape or pred.ndim != 4 or pred.shape[1] != NUM_JOINTS:
            raise ValueError(
                f"pred {tuple(pred.shape)} and target {tuple(target.shape)} must both be (B, {NUM_JOINTS}, h, w)"
            )
        if weight.shape != pred.shape[:2]:
            raise ValueError(f"weight {tuple(weight.shape)} must be (B, {NUM_JOINTS})")
        channel_mse = ((pred - target) ** 2).mean(dim=(2, 3)) * weight.to(pred.dtype)
        body = channel_mse[:, list(BODY_JOINTS)].mean()
        foot = channel_mse[:, list(FOOT_JOINTS)].mean()
        n_body, n_foot, lam = len(BODY_JOINTS), len(FOOT_JOINTS), self.foot_weight
        loss = (n_body * body + n_foot * lam * foot) / (n_body + n_foot * lam)
        return {"loss": loss, "body": body, "foot": foot}
