"""Uncertainty-aware feet matching: propagated ground covariances, the Mahalanobis cost, plane heights."""

import numpy as np
import pytest

from data.keypoints import LEFT_ANKLE, NUM_JOINTS, RIGHT_ANKLE
from reconstruction.matching import FeetMatcher
from reconstruction.matching.feet import edge_costs, features_from_feet, feet_features
from reconstruction.matching.feet_uncertainty import (
    image_to_plane_homography,
    joints_on_planes,
    mahalanobis_distances,
    plane_to_image_homography,
    views_joints_on_planes,
)
from tests.test_feet_matching import crowd, matched_id_sets, ring_rig, scene

DIST = (-0.25, 0.05, 0.001, -0.001, 0.0)


def one_joint_cov(cam, xy, sigma=3.0, height=0.0):
    """Ground point and propagated covariance of one joint seen at the projection of (x, y, height)."""
    uv = cam.project(np.array([xy[0], xy[1], height]))[None, None]
    ground, _, cov = joints_on_planes(cam, uv, np.array([height]), sigma)
    return uv[0, 0], ground[0, 0], cov[0, 0]


@pytest.mark.parametrize("dist", [(0, 0, 0, 0, 0), DIST])
def test_ground_covariance_matches_monte_carlo(dist):
    cam = ring_rig(4, dist=dist)[1]
    uv, ground, cov = one_joint_cov(cam, (1.5, -2.0), sigma=3.0)
    rng = np.random.default_rng(0)
    noisy = cam.image_to_ground(uv + 3.0 * rng.normal(size=(2000, 2)))
    mc = np.cov(noisy.T)
    np.testing.assert_allclose(ground, cam.image_to_ground(uv), atol=1e-9)
    assert np.linalg.norm(cov - mc) / np.linalg.norm(mc) < 0.1
    np.testing.assert_allclose(np.linalg.eigvalsh(cov), np.linalg.eigvalsh(mc), rtol=0.1)


def test_all_views_at_once_equal_view_by_view_and_land_on_the_truth():
    # 4 cameras (two with distortion), one with no detections, planes at three heights: the stacked call equals
    # one call per camera, and the points land on the truth
    plain, distorted = ring_rig(4), ring_rig(4, dist=DIST)
    cams, counts = [plain[0], distorted[1], plain[2], distorted[3]], [5, 0, 7, 3]
    heights = np.array([0.0, 0.07, 1.0])
    rng = np.random.default_rng(3)
    xy = rng.uniform(-2, 2, (sum(counts), 3, 2))
    X = np.concatenate([xy, np.broadcast_to(heights[None, :, None], xy.shape[:2] + (1,))], axis=-1)
    view = np.repeat(np.arange(4), counts)
    uv = np.stack([cams[v].project(X[n]) for n, v in enumerate(view)])
    sigma = rng.uniform(1, 5, uv.shape[:2])
    ground, depth, cov = views_joints_on_planes(cams, counts, uv, heights, sigma)
    ends = np.cumsum(counts)
    for v, cam in enumerate(cams):
        rows = slice(ends[v] - counts[v], ends[v])
        one = joints_on_planes(cam, uv[rows], heights, sigma[rows])
        for got, want in zip((ground[rows], depth[rows], cov[rows]), one):
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ground, xy, atol=1e-6)
    assert np.all(depth > 0)


def test_ground_covariance_grows_with_distance():
    cam = ring_rig(4)[0]  # at (8, 0, 3) looking at the origin
    sizes = [np.sqrt(np.linalg.det(one_joint_cov(cam, (x, 0.0))[2])) for x in (6.0, 3.0, 0.0, -3.0)]
    assert all(a < b for a, b in zip(sizes, sizes[1:]))
    far, near = sizes[-1], sizes[0]
    assert far / near > (11.0 / 2.0) ** 2  # roughly d^2 / (H f): along the ray it grows faster


def test_mahalanobis_is_symmetric_and_euclidean_over_sigma_for_equal_isotropic_covariances():
    rng = np.random.default_rng(1)
    pa, pb = rng.normal(size=(4, 2)), rng.normal(size=(3, 2))
    ca = np.stack([np.diag(rng.uniform(0.01, 0.2, 2)) for _ in range(4)])
    cb = np.stack([np.diag(rng.uniform(0.01, 0.2, 2)) for _ in range(3)])
    ab = mahalanobis_distances(pa, pb, ca, cb, 0.05)
    np.testing.assert_allclose(ab, mahalanobis_distances(pb, pa, cb, ca, 0.05).T, rtol=1e-12)
    s2, floor = 0.03, 0.05
    eye_a, eye_b = np.broadcast_to(s2 * np.eye(2), (4, 2, 2)), np.broadcast_to(s2 * np.eye(2), (3, 2, 2))
    sigma = np.sqrt(2 * s2 + floor**2)
    euclid = np.linalg.norm(pa[:, None] - pb[None], axis=-1)
    np.testing.assert_allclose(mahalanobis_distances(pa, pb, eye_a, eye_b, floor), euclid / sigma, rtol=1e-12)
    fa = features_from_feet(pa, pa + [0.3, 0], np.ones(4, bool), np.ones(4, bool), None, eye_a * 2, eye_a * 2)
    fb = features_from_feet(pb, pb + [0.3, 0], np.ones(3, bool), np.ones(3, bool), None, eye_b * 2, eye_b * 2)
    np.testing.assert_allclose(fa.cov, eye_a)  # p = mean of two feet: covariance halves
    cost = edge_costs(fa, fb, 1.0, 0.0, 0.0, metric="mahalanobis", floor_m=floor)
    np.testing.assert_allclose(cost, euclid / sigma, rtol=1e-12)
    with pytest.raises(ValueError, match="covariance"):
        edge_costs(features_from_feet(pa, pa, np.ones(4, bool), np.ones(4, bool)), fb, metric="mahalanobis")


