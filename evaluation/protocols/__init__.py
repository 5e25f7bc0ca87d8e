"""Dataset protocols (layer 4): the benchmarks' own published metrics, beside the generic evaluation.

``base`` holds the interface (``DatasetProtocol``); ``shelf`` the Shelf PCP protocol (and 4D
Association's stored output scored the same way); ``panoptic`` the Panoptic AP / MPJPE protocol;
``reprojection_coco`` the COCO AP/AR of reprojected 3D poses (Wildtrack, paper Table 1).

A dataset loader (layer 2) may not import these: it lists the plain-data inputs of its protocols in
``sequence.protocol_inputs`` (``[{"name": ..., **arguments}]``) and :func:`attach_protocols`
builds them into ``sequence.protocols``. eval.py calls it after loading; ``evaluate_sequence`` calls it
too (it is idempotent), so a sequence built in code is scored the same way.

May import every lower layer (``data``, the stages) and the rest of ``evaluation``.
"""

from __future__ import annotations

from typing import Callable

from data.multiview import Sequence
from evaluation.protocols.panoptic import PanopticProtocol
from evaluation.protocols.reprojection_coco import ReprojectionCOCOProtocol
from evaluation.protocols.shelf import ShelfProtocol

# protocol name in protocol_inputs -> builder(sequence, **arguments)
BUILDERS: dict[str, Callable] = {
    "shelf": lambda sequence, **arguments: ShelfProtocol(**arguments),
    "panoptic": lambda sequence, **arguments: PanopticProtocol(**arguments),
    "reprojection_coco": lambda sequence, **arguments: ReprojectionCOCOProtocol(sequence.rig, **arguments),
}


def attach_protocols(sequence: Sequence) -> Sequence:
    """Build the protocols ``sequence.protocol_inputs`` asks for into ``sequence.protocols``, once.

    A sequence that already carries protocols is left as it is. Returns the sequence.
    """
    if not sequence.protocols:
        for spec in sequence.protocol_inputs:
            arguments = {k: v for k, v in spec.items() if k != "name"}
            if spec["name"] not in BUILDERS:
                raise ValueError(f"unknown dataset protocol {spec['name']!r}; known: {', '.join(BUILDERS)}")
            sequence.protocols.append(BUILDERS[spec["name"]](sequence, **arguments))
    return sequence


__all__ = ["BUILDERS", "PanopticProtocol", "ReprojectionCOCOProtocol", "ShelfProtocol", "attach_protocols"]
