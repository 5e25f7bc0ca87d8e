import itertools

import numpy as np
import pytest

from data.geometry.camera import Camera, Rig
from data.keypoints import NUM_JOINTS
from data.multiview import ViewDetections
from evaluation.correspondence import correspondence_counts
from reconstruction.matching import FeetMatcher
from reconstruction.matching.feet import (
    FEET_ABOVE_HORIZON,
    NO_COUNTERPART,
    NO_FOOT_JOINTS,
    edge_costs,
    features_from_feet,
    feet_features,
    pair_homography,
    to_image,
)
from reconstruction.matching.merge import merge_edges, solve_pair


def ring_rig(n: int, radius: float = 8.0, height: float = 3.0, dist=(0, 0, 0, 0, 0)) -> Rig:
    """n cameras on a circle around the origin, looking at it; f = 1000, 1280x720."""
    K = np.array([[1000.0, 0, 640], [0, 1000, 360], [0, 0, 1]])
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        c = np.array([radius * np.cos(a), radius * np.sin(a), height])
        z = -c / np.linalg.norm(c)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        cams.append(Camera(f"c{i}", K, np.array(dist, float), R, -R @ c, (1280, 720)))
    return Rig.from_cameras(cams)


def person(ground: np.ndarray, heading: float, stride: float) -> np.ndarray:
    """Plausible COCO-23 joints (23, 3) standing at a ground (x, y), feet a stride apart along heading."""
    fwd = np.array([np.cos(heading), np.sin(heading), 0.0])
    side = np.array([-fwd[1], fwd[0], 0.0])
    g = np.array([ground[0], ground[1], 0.0])
    X = np.tile(g + [0, 0, 1.0], (NUM_JOINTS, 1))
    X[:5, 2] = 1.6
    X[5:11, 2] = 1.35
    for foot, sign, ankle, toes in ((0, 1, 15, 17), (1, -1, 16, 20)):
        heel = g + sign * 0.1 * side - (foot - 0.5) * stride * fwd
        X[toes] = heel + 0.2 * fwd + [0, 0, 0.02]
        X[toes + 1] = heel + 0.15 * fwd + sign * 0.05 * side + [0, 0, 0.02]
        X[toes + 2] = heel + [0, 0, 0.03]
        X[ankle] = heel + [0, 0, 0.09]
    return X


def scene(
    rig: Rig,
    people: dict[int, np.ndarray],
    visible: dict[int, list[int]] | None = None,
    rng: np.random.Generator | None = None,
) -> list[ViewDetections]:
    """Project persons {id: (23, 3)} into the views where visible (default all), optionally shuffled."""
    views = []
    for v, cam in enumerate(rig):
        ids = [i for i in people if visible is None or v in visible.get(i, range(len(rig)))]
        if rng is not None:
            ids = list(rng.permutation(ids))
        kp = np.zeros((len(ids), NUM_JOINTS, 3))
        for n, i in enumerate(ids):
            kp[n, :, :2] = cam.project(people[i])
            kp[n, :, 2] = 0.9
        views.append(ViewDetections(kp, np.ones((len(ids), 4)), np.ones(len(ids)), np.array(ids, np.int64)))
    return views


def crowd(n: int = 6, seed: int = 0) -> dict[int, np.ndarray]:
    """n persons on a 1.2 m grid around the origin with random headings and strides."""
    rng = np.random.default_rng(seed)
    spots = [np.array([x, y]) for x in (-1.2, 0, 1.2) for y in (-1.2, 0, 1.2)]
    return {
        i: person(spots[i] + rng.uniform(-0.2, 0.2, 2), rng.uniform(0, 2 * np.pi), rng.uniform(0.05, 0.5))
        for i in range(n)
    }


def matched_id_sets(assignment: np.ndarray, views: list[ViewDetections]) -> set[frozenset]:
    """Each predicted person as its set of (view, ground-truth id)."""
    return {frozenset((v, int(views[v].person_ids[d])) for v, d in enumerate(row) if d >= 0) for row in assignment}


@pytest.mark.parametrize("dist", [(0, 0, 0, 0, 0), (-0.1, 0.02, 0, 0, 0)])
def test_noise_free_scene_is_matched_perfectly(dist):
    rig = ring_rig(4, dist=dist)
    views = scene(rig, crowd())
    matcher = FeetMatcher()
    assignment, reasons = matcher(views, rig)
    counts = correspondence_counts(assignment, [v.person_ids for v in views])
    assert counts.precision == 1.0 and counts.recall == 1.0
    assert counts.persons == 6 and counts.recovered_share == 1.0
    assert not reasons


