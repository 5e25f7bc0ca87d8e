"""The default matcher (``matching=evidence``): every pair judged by all the evidence its two detections share.

For detections i (view a) and j (view b) the evidence is one chi-square D^2 in the units of the 2D noise model
(``noise_model``): the squared Mahalanobis distance of their feet midpoints on the ground plane (2 dof, covariance
propagated from pixel noise, :mod:`.feet_uncertainty`) plus, for every joint both see, the Sampson distance
e^2 / (s_b^2 |F x_a|_12^2 + s_a^2 |F^T x_b|_12^2) of the two pixels to the epipolar geometry (1 dof each, capped at
outlier_sd^2 so that a swapped or hidden joint counts as one bad joint, not as a wrong person).

Under "same person" D^2 is chi^2(dof), so the gate is the test D^2 <= chi^2_{1 - reject_rate}(dof): pairs sharing
3 joints or 20 are judged on one scale. The cost is the negative log-likelihood ratio 0.5 D^2 - evidence_per_dof dof.
Per view pair a gated assignment (:func:`data.assignment.solve_sparse_pairs`); the model's noise is first scaled to
the frame's (:meth:`EvidenceMatcher.noise_scale2`); then persons are merged cheapest edge first with complete linkage:
two partial persons join only when every cross pair passes the test with the noise widened by ``link_scale`` and no
view would hold two, so a detection is left unmatched rather than merged wrongly. The view pairs of the calibration
are computed under the (loosest) link test, the others under the gate alone; the merge computes the link tests it
asks for there (:func:`~reconstruction.matching.evidence_kernels.merge_linked`).
"""

from __future__ import annotations

import statistics
from collections import Counter
from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations

import numpy as np
from scipy.special import gammaincinv

from data import assignment
from data.assignment import solve_sparse_pairs, swap_regrets
from data.geometry.camera import Rig
from data.multiview import ViewDetections
from reconstruction.matching import feet_kernels
from reconstruction.matching.epipolar import fundamentals
from reconstruction.matching.evidence_kernels import ChiTest, Detections, LinkTests, Sample, merge_linked, pairs_chi2
from reconstruction.matching.feet import NO_COUNTERPART, FeetMatcher
from reconstruction.matching.merge import as_edges
from reconstruction.noise_model import AnyNoiseModel, NoiseModel
from reconstruction.results import Matches
from reconstruction.solver.person_prior import chi2_medians

TOO_LITTLE_EVIDENCE = "too_little_evidence"  # no usable foot and fewer than min_dof usable joints
NON_FINITE_KEYPOINTS = "non_finite_keypoints"  # ... and some keypoints were NaN / inf (treated as missing)
AMBIGUOUS = "ambiguous"  # its pairs were refused: an alternative partner fit within ambiguity_margin
CALIBRATION_SAMPLE = 400  # mutual best pairs enough for the median of the noise calibration


@lru_cache(maxsize=16)
def gate_limits(reject_rate: float, max_dof: int) -> np.ndarray:
    """chi^2 quantile 1 - reject_rate for 0..max_dof degrees of freedom: (max_dof + 1,); inf at dof 0."""
    dof = np.arange(max_dof + 1)
    # scipy.stats.chi2.ppf's own formula, without importing scipy.stats (a slow import)
    return np.where(dof > 0, 2.0 * gammaincinv(np.maximum(dof, 1) / 2.0, 1.0 - reject_rate), np.inf)


