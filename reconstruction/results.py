"""The typed results the per-frame stages hand each other: a matcher's :class:`Matches`, a reconstruction's
:class:`Reconstruction`, and the skeleton prior a tracker offers the MAP (:class:`SkeletonPrior`)."""

from __future__ import annotations

from collections import Counter
from typing import NamedTuple

import numpy as np


def joint_sources(scores: np.ndarray, views: np.ndarray, smoothed: np.ndarray) -> np.ndarray:
    """Where each output joint came from, codes into data.formats.poses_io.JOINT_SOURCES: scores (P, J), views
    (P, J) int, smoothed (P,) bool -> (P, J) int8. none: score 0 (not output); views: triangulated from 2+ views; fewer views: motion on a
    person the tracker's motion model weighed in, else prior (the reconstruction's bone prior and fitted body)."""
    fewer = np.where(np.asarray(smoothed, dtype=bool)[:, None], 3, 2)
    return np.where(scores <= 0, 0, np.where(views >= 2, 1, fewer)).astype(np.int8)


class Matches(NamedTuple):
    """A matcher's answer for one frame: assignment (P, V) int, the detection index of person p in view v or -1;
    unmatched, this frame's detections left out of every person, counted by reason."""

    assignment: np.ndarray
    unmatched: Counter[str]


class Reconstruction(NamedTuple):
    """A reconstruction's answer for one frame: poses (P, J, 4) x, y, z (m) and score; joint_variance (P, J) m^2 of
    each joint's estimate (None where the stage has none); bone_lengths (P, L) m measured in this frame (NaN where
    unmeasured; None where the stage measures none). Each joint's provenance is the pipeline's (FrameResult)."""

    poses: np.ndarray
    joint_variance: np.ndarray | None = None
    bone_lengths: np.ndarray | None = None


class SkeletonPrior(NamedTuple):
    """A tracker's bone lengths for the persons of a frame: lengths (P, L) m, the median over each person's track (NaN
    where it offers none), and their standard errors (P, L) m (inf there); the MAP combines them with the frame's own
    estimate by precision."""

    lengths: np.ndarray
    standard_errors: np.ndarray
