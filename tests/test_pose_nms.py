"""Pose-NMS (models/pose_nms.py): a duplicated box of one person is merged away, distinct people are kept."""

from __future__ import annotations

import numpy as np
import pytest

from data.keypoints import NUM_JOINTS, OKS_SIGMAS
from models.pose_nms import joint_similarity, pose_nms


def person(rng: np.random.Generator, x0: float, y0: float = 50.0) -> tuple[np.ndarray, np.ndarray]:
    """A random pose (23, 3) in a 60 x 160 box at (x0, y0) and the box (4,)."""
    xy = rng.uniform((x0, y0), (x0 + 60, y0 + 160), (NUM_JOINTS, 2))
    return np.column_stack([xy, rng.uniform(0.3, 0.9, NUM_JOINTS)]), np.array([x0, y0, 60.0, 160.0])


def test_duplicate_box_is_merged_and_distinct_people_are_kept():
    rng = np.random.default_rng(0)
    a, box_a = person(rng, 0.0)
    b, box_b = person(rng, 100.0)  # another person beside a
    dup = a.copy()
    dup[:, :2] += rng.normal(0, 1.0, (NUM_JOINTS, 2))  # the same person seen from a shifted box
    dup[:, 2] = 0.5
    keypoints = np.stack([dup, a, b])
    boxes = np.stack([box_a + [3, -2, 4, 0], box_a, box_b])
    scores = np.array([0.6, 0.9, 0.8])
    copies = keypoints.copy(), boxes.copy(), scores.copy()
    keep, merged = pose_nms(keypoints, boxes, scores, oks=0.7)
    assert keep.tolist() == [1, 2]  # the duplicate (lower score) went into a; b stays as it was
    np.testing.assert_array_equal(merged[1], b)
    w = np.stack([a[:, 2], dup[:, 2]])  # every joint of the duplicate agrees with a's (1 px noise)
    expected = (w[..., None] * np.stack([a[:, :2], dup[:, :2]])).sum(0) / w.sum(0)[:, None]
    np.testing.assert_allclose(merged[0, :, :2], expected)
    np.testing.assert_allclose(merged[0, :, 2], np.maximum(a[:, 2], 0.5))
    for before, after in zip(copies, (keypoints, boxes, scores)):
        np.testing.assert_array_equal(before, after)


def test_overlap_is_the_coco_oks():
    ref = np.zeros((NUM_JOINTS, 3))
    ref[:, 2] = 1.0
    other = ref.copy()
    other[:, 0] = 5.0
    area = 60.0 * 160.0
    sim = joint_similarity(ref, other[None], area, OKS_SIGMAS)
    np.testing.assert_allclose(sim[0], np.exp(-25.0 / (2 * area * (2 * OKS_SIGMAS) ** 2)))
    # just above and below the threshold: merged, kept
    oks = sim.mean()
    keypoints, boxes = np.stack([ref, other]), np.array([[0, 0, 60.0, 160.0]] * 2)
    assert pose_nms(keypoints, boxes, np.array([1.0, 0.5]), oks=oks - 1e-6)[0].tolist() == [0]
    assert pose_nms(keypoints, boxes, np.array([1.0, 0.5]), oks=oks + 1e-6)[0].tolist() == [0, 1]


def test_a_duplicate_that_lost_its_joints_to_the_association_still_merges():
    rng = np.random.default_rng(1)
    a, box = person(rng, 0.0)
    lost = a.copy()
    lost[:, 2] = 0.0  # global association gave every joint to a; positions kept
    keep, merged = pose_nms(np.stack([a, lost]), np.stack([box, box]), np.array([0.8, 0.0]))
    assert keep.tolist() == [0]
    np.testing.assert_allclose(merged[0], a, rtol=1e-12)  # the score-0 duplicate adds no weight


def test_empty_and_mismatched_inputs():
    keep, merged = pose_nms(np.zeros((0, NUM_JOINTS, 3)), np.zeros((0, 4)), np.zeros(0))
    assert keep.shape == (0,) and merged.shape == (0, NUM_JOINTS, 3)
    with pytest.raises(ValueError, match="shape mismatch"):
        pose_nms(np.zeros((2, NUM_JOINTS, 3)), np.zeros((1, 4)), np.zeros(2))