def joint_variances(
    views: list[ViewDetections], cameras: list, min_score: float, noise_model: AnyNoiseModel, J: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undistorted pixels (N, J, 2), pixel variances (N, J) (0: unusable) and any-non-finite (N,) of the
    detections of V views stacked in view order."""
    kp = np.concatenate([np.asarray(v.keypoints, dtype=np.float64).reshape(-1, J, 3) for v in views])
    boxes = np.concatenate([np.asarray(v.bboxes, dtype=np.float64).reshape(-1, 4) for v in views])
    finite = np.isfinite(kp[..., 0]) & np.isfinite(kp[..., 1]) & np.isfinite(kp[..., 2])  # not .all(-1): slow on 3
    ok = finite & (kp[..., 2] >= min_score)
    clean = np.where(ok[..., None], kp, 0.0)
    view_of = np.repeat(np.arange(len(views)), [len(v) for v in views])
    sigma = noise_model.sigma(clean, np.nan_to_num(boxes, nan=0.0, posinf=0.0, neginf=0.0), view_of)
    var, bad = np.where(ok & np.isfinite(sigma), sigma**2, 0.0), ~finite.all(axis=1)
    if not any(cam.has_distortion for cam in cameras):  # the joints not ok are zero already
        return np.ascontiguousarray(clean[..., :2]), var, bad
    ends = np.cumsum([len(v) for v in views])
    uv = [cam.undistort_points(clean[e - len(v) : e, :, :2]) for v, cam, e in zip(views, cameras, ends) if len(v)]
    uv = np.concatenate(uv) if uv else clean[..., :2]
    return np.ascontiguousarray(np.where(ok[..., None], uv, 0.0)), var, bad


def calibrated_chi2(floats: np.ndarray, first: int, loosest: float, scale2: float) -> np.ndarray:
    """D^2 = feet + body / scale2 of pairs_chi2's rows: floats (E, 2) (chi^2 computed at loosest for rows < first,
    at scale2 after; feet term or NaN) -> (E,). The feet term keeps its own model (its floor is not pixel noise)."""
    feet = np.where(np.isfinite(floats[:, 1]), floats[:, 1], 0.0)
    computed_at = np.where(np.arange(len(floats)) < first, loosest, scale2)
    return feet + (floats[:, 0] - feet) * computed_at / scale2


def merge_complete(
    edges: np.ndarray,
    linked: np.ndarray,
    num_detections: list[int],
    min_views: int,
    evidence: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Persons from edges (E, 5) (view_a, det_a, view_b, det_b, cost), cheapest first, joining two partial persons
    only when every cross pair is linked ((L, 2) global detection indices) and no view repeats: -> (P, V), V <= 62.

    With evidence = (has_feet (N,), joint variances (N, J)), a pair sharing no evidence counts as linked."""
    edges = as_edges(edges)
    counts = np.asarray(num_detections, dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    ga = offsets[edges[:, 0].astype(np.int64)] + edges[:, 1].astype(np.int64)
    gb = offsets[edges[:, 2].astype(np.int64)] + edges[:, 3].astype(np.int64)
    has_feet, var = evidence if evidence is not None else (np.ones(offsets[-1], bool), np.ones((offsets[-1], 1)))
    return _merge(ga, gb, edges[:, 4], counts, linked, min_views, all_tested(len(counts), has_feet, var))


def _merge(ga, gb, cost, counts: np.ndarray, linked: np.ndarray, min_views: int, lazy: LinkTests) -> np.ndarray:
    """:func:`merge_complete` of edges given by global detection indices ga, gb (E,) and cost (E,): -> (P, V)."""
    if len(counts) > 62:
        raise ValueError(f"complete-linkage merging keeps views in a 64-bit mask: at most 62 views, got {len(counts)}")
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    view_of = np.repeat(np.arange(len(counts)), counts).astype(np.int64)
    links = np.ascontiguousarray(np.asarray(linked, dtype=np.int64).reshape(-1, 2))
    order = np.lexsort((gb, ga, cost))
    ga, gb = (np.ascontiguousarray(g, np.int64)[order] for g in (ga, gb))
    root = merge_linked(ga, gb, view_of, links, lazy)
    is_root = np.zeros(len(view_of), dtype=bool)
    is_root[root] = True
    person = (np.cumsum(is_root) - 1)[root]  # persons numbered by their root (np.unique's order, a third of its time)
    rows = np.full((person.max(initial=-1) + 1, len(counts)), -1, dtype=np.int64)
    rows[person, view_of] = np.arange(offsets[-1]) - offsets[view_of]
    return rows[np.bincount(person, minlength=len(rows)) >= min_views]


def all_tested(V: int, has_feet: np.ndarray, var: np.ndarray) -> LinkTests:
    """The merge's inputs where every link test is among the links (a merge of given links): nothing to compute."""
    J, z, has_feet = var.shape[1], np.zeros, np.ascontiguousarray(has_feet, bool)
    var = np.ascontiguousarray(var, np.float64)
    det = Detections(z((0, J, 2)), var, z(V + 1, np.int64), has_feet, z((0, 2)), z((0, 2, 2)), 1.0, z((V, V, 3, 3)))
    return LinkTests(det, np.ones((V, V), dtype=bool), ChiTest(np.full(J + 3, np.inf), 1, 1.0, 1.0))


@lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile (or load from numba's cache) the matcher's kernels once per process, on two detections."""
    one, det = np.array([0, 1, 2]), all_tested(2, np.ones(2, bool), np.ones((2, 2))).det
    det = det._replace(uv=np.zeros((2, 2, 2)), offsets=np.array([0, 1, 2]), p=np.zeros((2, 2)), cov=np.zeros((2, 2, 2)))
    test = ChiTest(np.full(5, np.inf), 1, 9.0, 1.0)
    out = (np.empty((1, 4), np.int64), np.empty((1, 2)), np.empty(1), 0, 0)
    pairs_chi2(det, np.array([[0, 1]]), 0, test, Sample(np.ones(5), 2.0, 1), *out)
    assignment.warm_up()
    merge_linked(one[:1], one[1:2], one[:2], np.zeros((0, 2), np.int64), LinkTests(det, np.zeros((2, 2), bool), test))
    feet_kernels.warm_up()


@dataclass(frozen=True)
class FrameEvidence:
    """A frame's detections stacked over its V views (N in all) and its detection pairs that pass the gate (in the
    calibration's view pairs, every one that passes the link test).

    counts (V,); view_pairs (K, 2); per pair: pair (E,) its row of view_pairs, gi, gj (E,) global indices, d2 (E,)
    at the calibrated noise, dof (E,); scale2 the frame's squared noise scale; per detection: usable (N,) (feet or
    >= min_dof joints), bad (N,) (non-finite keypoints); lazy: the detections and the link tests for the merge."""

    counts: np.ndarray
    view_pairs: np.ndarray
    pair: np.ndarray
    gi: np.ndarray
    gj: np.ndarray
    d2: np.ndarray
    dof: np.ndarray
    scale2: float
    usable: np.ndarray
    bad: np.ndarray
    lazy: LinkTests


class EvidenceMatcher:
    """Matching by all shared evidence: ``matcher(views, rig) -> Matches``.

    reject_rate: the test's probability of rejecting a true pair whose noise follows ``noise_model`` (the 2D pixel
    sigma model); evidence_per_dof: log-likelihood ratio credited per agreeing dof; min_dof: fewest dof a pair needs;
    min_score: a joint is used from it on; feet: FeetMatcher keys of the ground-plane feet; calibrate, max_noise_scale,
    min_calibration_pairs: the frame's noise scale (:meth:`noise_scale2`); outlier_sd: one joint adds at most
    outlier_sd^2 model variances; link_scale: the noise factor of the merge's looser test; ambiguity_margin: a pair
    is kept only if every alternative assignment of its view pair costs this much more (log-likelihood ratio)."""

    def __init__(
        self,
        *,
        reject_rate: float = 1e-3,
        evidence_per_dof: float = 2.0,
        min_dof: int = 2,
        min_score: float = 0.2,
        noise_model: AnyNoiseModel | None = None,
        min_views: int = 2,
        ambiguity_margin: float = 2.0,
        feet: dict | None = None,
        calibrate: bool = True,
        max_noise_scale: float = 4.0,
        min_calibration_pairs: int = 5,
        outlier_sd: float = 12.0,
        link_scale: float = 2.0,
    ) -> None:
        if not 0 < reject_rate < 1 or int(min_dof) < 1 or int(min_views) < 1 or not evidence_per_dof >= 0:
            raise ValueError(
                "need 0 < reject_rate < 1, min_dof >= 1, min_views >= 1, evidence_per_dof >= 0; got "
                f"{reject_rate}, {min_dof}, {min_views}, {evidence_per_dof}"
            )
        if not max_noise_scale >= 1 or int(min_calibration_pairs) < 1:
            raise ValueError(
                f"need max_noise_scale, min_calibration_pairs >= 1; got {max_noise_scale}, {min_calibration_pairs}"
            )
        if not outlier_sd > 0:
            raise ValueError(f"outlier_sd must be > 0, got {outlier_sd}")
        if not 1 <= link_scale <= max_noise_scale:
            raise ValueError(f"need 1 <= link_scale <= max_noise_scale, got {link_scale}")
        if not 0 <= ambiguity_margin < np.inf:
            raise ValueError(f"ambiguity_margin must be a finite number >= 0, got {ambiguity_margin}")
        self.ambiguity_margin = float(ambiguity_margin)
        self.reject_rate, self.evidence_per_dof = float(reject_rate), float(evidence_per_dof)
        self.min_dof, self.min_score, self.min_views = int(min_dof), float(min_score), int(min_views)
        self.noise_model = NoiseModel() if noise_model is None else noise_model
        self.calibrate, self.max_noise_scale = bool(calibrate), float(max_noise_scale)
        self.min_calibration_pairs = int(min_calibration_pairs)
        self.outlier_sd, self.link_scale = float(outlier_sd), float(link_scale)
        self.last_noise_scale = 1.0
        self._rows_hint = 0  # rows of the detection-pair buffers: the last frame's count, with a margin
        self.feet = FeetMatcher(min_views=min_views, **{"pixel_sigma": 5.0, **(feet or {})})

    def detections(self, views: list[ViewDetections], rig: Rig) -> tuple[Detections, np.ndarray]:
        """The frame's detections stacked over views and which have non-finite keypoints (N,)."""
        if len(views) != len(rig):
            raise ValueError(f"{len(views)} views of detections for a rig of {len(rig)} cameras")
        counts = np.array([len(v) for v in views], dtype=np.int64)
        J = next((v.keypoints.shape[1] for v in views if len(v)), 23)
        for v in views:
            if len(v) and np.shape(v.keypoints)[1:] != (J, 3):
                raise ValueError(f"keypoints must have shape (N, {J}, 3) in every view, got {np.shape(v.keypoints)}")
        uv, var, bad = joint_variances(views, list(rig), self.min_score, self.noise_model, J)
        ends = np.cumsum(counts)  # a view with a non-finite keypoint (bad) gets it zeroed for the feet
        feet = self.feet.stacked_features(
            [_finite(v) if bad[e - len(v) : e].any() else v for v, e in zip(views, ends)], rig
        )
        offsets = np.concatenate([[0], ends]).astype(np.int64)
        p, cov = (np.ascontiguousarray(a, dtype=np.float64) for a in (feet.p, feet.cov))
        has_p, floor2 = np.asarray(feet.has_p, dtype=bool), self.feet.ground_sigma_floor**2
        return Detections(uv, var, offsets, has_p, p, cov, floor2, fundamentals(rig)), bad

    def frame_evidence(self, views: list[ViewDetections], rig: Rig) -> FrameEvidence:
        """The frame's detections and its detection pairs that pass the test at its calibrated noise."""
        det, bad = self.detections(views, rig)
        counts, J = np.diff(det.offsets), det.var.shape[1]
        view_pairs = _view_pairs(counts)
        pairs, scale2, done = self._calibrated_pairs(det, view_pairs)
        usable = det.has_p | ((det.var > 0).sum(axis=1) >= self.min_dof)
        tested = np.zeros((len(counts), len(counts)), dtype=bool)  # the calibration's view pairs: all link tests
        tested[view_pairs[:done, 0], view_pairs[:done, 1]] = tested[view_pairs[:done, 1], view_pairs[:done, 0]] = True
        link = ChiTest(
            gate_limits(self.reject_rate, J + 2) * self.link_scale**2, self.min_dof, self.outlier_sd**2, scale2
        )
        return FrameEvidence(counts, view_pairs, *pairs, scale2, usable, bad, LinkTests(det, tested, link))

    def __call__(self, views: list[ViewDetections], rig: Rig) -> Matches:
        """Assignment of one frame: V views -> Matches, (P, V) detection indices (-1 where absent)."""
        ev = self.frame_evidence(views, rig)
        self.last_noise_scale = float(np.sqrt(ev.scale2))
        limit = gate_limits(self.reject_rate, ev.lazy.det.var.shape[1] + 2)[ev.dof]
        links = ev.d2 <= limit * self.link_scale**2  # an untestable pair (inf at dof 0) is linked
        rows = np.flatnonzero((ev.d2 <= limit) & np.isfinite(ev.d2))
        q, offsets = ev.pair[rows], ev.lazy.det.offsets
        da, db = ev.gi[rows] - offsets[ev.view_pairs[q, 0]], ev.gj[rows] - offsets[ev.view_pairs[q, 1]]
        cost = 0.5 * ev.d2[rows] - self.evidence_per_dof * ev.dof[rows]
        starts = np.concatenate([[0], np.cumsum(np.bincount(q, minlength=len(ev.view_pairs)))]).astype(np.int64)
        keep = solve_sparse_pairs(starts, ev.counts[ev.view_pairs], da, db, cost)
        refused = np.zeros_like(keep)
        if self.ambiguity_margin > 0:
            refused = keep & (swap_regrets(starts, da, db, cost, keep) < self.ambiguity_margin)
            keep = keep & ~refused
        linked, kept = np.stack([ev.gi[links], ev.gj[links]], axis=1), rows[keep]
        assignment = _merge(ev.gi[kept], ev.gj[kept], cost[keep], ev.counts, linked, self.min_views, ev.lazy)
        ambiguous = np.concatenate([ev.gi[rows[refused]], ev.gj[rows[refused]]])
        return Matches(assignment, _unmatched(assignment, ev, ambiguous))

    def _calibrated_pairs(self, det: Detections, view_pairs: np.ndarray) -> tuple[list[np.ndarray], float, int]:
        """[view pair row, i, j, D^2 at the calibrated noise, dof] (E,) each of the detection pairs that pass, the
        frame's squared noise scale and the view pairs of the calibration (view_pairs[:done], under the link test)."""
        sizes, J = np.diff(det.offsets)[view_pairs].reshape(-1, 2), det.var.shape[1]
        # room for the largest view pair, or for the last frame's rows (a crowd's frames are alike: no regrowing)
        room = max(int(sizes.prod(axis=1).max(initial=0)) + 4 * len(det.var), self._rows_hint)
        out = [np.empty((room, 4), np.int64), np.empty((room, 2)), np.empty(int(sizes.min(axis=1).sum())), 0, 0]
        medians, loosest, scale2, done = chi2_medians(np.arange(J + 3)), self.max_noise_scale**2, 1.0, 0
        gate = gate_limits(self.reject_rate, J + 2)
        if self.calibrate:
            test = ChiTest(gate * self.link_scale**2, self.min_dof, self.outlier_sd**2, loosest)
            sample = Sample(medians, self.evidence_per_dof, CALIBRATION_SAMPLE)
            done = _run_pairs(det, view_pairs, 0, test, sample, out, sizes)
            scale2 = self.noise_scale2(out[2][: out[4]])
        first = out[3]  # rows computed at the loosest scale
        # the gate, widened by rounding: every row the gate lets through (its D^2 is recomputed) is computed
        test = ChiTest(gate * (1.0 + 1e-9), self.min_dof, self.outlier_sd**2, scale2)
        _run_pairs(det, view_pairs, done, test, Sample(medians, self.evidence_per_dof, 0), out, sizes)
        ints, floats = out[0][: out[3]], out[1][: out[3]]
        self._rows_hint = int(1.25 * out[3]) + int(sizes.prod(axis=1).max(initial=0))
        d2 = calibrated_chi2(floats, first, loosest, scale2)
        return [ints[:, 0], ints[:, 1], ints[:, 2], d2, ints[:, 3]], scale2, done

    def noise_scale2(self, ratios: list[float] | np.ndarray) -> float:
        """The frame's squared 2D noise over the model: the median of the calibration ratios (R,), clipped to
        [max_noise_scale^-2, max_noise_scale^2]; 1 with fewer than min_calibration_pairs.

        The ratios are body chi^2 / median(chi^2(body dof)) of each view pair's mutual best partners under the test
        widened by max_noise_scale: mostly true pairs, so their median estimates the squared scale robustly."""
        if len(ratios) < self.min_calibration_pairs:
            return 1.0
        # statistics.median, not np.median: a few dozen floats, where numpy's per-call overhead dominates
        median = statistics.median(np.asarray(ratios, dtype=np.float64).tolist())
        return float(min(max(median, self.max_noise_scale**-2), self.max_noise_scale**2))