@pytest.mark.parametrize("dist", [(0, 0, 0, 0, 0), DIST])
def test_noise_free_ankle_only_detection_lands_on_the_truth(dist):
    cam = ring_rig(4, dist=dist)[2]
    truth = np.array([[0.4, -0.7], [0.7, -0.5]])  # left, right ankle (x, y) at 0.07 m
    kp = np.zeros((1, NUM_JOINTS, 3))
    kp[0, [LEFT_ANKLE, RIGHT_ANKLE], :2] = cam.project(np.column_stack([truth, np.full(2, 0.07)]))
    kp[0, [LEFT_ANKLE, RIGHT_ANKLE], 2] = 0.9
    f = feet_features(kp, cam, ankle_height_m=0.07)
    np.testing.assert_allclose(np.stack([f.left[0], f.right[0]]), truth, atol=1e-6)
    flat = feet_features(kp, cam, ankle_height_m=0.0)  # the paper's z = 0: pushed away from the camera
    d_cam = np.linalg.norm(cam.center[:2] - truth[0])
    assert np.linalg.norm(cam.center[:2] - flat.left[0]) > d_cam + 0.05
    pixel = plane_to_image_homography(cam, 0.07) @ np.append(truth[0], 1.0)  # K [r1 r2 h r3 + t]
    world = cam.P @ np.array([*truth[0], 0.07, 1.0])
    np.testing.assert_allclose(pixel[:2] / pixel[2], world[:2] / world[2], atol=1e-9)
    back = image_to_plane_homography(cam, 0.07) @ pixel
    np.testing.assert_allclose(back[:2] / back[2], truth[0], atol=1e-9)


def test_default_matcher_is_mahalanobis_and_both_metrics_match_a_clean_scene():
    rig = ring_rig(4)
    views = scene(rig, crowd())
    truth = {frozenset((v, i) for v in range(4)) for i in range(6)}
    default = FeetMatcher()
    assert default.location_metric == "mahalanobis" and default.foot_rule == "mean"
    assert matched_id_sets(default(views, rig).assignment, views) == truth
    paper = FeetMatcher(location_metric="euclidean", foot_rule="lowest", ankle_height_m=0.0)
    assert matched_id_sets(paper(views, rig).assignment, views) == truth
    with pytest.raises(ValueError):
        FeetMatcher(space="image", location_metric="mahalanobis", gate=60.0, unknown_stride_cost=10.0)


def _numpy_foot(ground, cov, y, valid, rule, ankle, ankle_fallback):
    """The numpy selection foot_points replaced, one side: (N, 3, 2), (N, 3, 2, 2), (N, 3), (N, 3), rule, the
    ankle's (ground (N, 2), cov (N, 2, 2), usable (N,)) -> point (N, 2), covariance (N, 2, 2), ok (N,)."""
    ok = valid.any(axis=1)
    if rule == "lowest":
        pick = np.argmax(np.where(valid, y, -np.inf), axis=1)
        point, point_cov = ground[np.arange(len(ground)), pick], cov[np.arange(len(ground)), pick]
    else:
        n = np.maximum(valid.sum(axis=1), 1)
        point = np.where(valid[..., None], ground, 0.0).sum(axis=1) / n[:, None]
        point_cov = np.where(valid[..., None, None], cov, 0.0).sum(axis=1) / (n**2)[:, None, None]
    if ankle_fallback:
        use = ~ok & ankle[2]
        point = np.where(use[:, None], ankle[0], point)
        point_cov = np.where(use[:, None, None], ankle[1], point_cov)
        ok = ok | use
    return point, point_cov, ok


@pytest.mark.parametrize("rule", ["mean", "lowest"])
@pytest.mark.parametrize("ankle_fallback", [True, False])
def test_foot_points_equal_the_numpy_selection(rule, ankle_fallback):
    from reconstruction.matching.feet_kernels import foot_points

    rng = np.random.default_rng(1)
    N = 300
    ground, cov, y = rng.normal(size=(N, 8, 2)), rng.normal(size=(N, 8, 2, 2)), rng.uniform(0, 9, (N, 8)).round()
    ground[rng.random((N, 8)) < 0.1, 1] = np.nan  # no point on the plane
    depth, scored = rng.normal(1.0, 1.0, (N, 8)), rng.random((N, 8)) < 0.5  # behind the camera, low scores
    point, point_cov, ok = np.empty((2, N, 2)), np.empty((2, N, 2, 2)), np.empty((2, N), bool)
    foot_points(ground, cov, depth, y, scored, rule == "lowest", ankle_fallback, point, point_cov, ok)
    ground_ok = np.isfinite(ground).all(axis=-1)  # the numpy version's preparation
    usable = scored & ground_ok & (depth > 0)
    ground, cov = np.where(ground_ok[..., None], ground, 0.0), np.where(ground_ok[..., None, None], cov, 0.0)
    for s in (0, 1):
        side, a = slice(3 * s, 3 * s + 3), 6 + s
        ankle = (ground[:, a], cov[:, a], usable[:, a])
        want = _numpy_foot(ground[:, side], cov[:, side], y[:, side], usable[:, side], rule, ankle, ankle_fallback)
        np.testing.assert_array_equal(ok[s], want[2])
        np.testing.assert_array_equal(point[s][ok[s]], want[0][ok[s]])  # a foot not ok is zeroed downstream
        np.testing.assert_array_equal(point_cov[s][ok[s]], want[1][ok[s]])
    assert ok.any() and not ok.all()
