"""Cross-view person matching (layer 3; paper section 3.2). A matcher maps the detections of one frame to
persons: ``matcher(views, rig) -> assignment`` with assignment (P, V) int, the detection index of person p
in view v or -1. Each matcher is a small callable class configured from ``configs/matching/*.yaml``.
May import ``data`` (layers 1-2) and the other stages; never ``evaluation`` or the entry points.
"""

from data.assignment import assignment_from_labels
from reconstruction.matching.epipolar import EpipolarMatcher
from reconstruction.matching.evidence import EvidenceMatcher
from reconstruction.matching.feet import FeetMatcher
from reconstruction.matching.feet_epipolar import FeetEpipolarMatcher
from reconstruction.matching.oracle import OracleMatcher
from reconstruction.matching.ransac import RansacMatcher

__all__ = [
    "EpipolarMatcher",
    "EvidenceMatcher",
    "FeetEpipolarMatcher",
    "FeetMatcher",
    "OracleMatcher",
    "RansacMatcher",
    "assignment_from_labels",
]
