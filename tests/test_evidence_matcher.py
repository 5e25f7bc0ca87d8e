"""The default matcher: calibrated chi-square gate on feet + body evidence, complete-linkage merging."""

import hashlib
from collections import Counter

import numpy as np
import pytest

from data.keypoints import FOOT_JOINTS, LEFT_ANKLE, RIGHT_ANKLE
from data.multiview import Frame, ViewDetections
from data.synthetic import SyntheticConfig, generate_sequence
from data.synthetic.rigs import ring_rig
from evaluation.correspondence import CorrespondenceCounts, correspondence_counts
from reconstruction.matching import EvidenceMatcher
from reconstruction.matching.epipolar import fundamental_matrix
from reconstruction.matching.evidence import calibrated_chi2, gate_limits, merge_complete
from reconstruction.matching.evidence_kernels import ChiTest, Detections, Sample, _linked_now, _masks, pairs_chi2
from reconstruction.matching.feet_uncertainty import mahalanobis_distances
from reconstruction.noise_model import NoiseModel
from reconstruction.pipeline import MultiViewPipeline
from reconstruction.solver.map_solver import MLEMAPReconstruction

FEET_AND_ANKLES = [*FOOT_JOINTS, LEFT_ANKLE, RIGHT_ANKLE]


def _scene(seed: int = 5, persons: int = 6, cameras: int = 4):
    return generate_sequence(
        SyntheticConfig(
            seed=seed, num_frames=1, num_persons=persons, num_cameras=cameras, noise_px=1.0, occlusion=False
        )
    )


def _keep(views, joints) -> list[ViewDetections]:
    """Copies of the views with only the given joints seen (the others missing: score 0)."""
    out = []
    for v in views:
        kp = v.keypoints.copy()
        drop = np.setdiff1d(np.arange(kp.shape[1]), joints)
        kp[:, drop] = 0.0
        out.append(ViewDetections(kp, v.bboxes, v.scores, v.person_ids))
    return out


def _counts(assignment, views) -> CorrespondenceCounts:
    return correspondence_counts(assignment, [v.person_ids for v in views])


def test_a_pair_with_only_body_joints_is_matched():
    seq = _scene()
    body = np.setdiff1d(np.arange(23), FEET_AND_ANKLES)
    views = _keep(seq.frames[0].views, body)
    c = _counts(EvidenceMatcher()(views, seq.rig).assignment, views)
    assert c.precision == 1.0 and c.recall > 0.95


def test_a_pair_with_only_feet_is_matched():
    # 3 people far apart: the feet (2 degrees of freedom) are enough evidence
    seq = generate_sequence(
        SyntheticConfig(
            seed=2,
            num_frames=1,
            num_persons=3,
            num_cameras=3,
            noise_px=1.0,
            occlusion=False,
            positions=[[[-2.0, -2.0], [2.0, 0.0], [-1.0, 2.5]]],
            area=(-4.0, 4.0, -4.0, 4.0),
        )
    )
    views = _keep(seq.frames[0].views, FEET_AND_ANKLES)
    c = _counts(EvidenceMatcher(min_dof=2)(views, seq.rig).assignment, views)
    assert c.precision == 1.0 and c.recall == 1.0


def _two_views(uv_a, var_a, uv_b, var_b, F, feet_dx=None) -> Detections:
    """pairs_chi2's detections of two views (no feet, or feet midpoints feet_dx apart, unit covariance)."""
    na, nb = len(uv_a), len(uv_b)
    Fs = np.zeros((2, 2, 3, 3))
    Fs[0, 1] = F
    p = np.zeros((na + nb, 2))
    if feet_dx is not None:
        p[:na, 0] = feet_dx
    has_p = np.full(na + nb, feet_dx is not None)
    uv, var = np.concatenate([uv_a, uv_b]), np.concatenate([var_a, var_b])
    return Detections(uv, var, np.array([0, na, na + nb]), has_p, p, np.zeros((na + nb, 2, 2)), 1.0, Fs)


