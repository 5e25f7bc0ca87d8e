"""The Shelf oracle bound (benchmarks/shelf_bound.py): exact views give the truth; the oracle never loses."""

from __future__ import annotations

import numpy as np

from benchmarks.shelf_bound import nearest_detections, oracle_pose, subset_poses
from data.keypoints import coco23_to_shelf14, with_mid_hip
from data.multiview import ViewDetections
from data.synthetic.body import mean_body, pose_joints
from data.synthetic.rigs import ring_rig


def _scene(views: int = 4):
    rig = ring_rig(views, 7.0, 2.5, look_at=(0.0, 0.0, 1.0))
    X = pose_joints(mean_body(), 0.3, -0.2, 0.7)
    uv = rig.project(X)
    keypoints = np.concatenate([uv, np.full(uv.shape[:-1] + (1,), 0.9)], axis=-1)
    return rig, X, keypoints


def test_every_view_subset_of_exact_detections_triangulates_the_truth():
    rig, X, keypoints = _scene(4)
    poses = subset_poses(keypoints, rig)
    assert poses.shape == (11, 15, 3)  # C(4,2) + C(4,3) + C(4,4) subsets
    np.testing.assert_allclose(poses, np.broadcast_to(with_mid_hip(coco23_to_shelf14(X)), poses.shape), atol=1e-6)


def test_a_view_without_detection_is_left_out_of_the_subsets():
    rig, _, keypoints = _scene(4)
    keypoints[1] = 0.0
    assert len(subset_poses(keypoints, rig)) == 4  # C(3,2) + C(3,3)


def test_oracle_keeps_the_nearest_candidate_per_joint_and_is_never_worse():
    rng = np.random.default_rng(0)
    gt = rng.normal(size=(15, 3))
    own = gt + rng.normal(0, 0.3, (15, 3))
    candidates = gt[None] + rng.normal(0, 0.3, (6, 15, 3))
    out = oracle_pose(own, candidates, gt)
    err_own, err_out = (np.linalg.norm(p - gt, axis=-1) for p in (own, out))
    assert np.all(err_out[:12] <= err_own[:12] + 1e-12)
    nearest = np.min(np.linalg.norm(np.concatenate([own[None], candidates]) - gt, axis=-1), axis=0)
    np.testing.assert_allclose(err_out[:12], nearest[:12])
    np.testing.assert_allclose(out[14], (out[2] + out[3]) / 2)


def test_nearest_detection_is_the_one_on_the_projected_truth():
    rig, X, keypoints = _scene(3)
    gt = with_mid_hip(coco23_to_shelf14(X))
    decoy = keypoints.copy()
    decoy[..., :2] += 200.0
    views = [
        ViewDetections(np.stack([decoy[v], keypoints[v]]), np.zeros((2, 4)), np.ones(2), -np.ones(2)) for v in range(3)
    ]
    chosen = nearest_detections(views, rig, gt, max_px=40.0)
    np.testing.assert_allclose(chosen, keypoints)
    assert not nearest_detections(
        [ViewDetections(decoy[v][None], np.zeros((1, 4)), np.ones(1), -np.ones(1)) for v in range(3)], rig, gt, 40.0
    ).any()
