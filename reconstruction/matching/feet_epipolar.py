"""Feet assignment with epipolar evidence from the other joints (``matching=feet_epipolar``)."""

from __future__ import annotations

from collections import Counter

import numpy as np

from data.geometry.camera import Rig
from data.multiview import ViewDetections
from reconstruction.matching.epipolar import TOO_FEW_JOINTS, epipolar_affinity, fundamentals, undistorted_joints
from reconstruction.matching.feet import NO_COUNTERPART, FeetMatcher
from reconstruction.matching.merge import match_pairs
from reconstruction.results import Matches


def combined_cost(
    feet_cost: np.ndarray,
    epipolar_px: np.ndarray,
    epipolar_sigma_px: float,
    missing_feet: np.ndarray | None = None,
    missing_feet_cost: float | None = None,
) -> np.ndarray:
    """sqrt(feet^2 + (epipolar / sigma)^2): (Na, Nb) SD, (Na, Nb) px -> (Na, Nb), inf where either is."""
    if missing_feet is not None and missing_feet_cost is not None:
        feet_cost = np.where(missing_feet, missing_feet_cost, feet_cost)
    with np.errstate(invalid="ignore"):
        cost = np.sqrt(np.square(feet_cost) + np.square(epipolar_px / epipolar_sigma_px))
    return np.where(np.isfinite(feet_cost) & np.isfinite(epipolar_px), cost, np.inf)


class FeetEpipolarMatcher:
    """Feet + epipolar matching: ``matcher(views, rig) -> Matches``; feet: FeetMatcher keys (its gate unused)."""

    def __init__(
        self,
        *,
        epipolar_sigma_px: float = 5.0,
        gate: float = 5.0,
        min_score: float = 0.2,
        min_common_joints: int = 3,
        min_views: int = 2,
        missing_feet_cost: float | None = None,
        feet: dict | None = None,
        margin: float = 0.0,
    ) -> None:
        feet = {"pixel_sigma": 5.0, **(feet or {})}
        if feet.get("location_metric", "mahalanobis") != "mahalanobis" or feet.get("space", "ground") != "ground":
            raise ValueError(
                "feet_epipolar needs the feet cost in standard deviations: location_metric=mahalanobis, space=ground"
            )
        if not epipolar_sigma_px > 0 or not gate > 0 or int(min_common_joints) < 1 or int(min_views) < 1:
            raise ValueError("epipolar_sigma_px and gate must be > 0, min_common_joints and min_views >= 1")
        if not margin >= 0:
            raise ValueError(f"margin must be >= 0, got {margin}")
        if missing_feet_cost is not None and not missing_feet_cost >= 0:
            raise ValueError(f"missing_feet_cost must be >= 0 or None, got {missing_feet_cost}")
        self.missing_feet_cost = None if missing_feet_cost is None else float(missing_feet_cost)
        self.feet = FeetMatcher(min_views=min_views, **feet)
        self.epipolar_sigma_px, self.gate, self.margin = float(epipolar_sigma_px), float(gate), float(margin)
        self.min_score, self.min_common_joints = float(min_score), int(min_common_joints)
        self.min_views = int(min_views)

    def pair_costs(self, views: list[ViewDetections], rig: Rig):
        """The pair cost function of one frame: V views -> ((a, b) -> (N_a, N_b) combined cost), feet, joints."""
        feats = self.feet.features(views, rig)
        joints = [undistorted_joints(v, cam, self.min_score) for v, cam in zip(views, rig)]
        F = fundamentals(rig)

        def cost(a: int, b: int) -> np.ndarray:
            feet = self.feet.pair_cost(feats[a], feats[b], rig[a])
            epi = epipolar_affinity(*joints[a], *joints[b], F[a, b], self.min_common_joints)
            missing = ~feats[a].has_p[:, None] | ~feats[b].has_p[None, :]
            return combined_cost(feet, epi, self.epipolar_sigma_px, missing, self.missing_feet_cost)

        return cost, feats, joints

    def __call__(self, views: list[ViewDetections], rig: Rig) -> Matches:
        """Assignment of one frame: V views -> Matches, (P, V) detection indices (-1 where absent)."""
        cost, feats, joints = self.pair_costs(views, rig)
        assignment = match_pairs(cost, [len(v) for v in views], self.gate, self.min_views, self.margin)
        reasons: Counter[str] = Counter()
        usable = 0
        for f, (_, ok) in zip(feats, joints):
            enough = ok.sum(axis=1) >= self.min_common_joints
            no_feet = ~f.has_p if self.missing_feet_cost is None else np.zeros(len(f), dtype=bool)
            reasons.update(str(r) for r in f.reason[no_feet] if r)  # feet required and missing
            reasons[TOO_FEW_JOINTS] += int(np.sum(~no_feet & ~enough))
            usable += int(np.sum(~no_feet & enough))
        reasons[NO_COUNTERPART] = usable - int(np.sum(assignment >= 0))
        return Matches(assignment, +reasons)