def _chi2(det: Detections, limits, min_dof=1, cap=1e9):
    """Detection pairs (i, j local) that pass, their chi^2 and dof, for two views."""
    assert len(limits) >= det.var.shape[1] + 3  # the kernel's contract: a limit for every dof up to feet + J
    room = int(np.prod(np.diff(det.offsets)))
    out = (np.empty((room, 4), np.int64), np.empty((room, 2)), np.empty(0), 0, 0)
    test, sample = ChiTest(limits, min_dof, float(cap), 1.0), Sample(np.ones(len(limits)), 2.0, 0)
    n, _, done = pairs_chi2(det, np.array([[0, 1]]), 0, test, sample, *out)
    ints, floats = out[0][:n], out[1][:n]
    assert done == 1 and np.all(ints[:, 0] == 0)
    return ints[:, 1], ints[:, 2] - det.offsets[1], floats[:, 0], ints[:, 3]


def test_the_gate_rejects_true_pairs_at_its_nominal_rate_whatever_the_degrees_of_freedom():
    # noise drawn exactly as the model says (2 px per coordinate): D^2 of a true pair is chi^2(common joints)
    rig = ring_rig(2, 6.0, 2.5)
    F = fundamental_matrix(rig[0], rig[1])
    rng = np.random.default_rng(0)
    rate = 0.05
    for joints in (3, 10, 20):
        X = rng.uniform([-1, -1, 0.2], [1, 1, 1.8], (400, joints, 3))
        uv = [rig[v].project(X) + rng.normal(0, 2.0, X.shape[:2] + (2,)) for v in (0, 1)]
        var = np.full((400, joints), 4.0)
        i, j, chi2, dof = _chi2(_two_views(uv[0], var, uv[1], var, F), gate_limits(rate, joints + 2))
        same = i == j
        rejected = 1 - np.sum(same) / 400
        assert abs(rejected - rate) < 3 * np.sqrt(rate * (1 - rate) / 400), (joints, rejected)
        assert np.all(dof[same] == joints) and np.all(np.isfinite(chi2))
        assert np.sum(~same) / (400 * 399) < 0.02  # the joints of another random person


def test_the_chi_square_is_the_sum_of_sampson_distances_and_the_feet_term():
    rig = ring_rig(2, 6.0, 2.5)
    F = fundamental_matrix(rig[0], rig[1])
    X = np.array([[[0.1, 0.2, 1.0], [0.3, -0.2, 1.5], [-0.4, 0.0, 0.5]]])
    a, b = rig[0].project(X), rig[1].project(X) + np.array([3.0, -2.0])
    var = np.array([[4.0, 9.0, 1.0]])
    # feet midpoints sqrt(2.5) m apart, covariance 0 + floor 1: a feet term of 2.5
    _, _, chi2, dof = _chi2(_two_views(a, var, b, var, F, np.sqrt(2.5)), gate_limits(1e-9, 5))
    ha, hb = np.c_[a[0], np.ones(3)], np.c_[b[0], np.ones(3)]
    la, lb = ha @ F.T, hb @ F
    e = np.sum(hb * la, axis=1)
    sampson = e**2 / (var[0] * (la[:, 0] ** 2 + la[:, 1] ** 2) + var[0] * (lb[:, 0] ** 2 + lb[:, 1] ** 2))
    assert dof[0] == 5
    np.testing.assert_allclose(chi2[0], 2.5 + sampson.sum())


def test_the_sparse_chi_square_equals_a_dense_reference():
    # random views: every pair's chi^2 (full sum, in joint order) where it passes, as a dense numpy computation
    rng = np.random.default_rng(4)
    rig = ring_rig(2, 6.0, 2.5)
    F = fundamental_matrix(rig[0], rig[1])
    X = rng.uniform([-1, -1, 0.2], [1, 1, 1.8], (30, 6, 3))
    uv = [rig[v].project(X[rng.permutation(30)[: 20 + 5 * v]]) + rng.normal(0, 3.0, (20 + 5 * v, 6, 2)) for v in (0, 1)]
    var = [np.where(rng.random((len(u), 6)) < 0.3, 0.0, 4.0) for u in uv]
    uv = [np.where(v[..., None] > 0, u, 0.0) for u, v in zip(uv, var)]
    limits, cap = gate_limits(1e-2, 6 + 2), 30.0
    i, j, chi2, dof = _chi2(_two_views(uv[0], var[0], uv[1], var[1], F), limits, 2, cap)
    ha = np.concatenate([uv[0], np.ones((20, 6, 1))], -1)
    hb = np.concatenate([uv[1], np.ones((25, 6, 1))], -1)
    la, lb = ha @ F.T, hb @ F  # (Na, J, 3), (Nb, J, 3)
    both = (var[0][:, None] > 0) & (var[1][None] > 0)
    e = np.einsum("bjr,ajr->abj", hb, la)
    denom = var[1][None] * (la[:, None, :, 0] ** 2 + la[:, None, :, 1] ** 2) + var[0][:, None] * (
        lb[None, :, :, 0] ** 2 + lb[None, :, :, 1] ** 2
    )
    terms = np.where(both, np.minimum(e**2 / np.where(both, denom, 1.0), cap), 0.0)
    d2, n = terms.sum(-1), both.sum(-1)
    passes = (n >= 2) & (d2 <= limits[n])
    np.testing.assert_array_equal(np.argwhere(passes), np.c_[i, j])
    np.testing.assert_allclose(chi2, d2[passes], rtol=1e-12)
    np.testing.assert_array_equal(dof, n[passes])


