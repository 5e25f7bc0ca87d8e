"""The joint-based matchers (the epipolar and RANSAC baselines of the paper's Table 6, and feet + epipolar) on hand-built scenes."""

import inspect
from pathlib import Path

import cv2
import numpy as np
import pytest
from hydra.utils import instantiate
from omegaconf import OmegaConf

from data.keypoints import FLIP_PAIRS, NUM_JOINTS
from evaluation.correspondence import correspondence_counts
from reconstruction.matching import EpipolarMatcher, FeetEpipolarMatcher, RansacMatcher
from reconstruction.matching.epipolar import (
    NO_COUNTERPART,
    TOO_FEW_JOINTS,
    epipolar_affinity,
    fundamental_matrix,
    undistorted_joints,
)
from reconstruction.matching.feet import NO_FOOT_JOINTS
from tests.test_feet_matching import matched_id_sets, ring_rig, scene

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "matching"
DIST = (-0.1, 0.02, 0.001, -0.001, 0.0)
MATCHERS = {"epipolar": EpipolarMatcher, "ransac": RansacMatcher, "feet_epipolar": FeetEpipolarMatcher}

# A standing person facing +x, in metres: (forward, left, up) of the left-side and central joints;
# the right side mirrors the left (FLIP_PAIRS).
_LEFT_AND_CENTRE = {
    0: (0.10, 0.0, 1.62),
    1: (0.08, 0.03, 1.66),
    3: (0.0, 0.08, 1.63),
    5: (0.0, 0.19, 1.42),
    7: (0.02, 0.24, 1.13),
    9: (0.08, 0.25, 0.86),
    11: (0.0, 0.10, 0.95),
    13: (0.02, 0.11, 0.52),
    15: (0.0, 0.11, 0.09),
    17: (0.17, 0.12, 0.02),
    18: (0.15, 0.17, 0.02),
    19: (-0.05, 0.11, 0.02),
}


def template() -> np.ndarray:
    """The standing COCO-23 template (23, 3)."""
    X = np.zeros((NUM_JOINTS, 3))
    for j, xyz in _LEFT_AND_CENTRE.items():
        X[j] = xyz
    for left, right in FLIP_PAIRS:
        X[right] = X[left] * [1, -1, 1]
    return X


def skeleton(ground, heading: float, scale: float = 1.0) -> np.ndarray:
    """The template scaled, turned to a heading and standing at a ground (x, y): (23, 3) metres."""
    c, s = np.cos(heading), np.sin(heading)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return scale * template() @ R.T + [ground[0], ground[1], 0.0]


def crowd(n: int = 7, seed: int = 0) -> dict[int, np.ndarray]:
    """n skeletons on a 1.2 m grid around the origin, random jitter, heading and size."""
    rng = np.random.default_rng(seed)
    spots = [np.array([x, y]) for x in (-1.2, 0, 1.2) for y in (-1.2, 0, 1.2)]
    return {
        i: skeleton(spots[i] + rng.uniform(-0.2, 0.2, 2), rng.uniform(0, 2 * np.pi), rng.uniform(0.9, 1.1))
        for i in range(n)
    }


def ids_of(views) -> list[np.ndarray]:
    """Ground-truth ids per view."""
    return [v.person_ids for v in views]


@pytest.mark.parametrize("name", MATCHERS)
@pytest.mark.parametrize("dist", [(0, 0, 0, 0, 0), DIST])
def test_noise_free_scene_is_matched_perfectly(name, dist):
    rig = ring_rig(5, dist=dist)
    views = scene(rig, crowd())
    matcher = MATCHERS[name]()
    assignment, reasons = matcher(views, rig)
    m = correspondence_counts(assignment, ids_of(views)).as_dict()
    assert m["precision"] == 1.0 and m["recall"] == 1.0
    assert m["persons"] == 7 and m["recovered_share"] == 1.0
    assert not reasons


@pytest.mark.parametrize("name", MATCHERS)
def test_shuffling_detections_keeps_the_matched_identities(name):
    rig = ring_rig(4)
    people = crowd(8, seed=3)
    ordered = scene(rig, people)
    shuffled = scene(rig, people, rng=np.random.default_rng(1))
    assert any(not np.array_equal(a.person_ids, b.person_ids) for a, b in zip(ordered, shuffled))
    matcher = MATCHERS[name]()
    found = matched_id_sets(matcher(ordered, rig).assignment, ordered)
    assert found == matched_id_sets(matcher(shuffled, rig).assignment, shuffled)
    assert len(found) == 8


