"""The errors of reading a training checkpoint or pretrained weights, in a module without torch, so that
train.py can catch them before it imports torch (a bad config value stops in about a second)."""

from __future__ import annotations


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used; the message names the file."""


class WeightsUnavailable(ValueError):
    """Pretrained weights that cannot be had here (no network for the download, an unreadable file)."""
