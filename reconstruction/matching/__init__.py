"""Cross-view person matching (layer 3; paper section 3.2): ``matcher(views, rig) -> Matches(assignment,
unmatched)``, assignment (P, V) the detection index of person p in view v or -1, unmatched the frame's left-out
detections by reason. Each matcher is a callable class configured from ``configs/matching/*.yaml``; may import
``data`` and the other stages, never ``evaluation`` or the entry points.
"""

from reconstruction.matching.epipolar import EpipolarMatcher
from reconstruction.matching.evidence import EvidenceMatcher
from reconstruction.matching.feet import FeetMatcher
from reconstruction.matching.feet_epipolar import FeetEpipolarMatcher
from reconstruction.matching.oracle import OracleMatcher
from reconstruction.matching.ransac import RansacMatcher

__all__ = ["EpipolarMatcher", "EvidenceMatcher", "FeetEpipolarMatcher", "FeetMatcher", "OracleMatcher", "RansacMatcher"]
