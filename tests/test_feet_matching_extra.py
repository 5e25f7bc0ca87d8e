"""Feet matcher acceptance points not covered by test_feet_matching.py: three-view conflicts end to end,
the calibrated homographies against cv2, people far apart, and a view where a person's feet are hidden."""

import cv2
import numpy as np
import pytest

from data.geometry.camera import Camera, apply_homography
from data.keypoints import LEFT_ANKLE, LEFT_FOOT, NUM_JOINTS, RIGHT_ANKLE, RIGHT_FOOT
from data.multiview import ViewDetections
from reconstruction.matching import FeetMatcher
from reconstruction.matching.feet import NO_COUNTERPART, NO_FOOT_JOINTS, feet_features, pair_homography
from tests.test_feet_matching import crowd, matched_id_sets, person, ring_rig, scene

DIST = (-0.25, 0.05, 0.001, -0.001, 0.0)


def feet_only(cam: Camera, midpoints: list[tuple[float, float]], ids: list[int]) -> ViewDetections:
    """Detections with only foot joints scored, feet 0.3 m apart along y around ground midpoints (N, 2)."""
    kp = np.zeros((len(midpoints), NUM_JOINTS, 3))
    for n, (x, y) in enumerate(midpoints):
        for foot, dy in ((LEFT_FOOT, -0.15), (RIGHT_FOOT, 0.15)):
            kp[n, list(foot), :2] = cam.project(np.array([x, y + dy, 0.0]))
            kp[n, list(foot), 2] = 0.9
    return ViewDetections(kp, np.ones((len(ids), 4)), np.ones(len(ids)), np.array(ids, np.int64))


def test_three_view_conflict_is_resolved_in_favour_of_the_cheaper_edges():
    # Ground midpoints on the x axis, equal strides, so an edge costs |dp| (k1 = 1): view 0 holds A (0)
    # and B (0.38), views 1 and 2 one detection each at 0.05 and 0.2. The pairs pick A0-D1 (0.05),
    # B0-D2 (0.18) and D1-D2 (0.15): together they chain A0 and B0, two view-0 detections.
    rig = ring_rig(3)
    views = [
        feet_only(rig[0], [(0.0, 0.0), (0.38, 0.0)], [0, 1]),
        feet_only(rig[1], [(0.05, 0.0)], [2]),
        feet_only(rig[2], [(0.2, 0.0)], [3]),
    ]
    matcher = FeetMatcher(location_metric="euclidean")  # costs in metres (the default is in standard deviations)
    feats = matcher.features(views, rig)
    np.testing.assert_allclose(matcher.pair_cost(feats[0], feats[1], rig[0]), [[0.05], [0.33]], atol=1e-9)
    np.testing.assert_allclose(matcher.pair_cost(feats[0], feats[2], rig[0]), [[0.2], [0.18]], atol=1e-9)
    np.testing.assert_allclose(matcher.pair_cost(feats[1], feats[2], rig[1]), [[0.15]], atol=1e-9)
    # Cheapest first: A0-D1 (0.05), D1-D2 (0.15), then B0-D2 (0.18) is refused. Solving pair by pair
    # in view order would instead have kept B0-D2 and refused D1-D2.
    assignment, reasons = matcher(views, rig)
    np.testing.assert_array_equal(assignment, [[0, 0, 0]])
    assert reasons == {NO_COUNTERPART: 1}
    swapped = [feet_only(rig[0], [(0.38, 0.0), (0.0, 0.0)], [1, 0])] + views[1:]
    np.testing.assert_array_equal(matcher(swapped, rig).assignment, [[1, 0, 0]])


def normalised(H: np.ndarray) -> np.ndarray:
    """A homography up to scale: unit Frobenius norm, H[2, 2] > 0 (3, 3)."""
    return H / np.linalg.norm(H) * np.sign(H[2, 2])


@pytest.mark.parametrize("dist", [(0, 0, 0, 0, 0), DIST])
def test_ground_homography_equals_the_one_cv2_estimates_from_four_ground_points(dist):
    cam = ring_rig(4, dist=dist)[1]
    ground = np.array([[-2.0, -1.5], [2.5, -1.0], [1.5, 2.0], [-1.0, 2.5]])
    pixels = cam.undistort_points(cam.project(np.column_stack([ground, np.zeros(4)])))
    H, _ = cv2.findHomography(pixels, ground, 0)
    np.testing.assert_allclose(normalised(cam.image_to_ground_homography()), normalised(H), atol=1e-6)
    G, _ = cv2.findHomography(ground, pixels, 0)
    np.testing.assert_allclose(normalised(cam.ground_to_image_homography()), normalised(G), atol=1e-6)


