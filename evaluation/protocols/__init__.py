"""Dataset protocols: the benchmarks' own published metrics, built from ``sequence.protocol_inputs``."""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Protocol

from data.multiview import Frame, Sequence
from evaluation.protocols.panoptic import PanopticProtocol
from evaluation.protocols.reprojection_coco import ReprojectionCOCOProtocol
from evaluation.protocols.shelf import ShelfProtocol

if TYPE_CHECKING:
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


BUILDERS: dict[str, Callable] = {  # protocol name in sequence.protocol_inputs -> builder(sequence, **arguments)
    "shelf": lambda sequence, **arguments: ShelfProtocol(**arguments),
    "panoptic": lambda sequence, **arguments: PanopticProtocol(**arguments),
    "reprojection_coco": lambda sequence, **arguments: ReprojectionCOCOProtocol(sequence.rig, **arguments),
}


def attach_protocols(sequence: Sequence) -> Sequence:
    """Build the protocols ``sequence.protocol_inputs`` asks for into ``sequence.protocols`` (once)."""
    if not sequence.protocols:
        for spec in sequence.protocol_inputs:
            arguments = {k: v for k, v in spec.items() if k != "name"}
            if spec["name"] not in BUILDERS:
                raise ValueError(f"unknown dataset protocol {spec['name']!r}; known: {', '.join(BUILDERS)}")
            sequence.protocols.append(BUILDERS[spec["name"]](sequence, **arguments))
    return sequence


__all__ = [
    "BUILDERS",
    "DatasetProtocol",
    "PanopticProtocol",
    "ReprojectionCOCOProtocol",
    "ShelfProtocol",
    "attach_protocols",
]
