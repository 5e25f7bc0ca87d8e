"""The typed results the per-frame stages hand each other: Matches, Reconstruction, SkeletonPrior."""

from __future__ import annotations

from collections import Counter
from typing import NamedTuple

import numpy as np


def joint_sources(scores: np.ndarray, views: np.ndarray, smoothed: np.ndarray) -> np.ndarray:
    """Each output joint's source (poses_io.JOINT_SOURCES codes): scores, views (P, J), smoothed (P,) -> (P, J) int8."""
    fewer = np.where(np.asarray(smoothed, dtype=bool)[:, None], 3, 2)
    return np.where(scores <= 0, 0, np.where(views >= 2, 1, fewer)).astype(np.int8)


class Matches(NamedTuple):
    """A matcher's answer for one frame."""

    assignment: np.ndarray  # (P, V) int, the detection index of person p in view v or -1
    unmatched: Counter[str]  # this frame's detections left out of every person, counted by reason


class Reconstruction(NamedTuple):
    """A reconstruction's answer for one frame; each joint's provenance is the pipeline's (FrameResult)."""

    poses: np.ndarray  # (P, J, 4) x, y, z (m) and score
    joint_variance: np.ndarray | None = None  # (P, J) m^2 of each joint's estimate; None where the stage has none
    bone_lengths: np.ndarray | None = None  # (P, L) m measured in this frame, NaN unmeasured; None: not measured


class SkeletonPrior(NamedTuple):
    """A tracker's bone lengths for a frame's persons; the MAP combines them with the frame's own by precision."""

    lengths: np.ndarray  # (P, L) m, the median over each person's track (NaN where it offers none)
    standard_errors: np.ndarray  # (P, L) m (inf there)
