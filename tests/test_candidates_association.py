"""Multi-peak heatmap decoding, back-projection to the image, and the global joints association."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from scipy.ndimage import maximum_filter

from data.keypoints import NUM_JOINTS, OKS_SIGMAS
from models.candidates import candidates_to_image, find_candidates
from models.joint_association import associate_joints


def gaussian(h: int, w: int, centre: tuple[float, float], sigma: float = 2.0, amp: float = 1.0) -> np.ndarray:
    """A Gaussian blob (h, w) at a sub-pixel (x, y) heatmap position."""
    ys, xs = np.mgrid[0:h, 0:w]
    return amp * np.exp(-((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2) / (2 * sigma**2))


def candidates(heatmaps, **options) -> tuple[np.ndarray, np.ndarray]:
    """find_candidates as numpy arrays."""
    xy, scores = find_candidates(heatmaps, **options)
    return xy.numpy(), scores.numpy()


def test_two_gaussian_peaks_at_sub_pixel_positions():
    hm = gaussian(64, 48, (12.3, 20.7)) + gaussian(64, 48, (33.6, 45.2), amp=0.7)
    xy, scores = candidates(hm[None, None], threshold=0.1, top_m=3)
    assert xy.shape == (1, 1, 3, 2) and scores.shape == (1, 1, 3)
    np.testing.assert_allclose(xy[0, 0, 0], (12.3, 20.7), atol=0.25)
    np.testing.assert_allclose(xy[0, 0, 1], (33.6, 45.2), atol=0.25)
    assert scores[0, 0, 0] > scores[0, 0, 1] > 0.6
    assert scores[0, 0, 2] == 0 and np.all(xy[0, 0, 2] == 0)
    only_high, high_scores = candidates(hm[None, None], threshold=0.8, top_m=3)
    assert np.count_nonzero(high_scores) == 1
    np.testing.assert_allclose(only_high[0, 0, 0], (12.3, 20.7), atol=0.25)


def test_suppression_keeps_exactly_the_local_maxima():
    rng = np.random.default_rng(3)
    hm = rng.uniform(0, 1, (2, 3, 9, 11))
    xy, scores = candidates(torch.from_numpy(hm), threshold=0.3, top_m=200, nms_kernel=3)
    for b in range(2):
        for j in range(3):
            peak = (hm[b, j] == maximum_filter(hm[b, j], size=3, mode="constant", cval=-1)) & (hm[b, j] > 0.3)
            expected = np.sort(hm[b, j][peak])[::-1]
            np.testing.assert_allclose(scores[b, j, : len(expected)], expected)
            assert np.all(scores[b, j, len(expected) :] == 0)
            rows, cols = np.nonzero(peak)
            near = np.abs(xy[b, j, : len(expected), None] - np.stack([cols, rows], 1)[None]).max(-1) <= 0.5
            assert near.any(axis=1).all()
    np_xy, np_scores = candidates(hm, threshold=0.3, top_m=200)
    np.testing.assert_array_equal(np_scores, scores)
    np.testing.assert_allclose(np_xy, xy)


def test_back_projection_through_a_known_affine():
    inverse = np.array([[[2.0, 0.0, 100.0], [0.0, 2.0, 50.0]]])
    out = candidates_to_image(np.array([[[[3.0, 5.0]]]]), inverse, stride=4)
    np.testing.assert_allclose(out[0, 0, 0], (2 * 13.5 + 100, 2 * 21.5 + 50))


def test_gaussian_rendered_at_an_image_point_decodes_back_to_it():
    forward = cv2.getRotationMatrix2D((150.0, 120.0), 30.0, 0.8)  # image -> crop input
    forward[:, 2] += (-60.0, -20.0)
    inverse = cv2.invertAffineTransform(forward)
    point = np.array([170.4, 131.9])
    x_in = forward[:, :2] @ point + forward[:, 2]
    x_hm = (x_in + 0.5) / 4 - 0.5
    hm = gaussian(64, 48, tuple(x_hm))
    xy, _ = candidates(hm[None, None], top_m=1)
    image_xy = candidates_to_image(xy, inverse[None], stride=4)
    np.testing.assert_allclose(image_xy[0, 0, 0], point, atol=0.05)


def one_joint(cands: list[list[tuple[float, float, float]]]) -> tuple[np.ndarray, np.ndarray]:
    """xy (P, 1, M, 2), scores (P, 1, M) from per-person lists of (x, y, score)."""
    m = max(len(c) for c in cands)
    arr = np.zeros((len(cands), 1, m, 3))
    for p, c in enumerate(cands):
        arr[p, 0, : len(c)] = c
    return arr[..., :2], arr[..., 2]


WRIST = np.array([OKS_SIGMAS[9]])
BOXES = np.array([[0.0, 0.0, 100.0, 200.0], [30.0, 0.0, 100.0, 200.0]])


def test_single_person_gives_the_argmax():
    xy, scores = one_joint([[(10, 20, 0.4), (50, 60, 0.8), (70, 80, 0.2)]])
    out = associate_joints(xy, scores, BOXES[:1], sigmas=WRIST)
    np.testing.assert_allclose(out[0, 0], (50, 60, 0.8))
    out = associate_joints(*one_joint([[(10, 20, 0.4)]]), BOXES[:1], sigmas=WRIST)
    np.testing.assert_allclose(out[0, 0], (10, 20, 0.4))


def test_two_boxes_claiming_one_wrist():
    xy, scores = one_joint([[(61, 100.5, 0.6), (20, 150, 0.3)], [(60, 100, 0.9)]])
    out = associate_joints(xy, scores, BOXES, sigmas=WRIST)
    np.testing.assert_allclose(out[1, 0], (60, 100, 0.9))
    np.testing.assert_allclose(out[0, 0], (20, 150, 0.3))
    # without a second candidate, A keeps its position with score 0
    xy, scores = one_joint([[(61, 100.5, 0.6)], [(60, 100, 0.9)]])
    out = associate_joints(xy, scores, BOXES, sigmas=WRIST)
    np.testing.assert_allclose(out[:, 0], [(61, 100.5, 0.0), (60, 100, 0.9)])


def test_distinct_nearby_joints_are_not_merged():
    xy, scores = one_joint([[(40, 100, 0.6)], [(80, 100, 0.9)]])  # 40 px > radius 0.062 * 141 = 8.8 px
    out = associate_joints(xy, scores, BOXES, sigmas=WRIST)
    np.testing.assert_allclose(out[:, 0], [(40, 100, 0.6), (80, 100, 0.9)])
    assert np.all(associate_joints(xy, np.zeros_like(scores), BOXES, sigmas=WRIST) == 0)


def crowd(rng: np.random.Generator, n: int = 6, m: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Overlapping persons whose candidates include their neighbours' joints: xy, scores, boxes."""
    joints = rng.uniform(0, 40, (n, NUM_JOINTS, 2)) + np.arange(n)[:, None, None] * 15.0
    xy = np.empty((n, NUM_JOINTS, m, 2))
    xy[:, :, 0] = joints + rng.normal(0, 0.5, joints.shape)
    for k in range(1, m):
        other = (np.arange(n) + k) % n
        xy[:, :, k] = joints[other] + rng.normal(0, 0.5, joints.shape)
    scores = rng.uniform(0.05, 1.0, (n, NUM_JOINTS, m))
    boxes = np.concatenate([joints.min(1), np.full((n, 2), 80.0)], axis=1)
    return xy, scores, boxes