@pytest.mark.parametrize("name", MATCHERS)
def test_person_seen_in_one_view_stays_unmatched_and_is_counted(name):
    rig = ring_rig(4)
    people = crowd(3)
    people[10] = skeleton((2.2, 2.0), 0.3)  # only in view 0
    people[11] = skeleton((-2.0, -2.4), 1.0)  # only in view 1
    views = scene(rig, people, visible={10: [0], 11: [1]})
    matcher = MATCHERS[name]()
    a, reasons = matcher(views, rig)
    assert matched_id_sets(a, views) == {frozenset((v, i) for v in range(4)) for i in range(3)}
    assert reasons == {NO_COUNTERPART: 2}
    ungated = MATCHERS[name](gate=np.inf)(views, rig).assignment  # the gate is what keeps them apart
    assert frozenset({(0, 10), (1, 11)}) in matched_id_sets(ungated, views)


@pytest.mark.parametrize("name", MATCHERS)
def test_two_people_far_apart_are_never_merged(name):
    rig = ring_rig(5)
    people = {0: skeleton((2.0, 1.5), 0.5), 1: skeleton((-1.5, -2.0), 2.0)}
    views = scene(rig, people, visible={0: [0, 1], 1: [2, 3]})  # only person-0/person-1 pairs across
    a = MATCHERS[name]()(views, rig).assignment
    assert matched_id_sets(a, views) == {frozenset({(0, 0), (1, 0)}), frozenset({(2, 1), (3, 1)})}
    merged = MATCHERS[name](gate=np.inf)(views, rig).assignment
    assert len(merged) == 1 and np.sum(merged >= 0) == 4


@pytest.mark.parametrize("name", MATCHERS)
def test_detection_with_too_few_joints_is_left_out_and_counted(name):
    rig = ring_rig(4)
    views = scene(rig, crowd(4))
    views[2].keypoints[1, 2:, 2] = 0.0  # two joints left
    views[3].keypoints[0, :, 2] = 0.15  # all below min_score
    matcher = MATCHERS[name]()
    a, reasons = matcher(views, rig)
    found = matched_id_sets(a, views)
    hidden = {(2, int(views[2].person_ids[1])), (3, int(views[3].person_ids[0]))}
    assert not any(hidden & s for s in found)
    assert frozenset((v, 1) for v in (0, 1, 3)) in found and frozenset((v, 0) for v in (0, 1, 2)) in found
    # feet_epipolar needs feet first by default: neither detection has a usable foot left
    assert reasons == ({NO_FOOT_JOINTS: 2} if name == "feet_epipolar" else {TOO_FEW_JOINTS: 2})


@pytest.mark.parametrize("name", MATCHERS)
def test_views_must_match_the_rig(name):
    rig = ring_rig(3)
    with pytest.raises(ValueError, match="rig"):
        MATCHERS[name]()(scene(ring_rig(2), crowd(2)), rig)


@pytest.mark.parametrize("name", MATCHERS)
def test_config_instantiates_with_every_constructor_argument(name):
    cfg = OmegaConf.load(CONFIGS / f"{name}.yaml")
    matcher = instantiate(cfg)
    assert type(matcher) is MATCHERS[name]
    params = set(inspect.signature(MATCHERS[name]).parameters)
    assert set(cfg) - {"_target_"} == params


