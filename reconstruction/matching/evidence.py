"""The default matcher (``matching=evidence``): every pair judged by all the evidence its two detections share.

For detections i (view a) and j (view b) the evidence is a chi-square in the units of the 2D noise model:

- feet: the squared Mahalanobis distance of their feet midpoints on the ground plane, the covariance
  propagated from pixel noise (:mod:`.feet_uncertainty`, as ``matching=feet``): 2 degrees of freedom
  when both have a usable foot (toe, heel or the ankle fallback);
- body: for every joint both see, the Sampson distance of the two pixels to the epipolar geometry,
  e^2 / (s_b^2 |F x_a|_12^2 + s_a^2 |F^T x_b|_12^2), e = x_b^T F x_a, with each joint's pixel sigma
  s = max(sigma_min, sqrt(sigma_px^2 + (c sqrt(box area))^2) / score^score_power) (the 2D model of the
  MAP, fitted to Shelf's OpenPose errors by benchmarks/fit_sigma_model.py): 1 degree of freedom each,
  capped at outlier_sd^2 (in variances of the model) so that a swapped or hidden joint counts as one
  bad joint, not as a wrong person.

Under "same person" the sum D^2 is chi^2 with dof = 2 [feet] + common joints, so the gate is the test
D^2 <= chi^2_{1 - reject_rate}(dof): a pair sharing 3 joints and one sharing 20 are judged on the same
scale, a detection without feet is matched by its body and one without a visible body by its feet.
Pairs with fewer than ``min_dof`` degrees of freedom are never matched. The assignment cost is the
negative log-likelihood ratio of "same" against "unrelated", 0.5 D^2 - evidence_per_dof * dof, so among
pairs that pass, more agreeing evidence is preferred. Per view pair a Jonker-Volgenant assignment, then
the model's noise is first scaled to the frame's (the median chi^2 per dof of the pairs a loose test
assigns), then persons are merged cheapest edge first with complete linkage: two partial persons join only when every
cross pair of their detections passes the test with the noise widened by ``link_scale`` (a true person
seen in 10 views has 45 pairs, a few of which fail the edge test by chance) and no view would hold two,
so a cluster whose members disagree is never formed: a detection is left unmatched rather than merged
wrongly.

The body term is computed in compiled loops (:mod:`.evidence_kernels`) that stop as soon as a pair
fails (the feet term first), so the unrelated pairs of a crowd cost a joint or two each.
"""

from __future__ import annotations

from collections import Counter
from functools import lru_cache
from itertools import combinations

import numpy as np
from scipy.special import gammaincinv

from data.geometry.camera import Rig
from data.multiview import ViewDetections
from reconstruction.compile_notice import compile_notice
from reconstruction.matching.epipolar import fundamental_matrix
from reconstruction.matching.evidence_kernels import merge_linked, pair_chi2
from reconstruction.matching.feet import NO_COUNTERPART, FeetMatcher
from reconstruction.matching.feet_uncertainty import mahalanobis_distances
from reconstruction.matching.merge import _as_edges, pair_edges, solve_pair
from reconstruction.solver.map_estimation import joint_sigma
from reconstruction.solver.person_prior import chi2_medians

TOO_LITTLE_EVIDENCE = "too_little_evidence"  # no usable foot and fewer than min_dof usable joints
NON_FINITE_KEYPOINTS = "non_finite_keypoints"  # ... and some keypoints were NaN / inf (treated as missing)
CALIBRATION_SAMPLE = 400  # mutual best pairs enough for the median of the noise calibration


def calibrated(body: np.ndarray, feet: np.ndarray, scale2: float) -> np.ndarray:
    """D^2 = feet + body / scale2: (Na, Nb) x2 -> (Na, Nb). The feet term keeps its own model (its ground
    floor is foot size and calibration, not pixel noise); a missing feet term (NaN) adds nothing."""
    return np.where(np.isfinite(feet), feet, 0.0) + body / scale2