def test_the_chi_square_with_feet_equals_a_dense_reference():
    # feet of some detections only, covariances from near-singular to not positive semi-definite, midpoints near and
    # far: the kernel's feet test (run for a view at once before the loop) keeps exactly the pairs a dense
    # computation passes, with the same chi^2
    rng = np.random.default_rng(7)
    rig = ring_rig(2, 6.0, 2.5)
    F = fundamental_matrix(rig[0], rig[1])
    X = rng.uniform([-1, -1, 0.2], [1, 1, 1.8], (40, 6, 3))
    n = (30, 37)
    who = [rng.permutation(40)[: n[v]] for v in (0, 1)]
    uv = [rig[v].project(X[who[v]]) + rng.normal(0, 3.0, (n[v], 6, 2)) for v in (0, 1)]
    var = [np.where(rng.random((n[v], 6)) < 0.3, 0.0, 4.0) for v in (0, 1)]
    uv = [np.where(v[..., None] > 0, u, 0.0) for u, v in zip(uv, var)]
    det = _two_views(uv[0], var[0], uv[1], var[1], F)
    N = sum(n)
    A = rng.normal(0, 0.4, (N, 2, 2)) * rng.choice([1e-4, 1.0, 30.0], (N, 1, 1))
    cov = A @ A.transpose(0, 2, 1)
    cov[::9] = [[1.0, 2.0], [2.0, 1.0]]  # not positive semi-definite: the pair's determinant may be < 0
    cov[::11, 1] = 0.0  # singular
    cov[::7, 0, 1] += 0.2  # asymmetric: the test takes the symmetric part
    floor = 0.3
    ground = X[np.concatenate(who), 0, :2] + rng.normal(0, 0.5, (N, 2))  # a person's feet midpoint in both views
    det = det._replace(has_p=rng.random(N) < 0.8, p=ground, cov=cov, floor2=floor**2)
    limits, cap = gate_limits(1e-2, 6 + 2), 30.0
    i, j, chi2, dof = _chi2(det, limits, 2, cap)
    has, p = det.has_p, det.p
    feet = mahalanobis_distances(p[: n[0]], p[n[0] :], cov[: n[0]], cov[n[0] :], floor) ** 2
    both_feet = has[: n[0], None] & has[None, n[0] :]
    ha = np.concatenate([uv[0], np.ones((n[0], 6, 1))], -1)
    hb = np.concatenate([uv[1], np.ones((n[1], 6, 1))], -1)
    la, lb = ha @ F.T, hb @ F
    both = (var[0][:, None] > 0) & (var[1][None] > 0)
    e = np.einsum("bjr,ajr->abj", hb, la)
    denom = var[1][None] * (la[:, None, :, 0] ** 2 + la[:, None, :, 1] ** 2) + var[0][:, None] * (
        lb[None, :, :, 0] ** 2 + lb[None, :, :, 1] ** 2
    )
    terms = np.where(both, np.minimum(e**2 / np.where(both, denom, 1.0), cap), 0.0)
    d2 = terms.sum(-1) + np.where(both_feet, feet, 0.0)
    k = both.sum(-1) + 2 * both_feet
    passes = (k >= 2) & (d2 <= limits[k])
    assert 0 < passes.sum() < passes.size and passes[both_feet].any() and passes[~both_feet].any()
    assert np.any(both_feet & (feet > limits[-1])) and np.any(both_feet & (feet > 0.3 * limits[-1]) & passes)
    np.testing.assert_array_equal(np.argwhere(passes), np.c_[i, j])
    np.testing.assert_allclose(chi2, d2[passes], rtol=1e-12)
    np.testing.assert_array_equal(dof, k[passes])


