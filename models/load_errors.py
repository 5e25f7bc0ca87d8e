"""Errors of reading checkpoints or pretrained weights, without torch: train.py catches them before importing it."""

from __future__ import annotations


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used; the message names the file."""


class WeightsUnavailable(ValueError):
    """Pretrained weights that cannot be had here (no network for the download, an unreadable file)."""
