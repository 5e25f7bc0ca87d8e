"""Cross-view person matching (layer 3; Sec. 3.2): configs/matching/*.yaml's ``matcher(views, rig) -> Matches``."""

from reconstruction.matching.epipolar import EpipolarMatcher
from reconstruction.matching.evidence import EvidenceMatcher
from reconstruction.matching.feet import FeetMatcher
from reconstruction.matching.feet_epipolar import FeetEpipolarMatcher
from reconstruction.matching.oracle import OracleMatcher
from reconstruction.matching.ransac import RansacMatcher

__all__ = ["EpipolarMatcher", "EvidenceMatcher", "FeetEpipolarMatcher", "FeetMatcher", "OracleMatcher", "RansacMatcher"]
