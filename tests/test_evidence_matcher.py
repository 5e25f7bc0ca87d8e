"""The default matcher: calibrated chi-square gate on feet + body evidence, complete-linkage merging."""

import numpy as np
import pytest

from data.keypoints import FOOT_JOINTS, LEFT_ANKLE, RIGHT_ANKLE
from data.multiview import Frame, ViewDetections
from data.synthetic import SyntheticConfig, generate_sequence
from data.synthetic.rigs import ring_rig
from evaluation.correspondence import CorrespondenceCounts, correspondence_counts
from reconstruction.matching import EvidenceMatcher
from reconstruction.matching.epipolar import fundamental_matrix
from reconstruction.matching.evidence import gate_limits, merge_complete
from reconstruction.matching.evidence_kernels import pair_chi2
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
    c = _counts(EvidenceMatcher()(views, seq.rig), views)
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
    c = _counts(EvidenceMatcher(min_dof=2)(views, seq.rig), views)
    assert c.precision == 1.0 and c.recall == 1.0


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
        out, dof = np.empty((400, 400)), np.empty((400, 400), dtype=np.int64)
        pair_chi2(
            uv[0], var, uv[1], var, F, np.full((400, 400), np.nan), gate_limits(rate, joints), 1, 1e9, 1.0, out, dof
        )
        rejected = np.mean(~np.isfinite(np.diag(out)))
        assert abs(rejected - rate) < 3 * np.sqrt(rate * (1 - rate) / 400), (joints, rejected)
        assert np.all(np.diag(dof)[np.isfinite(np.diag(out))] == joints)
        unrelated = out[~np.eye(400, dtype=bool)]  # the joints of another random person
        assert np.mean(np.isfinite(unrelated)) < 0.02


def test_the_chi_square_is_the_sum_of_sampson_distances_and_the_feet_term():
    rig = ring_rig(2, 6.0, 2.5)
    F = fundamental_matrix(rig[0], rig[1])
    X = np.array([[[0.1, 0.2, 1.0], [0.3, -0.2, 1.5], [-0.4, 0.0, 0.5]]])
    a, b = rig[0].project(X), rig[1].project(X) + np.array([3.0, -2.0])
    var = np.array([[4.0, 9.0, 1.0]])
    out, dof = np.empty((1, 1)), np.empty((1, 1), dtype=np.int64)
    pair_chi2(a, var, b, var, F, np.array([[2.5]]), gate_limits(1e-9, 5), 1, 1e9, 1.0, out, dof)
    ha, hb = np.c_[a[0], np.ones(3)], np.c_[b[0], np.ones(3)]
    la, lb = ha @ F.T, hb @ F
    e = np.sum(hb * la, axis=1)
    sampson = e**2 / (var[0] * (la[:, 0] ** 2 + la[:, 1] ** 2) + var[0] * (lb[:, 0] ** 2 + lb[:, 1] ** 2))
    assert dof[0, 0] == 5
    np.testing.assert_allclose(out[0, 0], 2.5 + sampson.sum())


def test_complete_linkage_never_joins_persons_whose_cross_pair_disagrees():
    # edges a0-b0 and b0-c0 pass, a0-c0 does not: c0 stays out; counts 1 per view
    edges = np.array([[0, 0, 1, 0, -5.0], [1, 0, 2, 0, -4.0]])
    linked = np.zeros((3, 3), dtype=bool)
    linked[0, 1] = linked[1, 0] = linked[1, 2] = linked[2, 1] = True
    out = merge_complete(edges, linked, [1, 1, 1], 2)
    np.testing.assert_array_equal(out, [[0, 0, -1]])
    linked[0, 2] = linked[2, 0] = True
    np.testing.assert_array_equal(merge_complete(edges, linked, [1, 1, 1], 2), [[0, 0, 0]])


def test_precise_in_a_dense_crowd_where_the_paper_matcher_merges_wrongly():
    seq = generate_sequence(
        SyntheticConfig(seed=1, num_frames=2, num_persons=80, area=(-4.5, 4.5, -4.5, 4.5), num_cameras=5, noise_px=2.0)
    )
    total = CorrespondenceCounts()
    matcher = EvidenceMatcher()
    for frame in seq.frames:
        total = total + _counts(matcher(frame.views, seq.rig), frame.views)
    assert total.precision > 0.98 and total.recall > 0.7


def test_bad_detections_are_reported_as_unmatched_by_reason_not_a_crash():
    seq = _scene()
    views = [ViewDetections(v.keypoints.copy(), v.bboxes, v.scores, v.person_ids) for v in seq.frames[0].views]
    views[0].keypoints[0] = np.nan  # a detection of NaN keypoints
    views[1].keypoints[0, 1:] = 0.0  # one with a single joint
    views[2].keypoints[0, :5] = np.nan  # some NaN joints: still usable
    matcher = EvidenceMatcher()
    assignment = matcher(views, seq.rig)
    reasons = matcher.last_unmatched_reasons
    assert reasons["non_finite_keypoints"] == 1 and reasons["too_little_evidence"] == 1
    assert 0 not in assignment[:, 0] and 0 not in assignment[:, 1] and 0 in assignment[:, 2]
    assert _counts(assignment, views).precision == 1.0


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
        {"c": 0.0, "sigma_px": 0.0, "sigma_min": 0.0},
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
        m = EvidenceMatcher(sigma_px=1.0, c=0.0, score_power=0.0)
        m(seq.frames[0].views, seq.rig)
        scales.append(m.last_noise_scale)
    assert 0.6 < scales[0] < 1.5 and 2.5 < scales[1] / scales[0] < 5.5


@pytest.mark.parametrize("reject_rate", [1e-2, 1e-4])
def test_gate_limits_are_scipy_chi2_quantiles(reject_rate: float) -> None:
    from scipy.stats import chi2

    limits = gate_limits(reject_rate, 60)
    assert limits[0] == np.inf
    np.testing.assert_array_equal(limits[1:], chi2.ppf(1 - reject_rate, np.arange(1, 61)))