def test_permuting_persons_permutes_the_output():
    rng = np.random.default_rng(11)
    xy, scores, boxes = crowd(rng)
    copies = xy.copy(), scores.copy(), boxes.copy()
    out = associate_joints(xy, scores, boxes)
    assert np.any(out[..., 2] < scores.max(-1))  # some person lost its best candidate: conflicts exist
    for _ in range(3):
        perm = rng.permutation(len(xy))
        np.testing.assert_array_equal(associate_joints(xy[perm], scores[perm], boxes[perm]), out[perm])
    for before, after in zip(copies, (xy, scores, boxes)):
        np.testing.assert_array_equal(before, after)


def test_no_two_persons_share_a_joint_node():
    xy, scores, boxes = crowd(np.random.default_rng(5))
    out = associate_joints(xy, scores, boxes, dist_thresh=1.0)
    radius = OKS_SIGMAS[None, :] * np.sqrt(boxes[:, 2] * boxes[:, 3])[:, None]  # (P, J)
    for j in range(NUM_JOINTS):
        matched = np.nonzero(out[:, j, 2] > 0)[0]
        for a in matched:
            for b in matched[matched > a]:
                d = np.linalg.norm(out[a, j, :2] - out[b, j, :2])
                assert d > (radius[a, j] + radius[b, j]) / 2


def test_shape_mismatch_is_refused():
    xy, scores, boxes = crowd(np.random.default_rng(0))
    with pytest.raises(ValueError, match="shape mismatch"):
        associate_joints(xy, scores, boxes[:-1])