def test_complete_linkage_never_joins_persons_whose_cross_pair_disagrees():
    # edges a0-b0 and b0-c0 pass, a0-c0 does not: c0 stays out; counts 1 per view
    edges = np.array([[0, 0, 1, 0, -5.0], [1, 0, 2, 0, -4.0]])
    linked = np.array([[0, 1], [2, 1]])
    out = merge_complete(edges, linked, [1, 1, 1], 2)
    np.testing.assert_array_equal(out, [[0, 0, -1]])
    np.testing.assert_array_equal(merge_complete(edges, np.r_[linked, [[0, 2]]], [1, 1, 1], 2), [[0, 0, 0]])
    # a0 and c0 share no evidence (no feet, no joint seen by both): nothing to test, so they may join
    has_feet, var = np.array([True, True, False]), np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    np.testing.assert_array_equal(merge_complete(edges, linked, [1, 1, 1], 2, (has_feet, var)), [[0, 0, 0]])
    var[2, 0] = 1.0
    np.testing.assert_array_equal(merge_complete(edges, linked, [1, 1, 1], 2, (has_feet, var)), [[0, 0, -1]])


def test_a_link_test_the_merge_computes_is_the_one_computed_with_every_pair():
    # a crowd whose calibration stops before the last view pairs: there the merge computes the link tests it
    # asks for; each must be the test of pairs_chi2 run over every pair at the link limits
    seq = generate_sequence(SyntheticConfig(seed=2, num_frames=1, num_persons=60, num_cameras=6, noise_px=2.0))
    matcher, views = EvidenceMatcher(), seq.frames[0].views
    ev = matcher.frame_evidence(views, seq.rig)
    det, tested, test = ev.lazy
    untested = ~tested[ev.view_pairs[:, 0], ev.view_pairs[:, 1]]
    assert 0 < untested.sum() < len(ev.view_pairs)
    room = int(np.prod(ev.counts[ev.view_pairs], axis=1).sum())
    out = (np.empty((room, 4), np.int64), np.empty((room, 2)), np.empty(0), 0, 0)
    n, _, _ = pairs_chi2(det, ev.view_pairs, 0, test, Sample(np.ones(len(test.limits)), 2.0, 0), *out)
    ints, d2 = out[0][:n], calibrated_chi2(out[1][:n], 0, 1.0, test.scale2)
    passes = d2 <= test.limits[ints[:, 3]]
    expected = {(int(i), int(j)) for q, i, j, _ in ints[passes] if untested[q]}
    view_of, masks = np.repeat(np.arange(len(views)), ev.counts), _masks(det.var)
    row = (np.empty((1, 4), np.int64), np.empty((1, 2)))
    computed = set()
    for q in np.flatnonzero(untested):
        a, b = ev.view_pairs[q]
        for i in range(det.offsets[a], det.offsets[a + 1]):
            for j in range(det.offsets[b], det.offsets[b + 1]):
                if _linked_now(j, i, view_of, masks, ev.lazy, row):  # either order
                    computed.add((i, j))
    assert len(expected) > 100 and computed == expected


def test_precise_in_a_dense_crowd_where_the_paper_matcher_merges_wrongly():
    seq = generate_sequence(
        SyntheticConfig(seed=1, num_frames=2, num_persons=80, area=(-4.5, 4.5, -4.5, 4.5), num_cameras=5, noise_px=2.0)
    )
    total = CorrespondenceCounts()
    matcher = EvidenceMatcher()
    for frame in seq.frames:
        total = total + _counts(matcher(frame.views, seq.rig).assignment, frame.views)
    assert total.precision > 0.98 and total.recall > 0.7


