import numpy as np

from evaluation.association import joint_errors, match_to_ground_truth, mpjpe
from evaluation.pcp import PART_NAMES, correct_parts, pcp_by_part
from evaluation.pose3d import Pose3DEvaluator


def poses(rng, n):
    out = np.ones((n, 23, 4))
    out[..., :3] = rng.uniform(-0.3, 0.3, (n, 23, 3)) + rng.uniform(-5, 5, (n, 1, 3))
    return out


def test_mpjpe_known_answer_and_root_alignment():
    gt = np.zeros((1, 23, 4))
    gt[..., 3] = 1
    pred = gt.copy()
    pred[..., 0] += 0.03
    pred[0, 4, 1] += 0.04  # joint 4 off by (0.03, 0.04) -> 5 cm
    err = joint_errors(pred, gt)
    np.testing.assert_allclose(err[0, 4], 0.05)
    np.testing.assert_allclose(mpjpe(err), (22 * 0.03 + 0.05) / 23)
    rooted = joint_errors(pred, gt, root=(11, 12))
    np.testing.assert_allclose(rooted[0, 4], 0.04, atol=1e-12)  # the common 3 cm shift is gone
    pred[0, 7, 3] = 0
    assert np.isnan(joint_errors(pred, gt)[0, 7])


def test_ground_truth_association_is_order_invariant_and_gated():
    rng = np.random.default_rng(0)
    gt = poses(rng, 6)
    pred = gt[[3, 0, 5, 1]].copy()
    pred[..., :3] += rng.normal(0, 0.01, pred[..., :3].shape)
    pairs = match_to_ground_truth(pred, gt)
    assert sorted(map(tuple, pairs)) == [(0, 3), (1, 0), (2, 5), (3, 1)]
    far = pred.copy()
    far[1, :, :3] += 2.0
    assert (1, 0) not in set(map(tuple, match_to_ground_truth(far, gt, max_dist_m=0.5)))


def test_pcp_part_rule_known_answers():
    gt = np.zeros((1, 15, 3))
    gt[0, 8], gt[0, 7] = [0, 0, 1.4], [0, 0, 1.1]  # right upper arm, 0.3 m
    pred = gt.copy()
    pred[0, 7] += [0.29, 0, 0]  # mean end-point error 0.145 <= 0.15
    assert correct_parts(pred, gt)[0, 0]
    pred[0, 7] += [0.02, 0, 0]  # 0.155 > 0.15
    assert not correct_parts(pred, gt)[0, 0]
    scores = pcp_by_part(np.array([[True] * 9 + [False]]))
    assert scores["torso"] == 0.0 and scores["head"] == 100.0 and scores["average"] == 90.0
    assert list(scores)[:-1] == list(PART_NAMES)


def test_evaluator_counts_missed_people_as_wrong_parts():
    rng = np.random.default_rng(1)
    gt = poses(rng, 4)
    ev = Pose3DEvaluator()
    ev.update(gt[:3].copy(), gt)  # perfect on 3 of 4 persons, one missed
    s = ev.summary()
    assert s["mpjpe_mm"] == 0.0 and s["num_matched"] == 3 and s["recall"] == 75.0
    np.testing.assert_allclose(s["pcp_average"], 75.0)