def random_points(n: int, seed: int = 0) -> np.ndarray:
    """World points (n, 3) in the middle of the ring, up to 2 m high."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-3, 3, (n, 2)), rng.uniform(0, 2, n)])


def test_fundamental_matrix_satisfies_the_epipolar_constraint():
    rig = ring_rig(5, dist=DIST)
    X = random_points(40)
    for a, b in ((0, 1), (0, 2), (3, 1)):
        F = fundamental_matrix(rig[a], rig[b])
        xa = rig[a].undistort_points(rig[a].project(X))
        xb = rig[b].undistort_points(rig[b].project(X))
        line = np.column_stack([xa, np.ones(40)]) @ F.T  # epipolar lines in view b
        residual = np.sum(line[:, :2] * xb, axis=1) + line[:, 2]
        assert np.max(np.abs(residual) / np.hypot(line[:, 0], line[:, 1])) < 1e-6  # pixels
        assert abs(np.linalg.det(F)) < 1e-12 and np.linalg.norm(F) == pytest.approx(1.0)


def test_fundamental_matrix_equals_the_one_cv2_estimates():
    rig = ring_rig(4)
    X = random_points(60, seed=1)
    for a, b in ((0, 1), (1, 3)):
        xa, xb = rig[a].project(X), rig[b].project(X)
        estimated, _ = cv2.findFundamentalMat(xa, xb, cv2.FM_8POINT)
        ours = fundamental_matrix(rig[a], rig[b])
        estimated = estimated / np.linalg.norm(estimated) * np.sign(np.sum(estimated * ours))
        np.testing.assert_allclose(estimated, ours, atol=1e-6)


def test_epipolar_affinity_equals_the_mean_of_cv2_epipolar_distances():
    rig = ring_rig(4, dist=DIST)
    views = scene(rig, crowd(3, seed=2))
    rng = np.random.default_rng(0)
    for v in (0, 2):
        views[v].keypoints[..., :2] += rng.normal(0, 4, views[v].keypoints[..., :2].shape)
    views[0].keypoints[1, :10, 2] = 0.0
    (uv_a, ok_a), (uv_b, ok_b) = (undistorted_joints(views[v], rig[v], 0.2) for v in (0, 2))
    F = fundamental_matrix(rig[0], rig[2])
    ours = epipolar_affinity(uv_a, ok_a, uv_b, ok_b, F)
    for i in range(3):
        for j in range(3):
            common = ok_a[i] & ok_b[j]
            pa, pb = uv_a[i, common], uv_b[j, common]
            lb = cv2.computeCorrespondEpilines(pa.reshape(-1, 1, 2), 1, F).reshape(-1, 3)
            la = cv2.computeCorrespondEpilines(pb.reshape(-1, 1, 2), 2, F).reshape(-1, 3)
            d = (np.abs(np.sum(lb[:, :2] * pb, 1) + lb[:, 2]) + np.abs(np.sum(la[:, :2] * pa, 1) + la[:, 2])) / 2
            assert ours[i, j] == pytest.approx(d.mean(), rel=1e-6)
    assert np.isinf(epipolar_affinity(uv_a, ok_a, uv_b, ok_b, F, min_common_joints=14)[1]).all()


def test_min_score_is_inclusive():
    rig = ring_rig(2)
    views = scene(rig, crowd(1))
    views[0].keypoints[0, :, 2] = 0.2
    assert undistorted_joints(views[0], rig[0], 0.2)[1].all()
    assert not undistorted_joints(views[0], rig[0], 0.2001)[1].any()


def pair_cost(matcher: RansacMatcher, views, rig, a: int = 0, b: int = 1) -> np.ndarray:
    """The RANSAC cost matrix of one view pair: (Na, Nb)."""
    ja, jb = (undistorted_joints(views[v], rig[v], matcher.min_score) for v in (a, b))
    return matcher.pair_cost(*ja, *jb, rig[a], rig[b], matcher.sample_keys(NUM_JOINTS))


def pole(ground) -> np.ndarray:
    """A 'person' whose 23 joints lie on one vertical line: (23, 3); the RANSAC body model is exact for it."""
    return np.column_stack([np.tile(ground, (NUM_JOINTS, 1)), np.linspace(0.05, 1.7, NUM_JOINTS)])


def test_ransac_cost_is_zero_where_its_model_holds_and_the_outlier_share_with_outliers():
    rig = ring_rig(4, dist=DIST)
    views = scene(rig, {0: pole((0.5, -0.3)), 1: pole((-1.0, 0.8))})
    matcher = RansacMatcher()
    clean = pair_cost(matcher, views, rig)
    assert np.diag(clean) == pytest.approx(0.0, abs=1e-4) and np.all(clean[[0, 1], [1, 0]] > 0.2)
    corrupt = np.array([1, 4, 9, 15, 20])  # 5 of 23 joints moved in view 1
    F = fundamental_matrix(rig[0], rig[1])
    costs, affinities = [], []
    for shift in (200.0, 800.0):
        moved = scene(rig, {0: pole((0.5, -0.3)), 1: pole((-1.0, 0.8))})
        moved[1].keypoints[0, corrupt, 0] += shift
        costs.append(pair_cost(matcher, moved, rig)[0, 0])
        ja, jb = (undistorted_joints(moved[v], rig[v], 0.2) for v in (0, 1))
        affinities.append(epipolar_affinity(*ja, *jb, F)[0, 0])
    assert costs == pytest.approx([5 / 23, 5 / 23], abs=1e-4)  # MSAC: outliers cost 1, exact inliers 0
    assert affinities[1] > 3 * affinities[0] > 0  # the epipolar mean follows the outliers


def test_ransac_is_deterministic_for_a_seed_and_independent_of_detection_order():
    rig = ring_rig(4)
    people = crowd(6, seed=4)
    views = scene(rig, people)
    first = pair_cost(RansacMatcher(seed=3), views, rig)
    np.testing.assert_array_equal(first, pair_cost(RansacMatcher(seed=3), views, rig))
    matcher = RansacMatcher(seed=3)
    matcher(scene(rig, crowd(4, seed=9)), rig)  # an earlier frame changes nothing
    np.testing.assert_array_equal(first, pair_cost(matcher, views, rig))
    shuffled = scene(rig, people, rng=np.random.default_rng(2))
    order = [np.argsort(v.person_ids) for v in shuffled]  # shuffled detections -> ordered ids
    np.testing.assert_allclose(pair_cost(matcher, shuffled, rig)[np.ix_(order[0], order[1])], first, rtol=1e-9)
    assert not np.array_equal(first, pair_cost(RansacMatcher(seed=4, iterations=3), views, rig))


def test_ransac_rejects_inconsistent_settings():
    with pytest.raises(ValueError, match="sample_size"):
        RansacMatcher(sample_size=4, min_common_joints=3)
    with pytest.raises(ValueError):
        RansacMatcher(inlier_px=0)