def test_shuffling_detections_keeps_the_matched_identities():
    rig = ring_rig(5)
    people = crowd(7, seed=3)
    ordered = scene(rig, people)
    shuffled = scene(rig, people, rng=np.random.default_rng(1))
    assert any(not np.array_equal(a.person_ids, b.person_ids) for a, b in zip(ordered, shuffled))
    matcher = FeetMatcher()
    assert matched_id_sets(matcher(ordered, rig).assignment, ordered) == matched_id_sets(
        matcher(shuffled, rig).assignment, shuffled
    )


def test_person_seen_in_one_view_stays_unmatched_and_the_gate_is_what_keeps_it():
    rig = ring_rig(4)
    people = crowd(3)
    people[10] = person(np.array([2.6, 2.4]), 0.3, 0.3)  # only in view 0
    people[11] = person(np.array([-2.6, -2.4]), 1.0, 0.3)  # only in view 1
    views = scene(rig, people, visible={10: [0], 11: [1]})
    matcher = FeetMatcher()
    a, reasons = matcher(views, rig)
    lonely = {(0, list(views[0].person_ids).index(10)), (1, list(views[1].person_ids).index(11))}
    assert not any((v, d) in lonely for row in a for v, d in enumerate(row))
    assert reasons == {NO_COUNTERPART: 2}
    ungated = FeetMatcher(gate=np.inf)(views, rig).assignment
    assert any((0, 10) in s and (1, 11) in s for s in matched_id_sets(ungated, views))


def test_merger_refuses_to_put_two_detections_of_one_view_in_a_person():
    # cheapest first: 0:0-1:0, 1:0-2:0 join; 2:0-0:1 would add a second view-0 detection.
    edges = np.array([[0, 0, 1, 0, 0.1], [1, 0, 2, 0, 0.2], [2, 0, 0, 1, 0.3], [0, 1, 1, 1, 0.4]])
    np.testing.assert_array_equal(merge_edges(edges, [2, 2, 1]), [[0, 0, 0], [1, 1, -1]])
    # two components {0:0, 1:0} and {0:1, 2:0} may not be joined through 1:0-2:0.
    edges = np.array([[0, 0, 1, 0, 0.1], [0, 1, 2, 0, 0.2], [1, 0, 2, 0, 0.3]])
    np.testing.assert_array_equal(merge_edges(edges[::-1], [2, 1, 1]), [[0, 0, -1], [1, -1, 0]])
    np.testing.assert_array_equal(merge_edges(edges, [2, 1, 1], min_views=3), np.zeros((0, 3)))


def test_merger_on_random_conflicting_edges_keeps_each_detection_once():
    rng = np.random.default_rng(0)
    counts = [3, 4, 2, 3]
    for _ in range(20):
        edges = []
        for _ in range(30):
            va, vb = rng.choice(4, 2, replace=False)
            edges.append([va, rng.integers(counts[va]), vb, rng.integers(counts[vb]), rng.random()])
        a = merge_edges(np.array(edges), counts)
        for v in range(4):
            used = a[:, v][a[:, v] >= 0]
            assert len(np.unique(used)) == len(used)
        assert np.all(np.sum(a >= 0, axis=1) >= 2)
        np.testing.assert_array_equal(a, merge_edges(np.array(edges)[rng.permutation(30)], counts))


def feats(left, right, has_left=True, has_right=True):
    """FeetFeatures of one detection from two feet (2,)."""
    return features_from_feet(
        np.array([left], float), np.array([right], float), np.array([has_left]), np.array([has_right])
    )