@pytest.mark.parametrize("pair", [(0, 1), (2, 0), (1, 3)])
def test_pair_homography_equals_the_one_cv2_estimates_from_four_ground_points(pair):
    rig = ring_rig(4, dist=DIST)
    l, m = rig[pair[0]], rig[pair[1]]
    ground = np.column_stack([[-2.0, 2.5, 1.5, -1.0], [-1.5, -1.0, 2.0, 2.5], np.zeros(4)])
    in_l, in_m = (c.undistort_points(c.project(ground)) for c in (l, m))
    H, _ = cv2.findHomography(in_m, in_l, 0)  # view m -> view l
    ours = pair_homography(l, m)
    np.testing.assert_allclose(normalised(ours), normalised(H), atol=1e-6)
    other = np.array([[0.3, -0.7, 0.0]])  # a fifth ground point maps through it
    np.testing.assert_allclose(
        apply_homography(ours, m.undistort_points(m.project(other))), l.undistort_points(l.project(other)), atol=1e-6
    )


def test_two_people_far_apart_in_every_view_are_never_merged():
    rig = ring_rig(4)
    people = {0: person(np.array([2.5, -2.0]), 0.4, 0.3), 1: person(np.array([-2.0, 2.5]), 2.0, 0.2)}
    everywhere = scene(rig, people)
    assert matched_id_sets(FeetMatcher()(everywhere, rig).assignment, everywhere) == {
        frozenset((v, i) for v in range(4)) for i in (0, 1)
    }
    apart = scene(rig, people, visible={0: [0, 1], 1: [2, 3]})  # the only cross pairs are 0 with 1
    assert matched_id_sets(FeetMatcher()(apart, rig).assignment, apart) == {
        frozenset({(0, 0), (1, 0)}),
        frozenset({(2, 1), (3, 1)}),
    }
    assert len(FeetMatcher(gate=np.inf)(apart, rig).assignment) == 1  # what the gate prevents


def test_person_with_hidden_feet_in_one_view_is_matched_through_the_other_views():
    rig = ring_rig(4)
    views = scene(rig, crowd(4, seed=1), rng=np.random.default_rng(7))
    hidden = int(np.flatnonzero(views[2].person_ids == 0)[0])
    views[2].keypoints[hidden, [LEFT_ANKLE, RIGHT_ANKLE, *LEFT_FOOT, *RIGHT_FOOT], 2] = 0.0
    matcher = FeetMatcher()
    assignment, reasons = matcher(views, rig)
    found = matched_id_sets(assignment, views)
    assert frozenset((v, 0) for v in (0, 1, 3)) in found
    assert found == {frozenset((v, 0) for v in (0, 1, 3))} | {frozenset((v, i) for v in range(4)) for i in (1, 2, 3)}
    assert reasons == {NO_FOOT_JOINTS: 1}


def test_the_features_of_all_views_at_once_are_those_of_each_view():
    # FeetMatcher.features computes every view in one pass (views_feet_features): the same, bit for bit
    from data.synthetic import SyntheticConfig, generate_sequence

    seq = generate_sequence(SyntheticConfig(seed=3, num_frames=1, num_persons=12, num_cameras=4, noise_px=2.0))
    views = list(seq.frames[0].views)
    views[2] = ViewDetections(views[2].keypoints[:0], views[2].bboxes[:0], views[2].scores[:0], views[2].person_ids[:0])
    m = FeetMatcher(pixel_sigma=4.0, sigma_score_power=0.5)
    for got, v, cam in zip(m.features(views, seq.rig), views, seq.rig):
        ref = feet_features(
            v.keypoints, cam, m.foot_rule, min_score=m.min_score, pixel_sigma=4.0, ankle_height_m=m.ankle_height_m,
            sigma_score_power=0.5,
        )  # fmt: skip
        for name in ("left", "right", "p", "v", "cov", "has_p", "has_stride", "reason"):
            np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
