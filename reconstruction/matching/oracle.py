"""The oracle matcher: detections grouped by their ground-truth identity (the ablations' upper bound)."""

from __future__ import annotations

from collections import Counter

import numpy as np

from data.assignment import assignment_from_labels
from data.geometry.camera import Rig
from data.multiview import ViewDetections
from reconstruction.results import Matches


class OracleMatcher:
    """Group detections by ``person_ids``; false positives (id -1) stay unmatched."""

    def __init__(self, min_views: int = 2) -> None:
        self.min_views = min_views

    def __call__(self, views: list[ViewDetections], rig: Rig) -> Matches:
        """Assignment of one frame: V views -> Matches, (P, V) detection indices (-1 where absent)."""
        if sum(len(v) for v in views) and all(np.all(v.person_ids < 0) for v in views):
            raise ValueError(
                "matching=oracle needs ground-truth identities (person_ids), "
                "and this dataset has none; choose another matcher"
            )
        return Matches(assignment_from_labels([v.person_ids for v in views], self.min_views), Counter())
