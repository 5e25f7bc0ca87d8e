"""Left / right labels made consistent across views and with the body (reconstruction/solver/side_labels.py):
the fundamental matrix against the matcher's, random per-view labels of a synthetic body restored to the
majority's, consistent labels left bit-identical, a limb pair the wrong way round exchanged."""

from __future__ import annotations

import numpy as np

from data.geometry.triangulation import triangulate_dlt
from data.keypoints import FLIP_PAIRS
from data.synthetic.body import mean_body, pose_joints
from reconstruction.matching.epipolar import fundamental_matrix
from reconstruction.solver.side_labels import (
    chain_sides,
    consistent_sides,
    epipolar_distance,
    fundamental_from_projections,
)
from tests.test_triangulation import observe, ring


def bodies(n: int = 3) -> np.ndarray:
    """(n, 23, 3) standing synthetic bodies 1.5 m apart, facing different ways."""
    return np.stack(
        [pose_joints(mean_body(), 1.5 * i - 1.5, 0.3 * i, 0.9 * i, phase=0.7 * i, walking=True) for i in range(n)]
    )


def test_fundamental_matrix_from_projections_equals_the_cameras_one():
    rig = ring(4)
    proj = rig.projection_matrices()
    F = fundamental_from_projections(proj[0], proj[2])
    G = fundamental_matrix(rig[0], rig[2])
    assert min(np.abs(F - G).max(), np.abs(F + G).max()) < 1e-9
    uv = observe(rig, bodies())[..., :2]
    assert epipolar_distance(uv[0], uv[2], F).max() < 1e-6  # the same point seen twice lies on its line
    assert epipolar_distance(uv[0][:, [5]], uv[2][:, [6]], F).min() > 1.0  # left shoulder vs right: not


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
