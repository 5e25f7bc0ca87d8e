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

The evidence is computed for all view pairs of a frame in compiled loops (:mod:`.evidence_kernels`) that
stop as soon as a pair fails (the feet term first), so the unrelated pairs of a crowd cost a joint or two
each, and only the pairs that pass are kept (a crowd has about one per detection and view, not N_a x N_b).
Each view pair's assignment is solved one connected component of allowed pairs at a time
(:mod:`.sparse_assignment`, scipy's solver step for step), and the merge reads the links as adjacency lists.
The view pairs the noise calibration reads are computed under the (loosest) link test; the others under the
gate alone, and the merge computes the link test of one of their pairs when it asks for it (100 people in 7
views: 40-75 per frame, where computing them all took 0.5 ms of the matching's 7).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations

import numpy as np
from scipy.special import gammaincinv

from data.assignment import solve_sparse_pairs
from data.geometry.camera import Rig
from data.multiview import ViewDetections
from reconstruction.compile_notice import warm_up_kernels
from reconstruction.matching import feet_kernels
from reconstruction.matching.epipolar import fundamental_matrix
from reconstruction.matching.evidence_kernels import (
    calibrated_chi2,
    gated_rows,
    merge_persons,
    pairs_chi2,
    usable_keypoints,
)
from reconstruction.matching.feet import NO_COUNTERPART, FeetMatcher
from reconstruction.matching.merge import _as_edges
from reconstruction.solver.map_estimation import joint_sigma
from reconstruction.solver.person_prior import chi2_medians

TOO_LITTLE_EVIDENCE = "too_little_evidence"  # no usable foot and fewer than min_dof usable joints
NON_FINITE_KEYPOINTS = "non_finite_keypoints"  # ... and some keypoints were NaN / inf (treated as missing)
CALIBRATION_SAMPLE = 400  # mutual best pairs enough for the median of the noise calibration


@lru_cache(maxsize=16)
def gate_limits(reject_rate: float, max_dof: int) -> np.ndarray:
    """chi^2 quantile 1 - reject_rate for 0..max_dof degrees of freedom: (max_dof + 1,); inf at dof 0."""
    dof = np.arange(max_dof + 1)
    # scipy.stats.chi2.ppf's own formula, without importing scipy.stats (~0.5 s)
    return np.where(dof > 0, 2.0 * gammaincinv(np.maximum(dof, 1) / 2.0, 1.0 - reject_rate), np.inf)


def joint_variances(
    views: list[ViewDetections], cameras: list, min_score: float, sigma_model: tuple[float, float, float, float], J: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undistorted pixels (N, J, 2), pixel variances (N, J) (0 = unusable) and any-non-finite (N,) of the
    detections of V views stacked in view order (N in all); sigma_model = (c, sigma_min, sigma_px,
    score_power) of :func:`joint_sigma`. Only the undistortion is done per view (camera)."""
    kp = np.concatenate([np.asarray(v.keypoints, dtype=np.float64).reshape(-1, J, 3) for v in views])
    boxes = np.concatenate([np.asarray(v.bboxes, dtype=np.float64).reshape(-1, 4) for v in views])
    clean, ok, bad = np.empty(kp.shape), np.empty(kp.shape[:2], dtype=bool), np.empty(len(kp), dtype=bool)
    usable_keypoints(kp, float(min_score), clean, ok, bad)
    sigma = joint_sigma(clean, np.nan_to_num(boxes, nan=0.0, posinf=0.0, neginf=0.0), *sigma_model)
    var = np.where(ok & np.isfinite(sigma), sigma**2, 0.0)
    if not any(cam.has_distortion for cam in cameras):  # the joints not ok are zero already
        return np.ascontiguousarray(clean[..., :2]), var, bad
    ends = np.cumsum([len(v) for v in views])
    uv = [cam.undistort_points(clean[e - len(v) : e, :, :2]) for v, cam, e in zip(views, cameras, ends) if len(v)]
    uv = np.concatenate(uv) if uv else clean[..., :2]
    return np.ascontiguousarray(np.where(ok[..., None], uv, 0.0)), var, bad


def merge_complete(
    edges: np.ndarray,
    linked: np.ndarray,
    num_detections: list[int],
    min_views: int,
    evidence: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Persons from edges (E, 5) (view_a, det_a, view_b, det_b, cost), cheapest first, joining two partial
    persons only when every cross pair of their detections is linked ((L, 2) pairs of global detection
    indices, views in order; either order) and no view repeats: -> (P, V) detection index per view or -1,
    V <= 62. With evidence = (has_feet (N,), joint variances (N, J)), a pair that shares no evidence (not
    both feet, no joint usable in both) has nothing to test and counts as linked."""
    edges = _as_edges(edges)
    counts = np.asarray(num_detections, dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    ga = offsets[edges[:, 0].astype(np.int64)] + edges[:, 1].astype(np.int64)
    gb = offsets[edges[:, 2].astype(np.int64)] + edges[:, 3].astype(np.int64)
    return _merge(ga, gb, edges[:, 4], counts, linked, min_views, evidence, None)


def _merge(
    ga: np.ndarray,
    gb: np.ndarray,
    cost: np.ndarray,
    counts: np.ndarray,
    linked: np.ndarray,
    min_views: int,
    evidence: tuple[np.ndarray, np.ndarray] | None,
    untested: tuple | None,
) -> np.ndarray:
    """:func:`merge_complete` of edges given by global detection indices ga, gb (E,) and cost (E,), views of
    counts (V,) detections: -> (P, V). untested: the inputs of the link tests not among ``linked``, computed
    when the merge asks (:func:`untested_links`), or None: every link test is in ``linked``."""
    if len(counts) > 62:
        raise ValueError(f"complete-linkage merging keeps views in a 64-bit mask: at most 62 views, got {len(counts)}")
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    view_of = np.repeat(np.arange(len(counts)), counts).astype(np.int64)
    has_feet, var = evidence if evidence is not None else (np.ones(offsets[-1], bool), np.ones((offsets[-1], 1)))
    links = np.ascontiguousarray(np.asarray(linked, dtype=np.int64).reshape(-1, 2))
    if untested is None:
        untested = all_tested(len(counts), var.shape[1])
    order = _by_cost(cost, ga, gb)
    person, size = merge_persons(
        np.ascontiguousarray(ga, np.int64)[order],
        np.ascontiguousarray(gb, np.int64)[order],
        view_of,
        links,
        np.ascontiguousarray(has_feet, bool),
        np.ascontiguousarray(var, np.float64),
        untested,
    )
    rows = np.full((len(size), len(counts)), -1, dtype=np.int64)
    rows[person, view_of] = np.arange(offsets[-1]) - offsets[view_of]
    return rows[size >= min_views]


def _by_cost(cost: np.ndarray, ga: np.ndarray, gb: np.ndarray) -> np.ndarray:
    """The order of edges by cost, ties by the detections ga, gb: (E,) x3 -> (E,) (numba's sorts cost seconds of
    compile). Finite float costs rarely tie: one argsort (4x faster than the lexsort it stands for), checked."""
    order = np.argsort(cost, kind="stable")
    ordered = np.asarray(cost)[order]
    tied = np.any(ordered[1:] == ordered[:-1]) or not np.isfinite(ordered[-1:]).all()  # NaN sorts last
    return np.lexsort((gb, ga, cost)) if tied else order


def untested_links(stacked: tuple, tested: np.ndarray, link_test: tuple) -> tuple:
    """What :func:`~reconstruction.matching.evidence_kernels.merge_linked` needs to compute a link test the merge
    asks for: from pairs_chi2's stacked inputs the pixels, feet and fundamental matrices; tested (V, V) bool
    (True: every pair of the two views that passes the link test is among the links); link_test = (limits (D + 1,)
    (the gate's x link_scale^2), min_dof, cap, the frame's scale2)."""
    uv, _, _, _, p, cov, floor2, fundamentals = stacked
    return uv, p, cov, floor2, fundamentals, tested, *link_test


def all_tested(V: int, J: int) -> tuple:
    """:func:`untested_links` where every link test is among the links (a merge of given links): nothing left."""
    stacked = (
        np.zeros((0, J, 2)),
        None,
        None,
        None,
        np.zeros((0, 2)),
        np.zeros((0, 2, 2)),
        1.0,
        np.zeros((V, V, 3, 3)),
    )
    return untested_links(stacked, np.ones((V, V), dtype=bool), (np.full(J + 3, np.inf), 1, 1.0, 1.0))


@lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile the kernels (or load them from numba's cache) once per process, so a first frame is not timed
    with the compiler."""
    uv, var, one = np.zeros((2, 2, 2)), np.ones((2, 2)), np.array([0, 1, 2])
    p, cov = np.zeros((2, 2)), np.zeros((2, 2, 2))
    F, pairs, limits = np.zeros((2, 2, 3, 3)), np.array([[0, 1]]), np.full(5, np.inf)
    out = (np.empty((1, 4), np.int64), np.empty((1, 2)), np.empty(1), 0, 0)
    pairs_chi2(uv, var, one, np.ones(2, bool), p, cov, 1.0, F, pairs, 0, limits, 1, 9.0, 1.0, np.ones(5), 2.0, 1, *out)
    solve_sparse_pairs(one[:2], np.ones((1, 2), np.int64), one[:2] * 0, one[:2] * 0, np.array([0.0, 1.0]))
    untested = untested_links((uv, var, one, None, p, cov, 1.0, F), np.zeros((2, 2), bool), (limits, 1, 9.0, 1.0))
    merge_persons(one[:1], one[1:2], one[:2], np.zeros((0, 2), np.int64), np.ones(2, bool), var, untested)
    joint_sigma(np.ones((1, 2, 3)), np.ones((1, 4)), 0.016, 1.0)  # its pass over the joints
    feet_kernels.warm_up()
    usable_keypoints(np.zeros((2, 2, 3)), 0.2, np.empty((2, 2, 3)), np.empty((2, 2), bool), np.empty(2, bool))
    ints = np.zeros((2, 4), np.int64)  # strided column views of pairs_chi2's output, as __call__ passes them
    d2 = calibrated_chi2(np.zeros((2, 2)), 0, 1.0, 1.0)
    gated_rows(ints[:, 0], ints[:, 1], ints[:, 2], d2, ints[:, 3], limits, 4.0, 2.0, one, pairs, 1)


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
        self._fundamentals: dict[int, tuple[Rig, np.ndarray]] = {}
        self._rows_hint = 0  # rows of the detection-pair buffers: the last frame's count, with a margin
        warm_up_kernels("evidence matcher", warm_up)  # one line while numba compiles (first run)
        self.feet = FeetMatcher(min_views=min_views, **{"pixel_sigma": 5.0, **(feet or {})})
        self.last_unmatched_reasons: Counter[str] = Counter()
        self.unmatched_reasons: Counter[str] = Counter()

    def _fundamentals_of(self, rig: Rig) -> np.ndarray:
        """F of every view pair (a, b) of the rig, x_b^T F[a, b] x_a = 0, computed once per rig: (V, V, 3, 3)."""
        key = id(rig)
        if key not in self._fundamentals:
            F = np.zeros((len(rig), len(rig), 3, 3))
            for a, b in combinations(range(len(rig)), 2):
                F[a, b] = fundamental_matrix(rig[a], rig[b])
            self._fundamentals[key] = (rig, F)  # keeps rig alive: its id stays unique
        return self._fundamentals[key][1]

    def frame_evidence(self, views: list[ViewDetections], rig: Rig) -> FrameEvidence:
        """The frame's detections stacked over views and its detection pairs that pass the link test at the
        frame's calibrated noise (:meth:`noise_scale2`)."""
        if len(views) != len(rig):
            raise ValueError(f"{len(views)} views of detections for a rig of {len(rig)} cameras")
        counts = np.array([len(v) for v in views], dtype=np.int64)
        J = next((v.keypoints.shape[1] for v in views if len(v)), 23)
        for v in views:
            if len(v) and np.shape(v.keypoints)[1:] != (J, 3):
                raise ValueError(f"keypoints must have shape (N, {J}, 3) in every view, got {np.shape(v.keypoints)}")
        model = (self.c, self.sigma_min, self.sigma_px, self.score_power)
        uv, var, bad = joint_variances(views, list(rig), self.min_score, model, J)
        ends = np.cumsum(counts)  # a view with a non-finite keypoint (bad) gets it zeroed for the feet
        feet = self.feet.stacked_features(
            [_finite(v) if bad[e - len(v) : e].any() else v for v, e in zip(views, ends)], rig
        )
        has_p = np.asarray(feet.has_p, dtype=bool)
        stacked = (
            uv,
            var,
            np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            has_p,
            np.ascontiguousarray(feet.p, dtype=np.float64),
            np.ascontiguousarray(feet.cov, dtype=np.float64),
            self.feet.ground_sigma_floor**2,
            self._fundamentals_of(rig),
        )
        view_pairs = _view_pairs(counts)
        pairs, scale2, done = self._calibrated_pairs(stacked, view_pairs, J)
        usable = has_p | ((var > 0).sum(axis=1) >= self.min_dof)
        tested = np.zeros((len(counts), len(counts)), dtype=bool)  # the calibration's view pairs: all link tests
        tested[view_pairs[:done, 0], view_pairs[:done, 1]] = tested[view_pairs[:done, 1], view_pairs[:done, 0]] = True
        link_test = (
            gate_limits(self.reject_rate, J + 2) * self.link_scale**2,
            self.min_dof,
            self.outlier_sd**2,
            scale2,
        )
        untested = untested_links(stacked, tested, link_test)
        return FrameEvidence(counts, stacked[2], view_pairs, *pairs, scale2, has_p, var, usable, bad, untested)

    def __call__(self, views: list[ViewDetections], rig: Rig) -> np.ndarray:
        """Assignment of one frame: V views -> (P, V) detection indices, -1 where absent."""
        ev = self.frame_evidence(views, rig)
        self.last_noise_scale = float(np.sqrt(ev.scale2))
        limits = gate_limits(self.reject_rate, next((v.keypoints.shape[1] for v in views if len(v)), 23) + 2)
        starts, rows, da, db, cost, links = gated_rows(
            ev.pair, ev.gi, ev.gj, ev.d2, ev.dof, limits, self.link_scale**2, self.evidence_per_dof, ev.offsets,
            ev.view_pairs, len(ev.view_pairs),
        )  # fmt: skip
        keep = solve_sparse_pairs(starts, ev.counts[ev.view_pairs], da, db, cost)
        kept = rows[keep]
        assignment = _merge(
            ev.gi[kept], ev.gj[kept], cost[keep], ev.counts, links, self.min_views, (ev.has_feet, ev.var), ev.untested
        )
        self._count_reasons(assignment, ev)
        return assignment

    def _calibrated_pairs(self, stacked: tuple, view_pairs: np.ndarray, J: int) -> tuple[list[np.ndarray], float, int]:
        """[view pair (E,) (row of view_pairs), i, j (E,) global detection indices, D^2 (E,) at the calibrated
        noise, dof (E,)] of the detection pairs that pass the test, the frame's squared noise scale and the
        view pairs computed for the calibration (view_pairs[:done]).

        View pairs are taken, neighbours first, under the loosest link test until the calibration has its sample
        (:meth:`noise_scale2`): every pair that passes the link test is among their rows. The others are computed
        at the calibrated scale under the gate, so that their loops stop as soon as the gate fails; the merge
        computes the link tests it needs of their other pairs (100 people in 7 views: 40-75 per frame).
        """
        sizes = np.diff(stacked[2])[view_pairs].reshape(-1, 2)
        # room for the largest view pair, or for the last frame's rows (a crowd's frames are alike: no regrowing)
        room = max(int(sizes.prod(axis=1).max(initial=0)) + 4 * len(stacked[1]), self._rows_hint)
        out = [
            np.empty((room, 4), np.int64),
            np.empty((room, 2)),
            np.empty(int(sizes.min(axis=1).sum())),
            0,
            0,
        ]
        calibration = (chi2_medians(np.arange(J + 3)), self.evidence_per_dof)
        loosest, scale2, done = self.max_noise_scale**2, 1.0, 0
        gate = gate_limits(self.reject_rate, J + 2)
        if self.calibrate:
            sample = (*calibration, CALIBRATION_SAMPLE)
            done = self._run_pairs(stacked, view_pairs, 0, loosest, sample, out, sizes, gate * self.link_scale**2)
            scale2 = self.noise_scale2(out[2][: out[4]])
        first = out[3]  # rows computed at the loosest scale
        # the gate, widened by rounding: every row gated_rows lets through (its D^2 is recomputed) is computed
        self._run_pairs(stacked, view_pairs, done, scale2, (*calibration, 0), out, sizes, gate * (1.0 + 1e-9))
        ints, floats = out[0][: out[3]], out[1][: out[3]]
        self._rows_hint = int(1.25 * out[3]) + int(sizes.prod(axis=1).max(initial=0))
        d2 = calibrated_chi2(floats, first, loosest, scale2)
        return [ints[:, 0], ints[:, 1], ints[:, 2], d2, ints[:, 3]], scale2, done

    def _run_pairs(
        self, stacked, view_pairs, q0: int, scale2: float, calibration: tuple, out: list, sizes, limits: np.ndarray
    ) -> int:
        """:func:`pairs_chi2` from view pair q0 at scale2 under limits (D + 1,) into out = [ints, floats, ratios, n,
        nr], growing ints and floats when a view pair needs the room: -> view pairs done."""
        fixed = (limits, self.min_dof)
        while True:
            out[3], out[4], q0 = pairs_chi2(
                *stacked, view_pairs, q0, *fixed, self.outlier_sd**2, scale2, *calibration, *out
            )
            if q0 == len(view_pairs) or (calibration[2] > 0 and out[4] >= calibration[2]):
                return q0
            grow = 2 * len(out[0]) + int(sizes[q0].prod())
            out[0] = np.concatenate([out[0][: out[3]], np.empty((grow, 4), np.int64)])
            out[1] = np.concatenate([out[1][: out[3]], np.empty((grow, 2))])

    def noise_scale2(self, ratios: list[float] | np.ndarray) -> float:
        """The frame's 2D noise over the model, squared, from the calibration ratios (their median): body chi^2 /
        median(chi^2(body dof)) of each view pair's mutual best partners under the loosest test (computed by
        :func:`~reconstruction.matching.evidence_kernels.pairs_chi2`).

        The mutual best partners under the test widened by ``max_noise_scale`` are mostly true pairs, so
        the median of their body chi^2 / median(chi^2(body dof)) estimates the squared scale robustly.
        Clipped to [1 / max_noise_scale^2, max_noise_scale^2]; 1 with fewer than ``min_calibration_pairs``.
        """
        if len(ratios) < self.min_calibration_pairs:
            return 1.0
        return float(np.clip(np.median(ratios), self.max_noise_scale**-2, self.max_noise_scale**2))

    def _count_reasons(self, assignment: np.ndarray, ev: FrameEvidence) -> None:
        """Unmatched detections by reason: too little evidence (with NaN keypoints, or not) or no counterpart."""
        placed = np.zeros(len(ev.usable), dtype=bool)
        placed[(ev.offsets[:-1] + assignment)[assignment >= 0]] = True
        unusable = ~placed & ~ev.usable
        reasons: Counter[str] = Counter()
        reasons[NON_FINITE_KEYPOINTS] = int(np.count_nonzero(unusable & ev.bad))
        reasons[TOO_LITTLE_EVIDENCE] = int(np.count_nonzero(unusable)) - reasons[NON_FINITE_KEYPOINTS]
        reasons[NO_COUNTERPART] = int(np.count_nonzero(~placed & ev.usable))
        self.last_unmatched_reasons = +reasons
        self.unmatched_reasons = self.unmatched_reasons + self.last_unmatched_reasons


def _view_pairs(counts: np.ndarray) -> np.ndarray:
    """The view pairs (a < b) where both views have detections, neighbours first ((0, 1), (1, 2), ..., then
    (0, 2), ...: the calibration sample covers every view early): (K, 2) int64."""
    pairs = sorted(
        ((a, b) for a, b in combinations(range(len(counts)), 2) if counts[a] and counts[b]),
        key=lambda ab: (ab[1] - ab[0], ab[0]),
    )
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


@dataclass(frozen=True)
class FrameEvidence:
    """A frame's detections, stacked over its V views (N in all), and its detection pairs that pass the gate (and in
    the view pairs of the calibration, every one that passes the link test).

    counts (V,), offsets (V + 1,) (view v: offsets[v]:offsets[v + 1]); view_pairs (K, 2); per detection pair:
    pair (E,) its row of view_pairs, gi, gj (E,) global indices, d2 (E,) chi^2 at the calibrated noise (scale2,
    squared), dof (E,); per detection: has_feet (N,), var (N, J) joint pixel variances (0: not usable), usable
    (N,) (feet or >= min_dof joints), bad (N,) (non-finite keypoints); untested: the link tests not among the
    rows, for the merge (:func:`untested_links`).
    """

    counts: np.ndarray
    offsets: np.ndarray
    view_pairs: np.ndarray
    pair: np.ndarray
    gi: np.ndarray
    gj: np.ndarray
    d2: np.ndarray
    dof: np.ndarray
    scale2: float
    has_feet: np.ndarray
    var: np.ndarray
    usable: np.ndarray
    bad: np.ndarray
    untested: tuple


def _finite(view: ViewDetections) -> ViewDetections:
    """The view with non-finite keypoints zeroed (missing), for the feet features."""
    kp = np.asarray(view.keypoints, dtype=np.float64)
    finite = np.isfinite(kp).all(axis=-1, keepdims=True)
    return ViewDetections(
        np.where(finite, kp, 0.0), np.nan_to_num(view.bboxes), view.scores, view.person_ids, view.occluded
    )
