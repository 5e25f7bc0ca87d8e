"""Dataset protocols: the benchmark-specific metrics attached to a Sequence (see :mod:`evaluation.protocols`)."""

from __future__ import annotations

from typing import Protocol

from data.multiview import Frame
from reconstruction.pipeline import FrameResult


class DatasetProtocol(Protocol):
    """A benchmark's own metrics: ``name``, ``update(frame, result)``, ``summary()``, ``report()``."""

    name: str

    def update(self, frame: Frame, result: FrameResult) -> None:
        """Score one reconstructed frame."""

    def summary(self) -> dict:
        """The metrics (JSON-serialisable) after the last frame."""

    def report(self) -> str:
        """The console tables, each labelled with its protocol."""