def test_the_assignments_are_those_of_the_dense_implementation():
    # sha256 of the (P, V) int64 assignments of both frames, as the dense per-view-pair implementation (commit
    # df9a567, before the sparse kernels) gave them: same persons, same order, same unmatched counts
    seq = generate_sequence(
        SyntheticConfig(seed=1, num_frames=2, num_persons=80, area=(-4.5, 4.5, -4.5, 4.5), num_cameras=5, noise_px=2.0)
    )
    matcher, digest, unmatched = EvidenceMatcher(ambiguity_margin=0.0), hashlib.sha256(), Counter()  # no refusals
    for frame in seq.frames:
        matches = matcher(frame.views, seq.rig)
        digest.update(np.ascontiguousarray(matches.assignment, dtype=np.int64).tobytes())
        unmatched += matches.unmatched
    assert digest.hexdigest()[:16] == "1136323799c2132a"
    assert unmatched == {"no_counterpart": 8, "too_little_evidence": 1}
    assert matcher.last_noise_scale == pytest.approx(0.45891882886317503, rel=1e-12)


def test_bad_detections_are_reported_as_unmatched_by_reason_not_a_crash():
    seq = _scene()
    views = [ViewDetections(v.keypoints.copy(), v.bboxes, v.scores, v.person_ids) for v in seq.frames[0].views]
    views[0].keypoints[0] = np.nan  # a detection of NaN keypoints
    views[1].keypoints[0, 1:] = 0.0  # one with a single joint
    views[2].keypoints[0, :5] = np.nan  # some NaN joints: still usable
    matcher = EvidenceMatcher()
    assignment, reasons = matcher(views, seq.rig)
    assert reasons["non_finite_keypoints"] == 1 and reasons["too_little_evidence"] == 1
    assert 0 not in assignment[:, 0] and 0 not in assignment[:, 1] and 0 in assignment[:, 2]
    assert _counts(assignment, views).precision == 1.0


def test_a_view_whose_keypoints_have_another_joint_count_is_named():
    seq = _scene()
    views = list(seq.frames[0].views)
    v = views[1]
    views[1] = ViewDetections(v.keypoints[:, :17], v.bboxes, v.scores, v.person_ids)  # COCO-17 among COCO-23
    with pytest.raises(ValueError, match=r"keypoints must have shape \(N, 23, 3\) in every view, got \(6, 17, 3\)"):
        EvidenceMatcher()(views, seq.rig).assignment


def test_a_frame_with_nan_keypoints_is_reconstructed_without_them():
    seq = _scene()
    views = [ViewDetections(v.keypoints.copy(), v.bboxes, v.scores, v.person_ids) for v in seq.frames[0].views]
    views[0].keypoints[0] = np.nan
    views[2].keypoints[0, :5] = np.nan
    views[1].keypoints[1, 3, 2] = np.inf
    result = MultiViewPipeline(seq.rig, EvidenceMatcher(), MLEMAPReconstruction())(Frame(0, views))
    assert len(result.poses3d) == 6 and np.isfinite(result.poses3d).all()


def test_rejects_bad_settings():
    for bad in (
        {"reject_rate": 0.0},
        {"min_dof": 0},
        {"max_noise_scale": 0.5},
        {"link_scale": 10.0},
        {"outlier_sd": 0.0},
    ):
        with pytest.raises(ValueError):
            EvidenceMatcher(**bad)


def test_the_noise_calibration_follows_the_detector():
    # the same scene with 1 and 4 px of noise: the estimated scale grows about 4x
    scales = []
    for noise in (1.0, 4.0):
        seq = generate_sequence(
            SyntheticConfig(
                seed=3,
                num_frames=1,
                num_persons=8,
                num_cameras=4,
                noise_px=noise,
                noise_depth_exponent=0.0,
                occlusion=False,
            )
        )
        m = EvidenceMatcher(noise_model=NoiseModel(sigma_px=1.0, c=0.0, score_power=0.0))
        m(seq.frames[0].views, seq.rig).assignment
        scales.append(m.last_noise_scale)
    assert 0.6 < scales[0] < 1.5 and 2.5 < scales[1] / scales[0] < 5.5


@pytest.mark.parametrize("reject_rate", [1e-2, 1e-4])
def test_gate_limits_are_scipy_chi2_quantiles(reject_rate: float) -> None:
    from scipy.stats import chi2

    limits = gate_limits(reject_rate, 60)
    assert limits[0] == np.inf
    np.testing.assert_array_equal(limits[1:], chi2.ppf(1 - reject_rate, np.arange(1, 61)))