def test_edge_cost_known_answers_for_each_term():
    a = feats([0, 0], [0.4, 0])  # p (0.2, 0), v (0.4, 0)
    moved = feats([0.3, 0.4], [0.7, 0.4])  # p moved by (0.3, 0.4): 0.5 m, same stride
    assert edge_costs(a, moved, 2.0, 1.0, 1.0)[0, 0] == pytest.approx(1.0)
    longer = feats([-0.1, 0], [0.5, 0])  # same p, parallel stride 0.6 m
    assert edge_costs(a, longer, 1.0, 3.0, 7.0)[0, 0] == pytest.approx(3.0 * 0.2)
    perpendicular = feats([0.2, -0.2], [0.2, 0.2])
    assert edge_costs(a, perpendicular, 1.0, 1.0, 0.7)[0, 0] == pytest.approx(0.7)
    diagonal = feats([0, -0.2], [0.4, 0.2])  # 45 degrees, p (0.2, 0), |v| = 0.4 sqrt 2
    assert edge_costs(a, diagonal, 1.0, 0.0, 1.0)[0, 0] == pytest.approx(np.sqrt(0.5))
    flipped = feats([0.4, 0], [0, 0])  # antiparallel: no direction cost
    assert edge_costs(a, flipped, 1.0, 1.0, 5.0)[0, 0] == pytest.approx(0.0)


def test_edge_cost_with_one_foot_or_none():
    a = feats([0, 0], [0.4, 0])
    one = feats([0.2, 0.3], [0, 0], has_right=False)  # p = left foot, stride unknown
    assert edge_costs(a, one, 1.0, 9.0, 9.0, unknown_stride_cost=0.05)[0, 0] == pytest.approx(0.35)
    none = feats([0, 0], [0, 0], False, False)
    assert none.reason[0] == NO_FOOT_JOINTS
    assert np.isinf(edge_costs(a, none)[0, 0]) and np.isinf(edge_costs(none, a)[0, 0])


def single_detection(cam: Camera, pixels: dict[int, tuple[float, float]]) -> np.ndarray:
    """Keypoints (1, 23, 3) with only the given joints scored."""
    kp = np.zeros((1, NUM_JOINTS, 3))
    for j, (u, y) in pixels.items():
        kp[0, j] = (u, y, 0.9)
    return kp


def test_feet_features_lowest_rule_mean_rule_and_ankle_fallback():
    cam = ring_rig(4, height=1.0)[0]  # the horizon is at y = 237
    px = {17: (600, 520), 18: (610, 530), 19: (590, 500), 22: (700, 510), 15: (600, 490), 16: (700, 480)}
    kp = single_detection(cam, px)
    f = feet_features(kp, cam, "lowest")
    np.testing.assert_allclose(f.left[0], cam.image_to_ground(np.array(px[18])))
    np.testing.assert_allclose(f.right[0], cam.image_to_ground(np.array(px[22])))
    assert f.has_stride[0] and f.reason[0] == ""
    np.testing.assert_allclose(f.p[0], (f.left[0] + f.right[0]) / 2)
    mean = feet_features(kp, cam, "mean")
    np.testing.assert_allclose(mean.left[0], cam.image_to_ground(np.array([px[j] for j in (17, 18, 19)])).mean(0))
    ankles = single_detection(cam, {15: px[15], 16: px[16]})
    fb = feet_features(ankles, cam, ankle_height_m=0.0)  # ankles projected onto z = 0, as the paper does
    np.testing.assert_allclose(fb.left[0], cam.image_to_ground(np.array(px[15])))
    assert fb.has_stride[0]
    no_fallback = feet_features(ankles, cam, ankle_fallback=False)
    assert not no_fallback.has_p[0] and no_fallback.reason[0] == NO_FOOT_JOINTS
    one_foot = feet_features(single_detection(cam, {19: px[19]}), cam)
    assert one_foot.has_p[0] and not one_foot.has_stride[0]
    np.testing.assert_allclose(one_foot.p[0], cam.image_to_ground(np.array(px[19])))
    low_score = kp.copy()
    low_score[0, :, 2] = 0.1
    assert feet_features(low_score, cam, min_score=0.2).reason[0] == NO_FOOT_JOINTS
    sky = single_detection(cam, {17: (640, 100), 20: (650, 100)})  # above the horizon
    assert feet_features(sky, cam).reason[0] == FEET_ABOVE_HORIZON
    assert len(feet_features(np.zeros((0, NUM_JOINTS, 3)), cam)) == 0


def test_matcher_reports_detections_without_feet():
    rig = ring_rig(3)
    views = scene(rig, crowd(3))
    views[1].keypoints[0, 15:, 2] = 0.0  # no ankle, no foot joint
    matcher = FeetMatcher()
    assert matcher(views, rig).unmatched == {NO_FOOT_JOINTS: 1}