def _run_pairs(det: Detections, view_pairs, q0: int, test: ChiTest, sample: Sample, out: list, sizes) -> int:
    """:func:`pairs_chi2` from view pair q0 into out = [ints, floats, ratios, n, nr], growing ints and floats when a
    view pair needs the room: -> view pairs done."""
    while True:
        out[3], out[4], q0 = pairs_chi2(det, view_pairs, q0, test, sample, *out)
        if q0 == len(view_pairs) or (sample.size > 0 and out[4] >= sample.size):
            return q0
        grow = 2 * len(out[0]) + int(sizes[q0].prod())
        out[0] = np.concatenate([out[0][: out[3]], np.empty((grow, 4), np.int64)])
        out[1] = np.concatenate([out[1][: out[3]], np.empty((grow, 2))])


def _unmatched(assignment: np.ndarray, ev: FrameEvidence, ambiguous: np.ndarray) -> Counter[str]:
    """Unmatched detections by reason: too little evidence (with NaN keypoints, or not), ambiguous (in a refused
    pair: global indices) or no counterpart."""
    placed = np.zeros(len(ev.usable), dtype=bool)
    placed[(ev.lazy.det.offsets[:-1] + assignment)[assignment >= 0]] = True
    unusable = ~placed & ~ev.usable
    refused = np.zeros(len(ev.usable), dtype=bool)
    refused[ambiguous] = True
    reasons: Counter[str] = Counter()
    reasons[NON_FINITE_KEYPOINTS] = int(np.count_nonzero(unusable & ev.bad))
    reasons[TOO_LITTLE_EVIDENCE] = int(np.count_nonzero(unusable)) - reasons[NON_FINITE_KEYPOINTS]
    reasons[AMBIGUOUS] = int(np.count_nonzero(~placed & ev.usable & refused))
    reasons[NO_COUNTERPART] = int(np.count_nonzero(~placed & ev.usable & ~refused))
    return +reasons


def _view_pairs(counts: np.ndarray) -> np.ndarray:
    """The view pairs (a < b) where both views have detections, neighbours first ((0, 1), (1, 2), ..., then (0, 2),
    ...: the calibration sample covers every view early): (K, 2) int64."""
    pairs = sorted(
        ((a, b) for a, b in combinations(range(len(counts)), 2) if counts[a] and counts[b]),
        key=lambda ab: (ab[1] - ab[0], ab[0]),
    )
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def _finite(view: ViewDetections) -> ViewDetections:
    """The view with non-finite keypoints zeroed (missing), for the feet features."""
    kp = np.asarray(view.keypoints, dtype=np.float64)
    finite = np.isfinite(kp).all(axis=-1, keepdims=True)
    return ViewDetections(
        np.where(finite, kp, 0.0), np.nan_to_num(view.bboxes), view.scores, view.person_ids, view.occluded
    )