@lru_cache(maxsize=16)
def gate_limits(reject_rate: float, max_dof: int) -> np.ndarray:
    """chi^2 quantile 1 - reject_rate for 0..max_dof degrees of freedom: (max_dof + 1,); inf at dof 0."""
    dof = np.arange(max_dof + 1)
    # scipy.stats.chi2.ppf's own formula, without importing scipy.stats (~0.5 s)
    return np.where(dof > 0, 2.0 * gammaincinv(np.maximum(dof, 1) / 2.0, 1.0 - reject_rate), np.inf)


def joint_variances(
    view: ViewDetections, camera, min_score: float, sigma_model: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undistorted pixels (N, J, 2), pixel variances (N, J) (0 = unusable) and any-non-finite (N,) of a view;
    sigma_model = (c, sigma_min, sigma_px, score_power) of :func:`joint_sigma`."""
    kp = np.asarray(view.keypoints, dtype=np.float64)
    finite = np.isfinite(kp).all(axis=-1)
    bad = ~finite.all(axis=-1)
    kp = np.where(finite[..., None], kp, 0.0)
    ok = finite & (kp[..., 2] >= min_score)
    kp = np.where(ok[..., None], kp, 0.0)
    sigma = joint_sigma(kp, np.nan_to_num(view.bboxes, nan=0.0, posinf=0.0, neginf=0.0), *sigma_model)
    var = np.where(ok & np.isfinite(sigma), sigma**2, 0.0)
    uv = camera.undistort_points(kp[..., :2]) if len(kp) else kp[..., :2]
    return np.ascontiguousarray(np.where(ok[..., None], uv, 0.0)), var, bad


def merge_complete(edges: np.ndarray, linked: np.ndarray, num_detections: list[int], min_views: int) -> np.ndarray:
    """Persons from edges (E, 5) (view_a, det_a, view_b, det_b, cost), cheapest first, joining two partial
    persons only when every cross pair of their detections is ``linked`` ((N, N) bool over global indices,
    views in order) and no view repeats: -> (P, V) detection index per view or -1, V <= 62."""
    edges = _as_edges(edges)
    counts = np.asarray(num_detections, dtype=np.int64)
    if len(counts) > 62:
        raise ValueError(f"complete-linkage merging keeps views in a 64-bit mask: at most 62 views, got {len(counts)}")
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    view_of = np.repeat(np.arange(len(counts)), counts).astype(np.int64)
    ga = offsets[edges[:, 0].astype(np.int64)] + edges[:, 1].astype(np.int64)
    gb = offsets[edges[:, 2].astype(np.int64)] + edges[:, 3].astype(np.int64)
    order = np.lexsort((gb, ga, edges[:, 4]))
    root = merge_linked(ga[order], gb[order], view_of, linked)
    rows = []
    for r in np.unique(root):
        members = np.flatnonzero(root == r)
        if len(members) >= min_views:
            row = np.full(len(counts), -1, dtype=np.int64)
            row[view_of[members]] = members - offsets[view_of[members]]
            rows.append(row)
    return np.stack(rows) if rows else np.zeros((0, len(counts)), dtype=np.int64)


@lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile the kernels (or load them from numba's cache) once per process, so a first frame is not timed
    with the compiler."""
    uv, var = np.zeros((1, 2, 2)), np.ones((1, 2))
    out, dof = np.empty((1, 1)), np.empty((1, 1), dtype=np.int64)
    pair_chi2(uv, var, uv, var, np.eye(3), np.full((1, 1), np.nan), np.full(5, np.inf), 1, 9.0, 1.0, out, dof)
    merge_linked(np.zeros(1, np.int64), np.ones(1, np.int64), np.arange(2, dtype=np.int64), np.ones((2, 2), bool))


class EvidenceMatcher:
    """Matching by all shared evidence: ``matcher(views, rig) -> (P, V)`` detection index per view or -1.

    Keys: reject_rate (the test's probability of rejecting a true pair whose noise follows the model),
    evidence_per_dof (log-likelihood ratio credited per agreeing degree of freedom), min_dof (fewest
    degrees of freedom a pair needs), min_score (a joint is used above it), c, sigma_min, sigma_px and
    score_power (the 2D pixel sigma model of :func:`joint_sigma`), min_views, feet (FeetMatcher keys for the ground-plane feet: pixel_sigma,
    ground_sigma_floor, foot_rule, ankle_height_m ...); calibrate (scale the model's noise to the frame's,
    :meth:`noise_scale2`), max_noise_scale and min_calibration_pairs (its bounds); outlier_sd (one joint adds at
    most outlier_sd^2 model variances to D^2, whatever the calibration: a few outlying joints do not reject
    a true pair); link_scale (the noise factor of
    the looser test every cross pair of two merging persons must pass). Detections left out of every person are counted
    by reason in ``last_unmatched_reasons`` and ``unmatched_reasons``.
    """

    def __init__(
        self,
        reject_rate: float = 1e-3,
        evidence_per_dof: float = 2.0,
        min_dof: int = 2,
        min_score: float = 0.2,
        c: float = 0.016,
        sigma_min: float = 1.0,
        sigma_px: float = 5.2,
        score_power: float = 1.27,
        min_views: int = 2,
        feet: dict | None = None,
        calibrate: bool = True,
        max_noise_scale: float = 4.0,
        min_calibration_pairs: int = 5,
        outlier_sd: float = 12.0,
        link_scale: float = 2.0,
    ) -> None:
        if not 0 < reject_rate < 1 or int(min_dof) < 1 or int(min_views) < 1:
            raise ValueError(
                f"need 0 < reject_rate < 1, min_dof >= 1, min_views >= 1; got {reject_rate}, {min_dof}, {min_views}"
            )
        if min(evidence_per_dof, c, sigma_min, sigma_px, score_power) < 0 or max(c, sigma_min, sigma_px) == 0:
            raise ValueError(
                "evidence_per_dof, c, sigma_min, sigma_px, score_power must be >= 0, and c, sigma_min, "
                "sigma_px not all 0"
            )
        self.reject_rate, self.evidence_per_dof = float(reject_rate), float(evidence_per_dof)
        self.min_dof, self.min_score, self.min_views = int(min_dof), float(min_score), int(min_views)
        self.c, self.sigma_min, self.sigma_px, self.score_power = (
            float(c),
            float(sigma_min),
            float(sigma_px),
            float(score_power),
        )
        if not max_noise_scale >= 1 or int(min_calibration_pairs) < 1:
            raise ValueError(
                f"need max_noise_scale >= 1 and min_calibration_pairs >= 1, got {max_noise_scale}, "
                f"{min_calibration_pairs}"
            )
        self.calibrate, self.max_noise_scale = bool(calibrate), float(max_noise_scale)
        self.min_calibration_pairs = int(min_calibration_pairs)
        if not outlier_sd > 0:
            raise ValueError(f"outlier_sd must be > 0, got {outlier_sd}")
        self.outlier_sd = float(outlier_sd)
        if not 1 <= link_scale <= max_noise_scale:
            raise ValueError(f"need 1 <= link_scale <= max_noise_scale, got {link_scale}")
        self.link_scale = float(link_scale)
        self.last_noise_scale = 1.0
        self._fundamentals: dict[tuple[int, int, int], tuple[Rig, np.ndarray]] = {}
        with compile_notice("evidence matcher"):  # one line while numba compiles (first run)
            warm_up()
        self.feet = FeetMatcher(min_views=min_views, **{"pixel_sigma": 5.0, **(feet or {})})
        self.last_unmatched_reasons: Counter[str] = Counter()
        self.unmatched_reasons: Counter[str] = Counter()

    def _fundamental(self, rig: Rig, a: int, b: int) -> np.ndarray:
        """F of a view pair of the rig, computed once per rig: (3, 3)."""
        key = (id(rig), a, b)
        if key not in self._fundamentals:
            self._fundamentals[key] = (rig, fundamental_matrix(rig[a], rig[b]))  # keeps rig alive: id stays unique
        return self._fundamentals[key][1]

    def pair_evidence(self, views: list[ViewDetections], rig: Rig):
        """The evidence function of one frame: (a, b[, scale2]) -> body chi^2 (N_a, N_b) in model units, dof
        (N_a, N_b), feet term (N_a, N_b) (NaN where either has no feet); the body term is inf where
        feet + body / scale2 fails the link test (default scale2: the loosest any calibration allows,
        ``max_noise_scale`` ** 2, so that no later test needs a pair it dropped)."""
        if len(views) != len(rig):
            raise ValueError(f"{len(views)} views of detections for a rig of {len(rig)} cameras")
        feats = self.feet.features([_finite(v) for v in views], rig)
        model = (self.c, self.sigma_min, self.sigma_px, self.score_power)
        joints = [joint_variances(v, cam, self.min_score, model) for v, cam in zip(views, rig)]
        J = next((v.keypoints.shape[1] for v in views if len(v)), 23)
        limits = gate_limits(self.reject_rate, J + 2)
        loosest = self.max_noise_scale**2 if self.calibrate else 1.0
        link2 = self.link_scale**2  # the widest test any later step applies (complete linkage)

        def evidence(a: int, b: int, scale2: float = loosest) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            fa, fb = feats[a], feats[b]
            feet = mahalanobis_distances(fa.p, fb.p, fa.cov, fb.cov, self.feet.ground_sigma_floor) ** 2
            feet = np.where(fa.has_p[:, None] & fb.has_p[None, :], feet, np.nan)
            out = np.empty((len(fa), len(fb)))
            dof = np.empty((len(fa), len(fb)), dtype=np.int64)
            pair_chi2(
                joints[a][0],
                joints[a][1],
                joints[b][0],
                joints[b][1],
                self._fundamental(rig, a, b),
                np.ascontiguousarray(feet),
                limits * link2,
                self.min_dof,
                self.outlier_sd**2,
                scale2,
                out,
                dof,
            )
            body = (out - np.where(np.isfinite(feet), feet, 0.0)) * scale2  # model units; inf = rejected
            return body, dof, feet

        return evidence, feats, joints

    def __call__(self, views: list[ViewDetections], rig: Rig) -> np.ndarray:
        """Assignment of one frame: V views -> (P, V) detection indices, -1 where absent."""
        evidence, feats, joints = self.pair_evidence(views, rig)
        counts = [len(v) for v in views]
        pairs, scale2 = self._calibrated_pairs(evidence, counts)
        self.last_noise_scale = float(np.sqrt(scale2))
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        limits = gate_limits(self.reject_rate, next((v.keypoints.shape[1] for v in views if len(v)), 23) + 2)
        edges = [np.zeros((0, 5))]
        linked = np.zeros((offsets[-1], offsets[-1]), dtype=bool)
        for a, b, body, dof, feet in pairs:
            d2 = calibrated(body, feet, scale2)
            block = d2 <= limits[dof] * self.link_scale**2
            linked[offsets[a] : offsets[a + 1], offsets[b] : offsets[b + 1]] = block
            linked[offsets[b] : offsets[b + 1], offsets[a] : offsets[a + 1]] = block.T
            ok = d2 <= limits[dof]
            if not ok.any():
                continue
            cost = np.where(ok, 0.5 * d2 - self.evidence_per_dof * dof, np.inf)
            rows, cols = solve_pair(cost)
            edges.append(pair_edges(a, b, rows, cols, cost))
        assignment = merge_complete(np.concatenate(edges), linked, counts, self.min_views)
        usable = [f.has_p | ((var > 0).sum(axis=1) >= self.min_dof) for f, (_, var, _) in zip(feats, joints)]
        self._count_reasons(assignment, usable, joints)
        return assignment

    def _calibrated_pairs(self, evidence, counts: list[int]) -> tuple[list[tuple], float]:
        """The evidence of every view pair (a, b, chi^2, dof, feet) and the squared noise scale of the frame.

        View pairs are taken, neighbours first, under the loosest test until the calibration has its sample
        (:meth:`noise_scale2`); the others are computed at the calibrated scale, so that their loops stop
        as soon as the link test fails.
        """
        # neighbours first ((0, 1), (1, 2), ..., then (0, 2), ...): the sample covers every view early
        view_pairs = sorted(
            ((a, b) for a, b in combinations(range(len(counts)), 2) if counts[a] and counts[b]),
            key=lambda ab: (ab[1] - ab[0], ab[0]),
        )
        pairs, ratios = [], []
        if self.calibrate:
            for a, b in view_pairs:
                pairs.append((a, b, *evidence(a, b)))
                ratios += self.calibration_ratios(*pairs[-1][2:])
                if len(ratios) >= CALIBRATION_SAMPLE:
                    break
        scale2 = self.noise_scale2(ratios) if self.calibrate else 1.0
        pairs += [(a, b, *evidence(a, b, scale2)) for a, b in view_pairs[len(pairs) :]]
        return pairs, scale2

    def calibration_ratios(self, body: np.ndarray, dof: np.ndarray, feet: np.ndarray) -> list[float]:
        """Body chi^2 / median(chi^2(body dof)) of a view pair's mutual best partners under the loosest test."""
        if not np.isfinite(body).any():
            return []
        loose = calibrated(body, feet, self.max_noise_scale**2)
        cost = np.where(np.isfinite(loose), 0.5 * loose - self.evidence_per_dof * dof, np.inf)
        best_b, best_a = np.argmin(cost, axis=1), np.argmin(cost, axis=0)
        rows = np.flatnonzero(best_a[best_b] == np.arange(len(cost)))  # mutual best partners
        rows = rows[np.isfinite(cost[rows, best_b[rows]])]
        cols = best_b[rows]
        body_dof = dof[rows, cols] - 2 * np.isfinite(feet[rows, cols])
        return (body[rows, cols][body_dof > 0] / chi2_medians(body_dof[body_dof > 0])).tolist()

    def noise_scale2(self, ratios: list[float]) -> float:
        """The frame's 2D noise over the model, squared, from :meth:`calibration_ratios` (their median).

        The mutual best partners under the test widened by ``max_noise_scale`` are mostly true pairs, so
        the median of their body chi^2 / median(chi^2(body dof)) estimates the squared scale robustly.
        Clipped to [1 / max_noise_scale^2, max_noise_scale^2]; 1 with fewer than ``min_calibration_pairs``.
        """
        if len(ratios) < self.min_calibration_pairs:
            return 1.0
        return float(np.clip(np.median(ratios), self.max_noise_scale**-2, self.max_noise_scale**2))

    def _count_reasons(self, assignment: np.ndarray, usable: list[np.ndarray], joints: list) -> None:
        """Unmatched detections by reason: too little evidence (with NaN keypoints, or not) or no counterpart."""
        reasons: Counter[str] = Counter()
        for v, ok in enumerate(usable):
            placed = np.zeros(len(ok), dtype=bool)
            placed[assignment[:, v][assignment[:, v] >= 0]] = True
            bad = joints[v][2]
            reasons[NON_FINITE_KEYPOINTS] += int(np.sum(~placed & ~ok & bad))
            reasons[TOO_LITTLE_EVIDENCE] += int(np.sum(~placed & ~ok & ~bad))
            reasons[NO_COUNTERPART] += int(np.sum(~placed & ok))
        self.last_unmatched_reasons = +reasons
        self.unmatched_reasons = self.unmatched_reasons + self.last_unmatched_reasons


def _finite(view: ViewDetections) -> ViewDetections:
    """The view with non-finite keypoints zeroed (missing), for the feet features."""
    kp = np.asarray(view.keypoints, dtype=np.float64)
    if np.isfinite(kp).all():
        return view
    finite = np.isfinite(kp).all(axis=-1, keepdims=True)
    return ViewDetections(
        np.where(finite, kp, 0.0), np.nan_to_num(view.bboxes), view.scores, view.person_ids, view.occluded
    )