def test_image_space_matches_like_ground_space_and_uses_the_pair_homography():
    rig = ring_rig(4)
    views = scene(rig, crowd(6, seed=5))
    ground = FeetMatcher()(views, rig).assignment
    image = FeetMatcher(space="image", k3=25.0, gate=60.0, unknown_stride_cost=10.0)(views, rig).assignment
    assert matched_id_sets(ground, views) == matched_id_sets(image, views)
    f1 = feet_features(views[1].keypoints, rig[1], "lowest")  # one foot pixel per foot, to map by H
    in0 = to_image(f1, rig[0])
    H = pair_homography(rig[0], rig[1])
    lowest_right = 20 + np.argmax(views[1].keypoints[0, 20:23, 1])
    mapped = np.append(views[1].keypoints[0, lowest_right, :2], 1.0) @ H.T
    np.testing.assert_allclose(in0.right[0], mapped[:2] / mapped[2], atol=1e-6)
    with pytest.raises(ValueError, match="pixels"):
        FeetMatcher(space="image")


def brute_force(cost: np.ndarray, gate: float) -> tuple[int, float]:
    """(number of allowed pairs, their total cost) of the best gated matching, by enumeration."""
    allowed = np.isfinite(cost) & (cost <= gate)
    best = (0, 0.0)
    for cols in itertools.permutations(range(cost.shape[1]), cost.shape[0]):
        pairs = [(r, c) for r, c in enumerate(cols) if allowed[r, c]]
        cand = (len(pairs), sum(cost[r, c] for r, c in pairs))
        if cand[0] > best[0] or (cand[0] == best[0] and cand[1] < best[1]):
            best = cand
    return best


def test_gated_pairwise_solve_equals_brute_force():
    rng = np.random.default_rng(0)
    for trial in range(40):
        shape = (4, 5) if trial % 2 else (3, 4)
        cost = rng.uniform(0, 1, shape)
        cost[rng.random(shape) < 0.15] = np.inf
        gate = rng.uniform(0.3, 1.0)
        rows, cols = solve_pair(cost, gate)
        assert np.all(cost[rows, cols] <= gate)
        assert len(set(rows)) == len(rows) and len(set(cols)) == len(cols)
        n, total = brute_force(cost, gate)
        assert len(rows) == n and cost[rows, cols].sum() == pytest.approx(total)
        r_t, c_t = solve_pair(cost.T, gate)
        assert len(r_t) == n and cost.T[r_t, c_t].sum() == pytest.approx(total)
    rows, cols = solve_pair(np.full((2, 3), np.inf))
    assert len(rows) == len(cols) == 0


def test_correspondence_counts_known_answer():
    ids = [np.array([1, 2, -1]), np.array([2, 1]), np.array([1, 3])]
    full = correspondence_counts(np.array([[0, 1, 0], [1, 0, -1], [2, -1, 1]]), ids)
    assert (full.predicted_pairs, full.correct_pairs, full.true_pairs) == (5, 4, 4)
    assert full.precision == 0.8 and full.recall == 1.0 and full.persons_recovered == 2
    partial = correspondence_counts(np.array([[0, 1, -1], [1, 0, -1], [2, -1, 1]]), ids)
    assert (partial.predicted_pairs, partial.correct_pairs, partial.persons) == (3, 2, 2)
    assert partial.recall == 0.5 and partial.recovered_share == 0.5
    assert (full + partial).true_pairs == 8
    with pytest.raises(ValueError, match="two persons"):
        correspondence_counts(np.array([[0, 1, -1], [0, 0, -1]]), ids)
    twice = correspondence_counts(np.array([[0, 0]]), [np.array([5, 5]), np.array([5])])
    assert twice.true_pairs == 2 and twice.persons == 1 and twice.persons_recovered == 0  # 5 twice in view 0


def test_feet_features_undistort_to_the_exact_ground_point():
    cam = ring_rig(4, dist=(-0.25, 0.05, 0.001, -0.001, 0))[1]
    ground = np.array([[1.5, -1.0], [1.8, -0.8]])  # left, right foot on z = 0
    kp = np.zeros((1, NUM_JOINTS, 3))
    kp[0, [19, 22], :2] = cam.project(np.column_stack([ground, np.zeros(2)]))
    kp[0, [19, 22], 2] = 1.0
    f = feet_features(kp, cam, "mean")
    np.testing.assert_allclose(np.stack([f.left[0], f.right[0]]), ground, atol=1e-6)
    np.testing.assert_allclose(f.v[0], ground[1] - ground[0], atol=1e-6)
