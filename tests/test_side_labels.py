"""Left / right labels made consistent across views and with the body (reconstruction/solver/side_labels.py):
random per-view labels of a synthetic body restored to the
majority's (also at the cameras' height, where view pairs' epipolar lines cannot tell), consistent labels
left bit-identical, the central pairs turned to the way the body faces, a limb pair the wrong way round
exchanged."""

from __future__ import annotations

import numpy as np

from data.geometry.triangulation import triangulate_dlt
from data.keypoints import FLIP_PAIRS
from data.synthetic.body import mean_body, pose_joints
from reconstruction.matching.epipolar import epipolar_distances, fundamental_matrix
from reconstruction.solver.side_labels import (
    best_labellings,
    chain_sides,
    consistent_sides,
    facing_directions,
    facing_sides,
)
from tests.test_triangulation import observe, ring


def bodies(n: int = 3) -> np.ndarray:
    """(n, 23, 3) standing synthetic bodies 1.5 m apart, facing different ways."""
    return np.stack(
        [pose_joints(mean_body(), 1.5 * i - 1.5, 0.3 * i, 0.9 * i, phase=0.7 * i, walking=True) for i in range(n)]
    )


def test_random_limb_labels_per_view_are_restored_and_consistent_ones_kept():
    rig = ring(5)
    poses = observe(rig, bodies())
    poses[..., :2] = rig.undistort(poses)[..., :2]
    assert np.array_equal(consistent_sides(poses, rig.projection_matrices()), poses)  # nothing to change
    rng = np.random.default_rng(1)
    swapped = poses.copy()
    limbs = [(a, b) for a, b in FLIP_PAIRS if a >= 5]  # the face's pairs sit a few px apart: below min_gain_px
    for p in range(poses.shape[1]):
        for left, right in limbs:
            views = rng.choice(5, size=2, replace=False)  # a minority of the views, as a half-blind network gives
            for v in views:
                swapped[v, p, [left, right]] = swapped[v, p, [right, left]]
    assert not np.array_equal(swapped, poses)
    restored = consistent_sides(swapped, rig.projection_matrices())
    np.testing.assert_array_equal(restored, poses)
    assert not np.array_equal(swapped, poses)  # the input is not modified


def test_a_limb_pair_the_wrong_way_round_is_exchanged_along_the_chain():
    rig = ring(4)
    X3 = bodies(2)
    poses = observe(rig, X3)
    X = triangulate_dlt(poses, rig.projection_matrices(), 2)
    kept_poses, kept_X = chain_sides(poses, X)
    np.testing.assert_array_equal(kept_X, X)
    np.testing.assert_array_equal(kept_poses, poses)
    wrong_poses, wrong_X = poses.copy(), X.copy()
    wrong_poses[:, 1, [9, 10]] = wrong_poses[:, 1, [10, 9]]  # person 1's wrists, in every view
    wrong_X[1, [9, 10]] = wrong_X[1, [10, 9]]
    fixed_poses, fixed_X = chain_sides(wrong_poses, wrong_X)
    np.testing.assert_allclose(fixed_X, X)
    np.testing.assert_array_equal(fixed_poses, poses)


def test_a_pair_at_the_cameras_height_is_labelled_by_reprojection_not_epipolar_lines():
    rig = ring(5, radius=6.0, height=1.45)  # cameras at shoulder height: both shoulders on each epipolar line
    X3 = bodies(1)
    X3[..., 2] += 1.45 - X3[0, 5, 2]  # the shoulders at the cameras' height exactly
    proj = rig.projection_matrices()
    uv = observe(rig, X3)[..., :2]
    xl, xr = uv[:, 0, 5], uv[:, 0, 6]  # (V, 2)
    F = fundamental_matrix(rig[0], rig[1])
    swapped = epipolar_distances(np.stack([xl[:1], xr[:1]]), np.stack([xr[1:2], xl[1:2]]), F)[0]  # (2, 2, 1)
    assert swapped[0, 0, 0] + swapped[1, 1, 0] < 1.0  # the view pair alone cannot tell the labels
    wrong = np.array([False, True, False, True, False])
    xl2, xr2 = np.where(wrong[:, None], xr, xl), np.where(wrong[:, None], xl, xr)
    labels, cost, given = best_labellings(xl2[None], xr2[None], np.ones((1, 5), bool), proj)
    np.testing.assert_array_equal(labels[0], wrong)  # the minority of views exchanged back
    assert cost[0] < 1e-3 < 20.0 < given[0]
    unseen = np.ones((1, 5), bool)
    unseen[0, 1] = False
    labels, _, _ = best_labellings(xl2[None], xr2[None], unseen, proj)
    np.testing.assert_array_equal(labels[0], wrong & unseen[0])  # a view that does not see the pair: untouched


def test_the_central_pairs_are_turned_to_the_way_the_body_faces():
    rig = ring(4)
    X3 = bodies(3)  # facing headings 0, 0.9 and 1.8 rad
    poses = observe(rig, X3)
    X = triangulate_dlt(poses, rig.projection_matrices(), 2)
    headings = np.array([0.0, 0.9, 1.8])
    left = facing_directions(X)
    expected = np.stack([-np.sin(headings), np.cos(headings), np.zeros(3)], axis=1)  # up x forward
    assert np.all((left * expected).sum(1) > 0.9)
    kept_poses, kept_X = facing_sides(poses, X)
    np.testing.assert_array_equal(kept_X, X)
    np.testing.assert_array_equal(kept_poses, poses)
    central = [(1, 2), (3, 4), (5, 6), (11, 12)]
    wrong_poses, wrong_X = poses.copy(), X.copy()
    for a, b in central:  # person 2's central pairs the wrong way round in every view
        wrong_poses[:, 2, [a, b]] = wrong_poses[:, 2, [b, a]]
        wrong_X[2, [a, b]] = wrong_X[2, [b, a]]
    fixed_poses, fixed_X = facing_sides(wrong_poses, wrong_X)
    np.testing.assert_array_equal(fixed_X, X)
    np.testing.assert_array_equal(fixed_poses, poses)
    blind = X.copy()
    blind[:, [0, 17, 18, 20, 21], 3] = 0  # no nose, no toes: no facing, nothing changed
    np.testing.assert_array_equal(facing_directions(blind), 0.0)
