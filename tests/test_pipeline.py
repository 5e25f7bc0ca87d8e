import json

import numpy as np
import pytest

from data.assignment import assignment_from_labels
from data.formats.poses_io import read_poses3d, write_poses3d
from data.multiview import Frame, ViewDetections
from reconstruction.matching import OracleMatcher
from reconstruction.pipeline import MultiViewPipeline, gather_views
from reconstruction.reconstructors import VanillaTriangulation
from tests.test_triangulation import ring


def test_assignment_from_labels_groups_and_drops_single_view_people():
    labels = [np.array([4, 7, -1]), np.array([7, 2]), np.array([2, 4, 9])]
    a = assignment_from_labels(labels)
    np.testing.assert_array_equal(a, [[-1, 1, 0], [0, -1, 1], [1, 0, -1]])  # persons 2, 4, 7; 9 dropped
    with pytest.raises(ValueError, match="twice"):
        assignment_from_labels([np.array([1, 1])])


def test_gather_views_fills_missing_views_with_zero_scores():
    kps = [np.full((2, 23, 3), v + 1.0) for v in range(2)]
    views = [ViewDetections(k, np.ones((2, 4)), np.ones(2), np.arange(2)) for k in kps]
    poses2d, boxes = gather_views(views, np.array([[1, -1], [0, 0]]))
    assert poses2d.shape == (2, 2, 23, 3)
    assert np.all(poses2d[1, 0] == 0) and np.all(poses2d[0, 0] == 1) and np.all(poses2d[1, 1] == 2)
    assert np.all(boxes[1, 0] == 0)


def test_oracle_pipeline_reconstructs_shuffled_noise_free_detections():
    rig = ring(4)
    rng = np.random.default_rng(0)
    X = rng.uniform([-2, -2, 0], [2, 2, 1.8], (3, 23, 3))
    views = []
    for v in range(4):
        order = rng.permutation(3)
        uv = rig[v].project(X[order])
        views.append(ViewDetections(np.concatenate([uv, np.ones((3, 23, 1))], -1), np.ones((3, 4)), np.ones(3), order))
    result = MultiViewPipeline(rig, OracleMatcher(), VanillaTriangulation())(Frame(0, views))
    np.testing.assert_allclose(result.poses3d[..., :3], X, atol=1e-6)
    with pytest.raises(ValueError, match="ground-truth identities"):
        OracleMatcher()([ViewDetections(v.keypoints, v.bboxes, v.scores, -np.ones(3)) for v in views], rig).assignment


def test_poses3d_json_round_trip(tmp_path):
    poses = np.random.default_rng(0).uniform(-1, 1, (2, 23, 4)).round(6)
    poses[..., 3] = np.abs(poses[..., 3])
    poses[0, 5] = 0
    write_poses3d(tmp_path / "p.json", [(300, poses, np.array([[0, -1], [1, 2]]))], ["a", "b"])
    doc = json.loads((tmp_path / "p.json").read_text())
    assert doc["units"] == "m" and doc["frames"][0]["poses"][1]["views"] == {"a": 1, "b": 2}
    np.testing.assert_allclose(read_poses3d(tmp_path / "p.json")[300], poses, atol=1e-6)
    assert not list(tmp_path.glob(".*tmp"))


def test_default_pipeline_with_tracking_runs_frames_without_any_person():
    """A frame with no detection (a camera image with nobody in it) before and after a frame with people."""
    from hydra import compose, initialize

    from data.synthetic import SyntheticConfig, generate_sequence

    sequence = generate_sequence(SyntheticConfig(num_frames=2, num_persons=3))
    with initialize(config_path="../configs", version_base="1.3"):
        cfg = compose("eval", overrides=["tracking=on"])
    pipeline = MultiViewPipeline.from_config(cfg, sequence.rig)
    empty = Frame(0, [ViewDetections.empty() for _ in sequence.rig])
    assert len(pipeline(empty).poses3d) == 0
    people = pipeline(Frame(1, sequence.frames[1].views))
    assert len(people.poses3d) == 3 and len(people.ids) == 3
    assert len(pipeline(Frame(2, [ViewDetections.empty() for _ in sequence.rig])).poses3d) == 0


def test_gather_views_equals_a_per_view_numpy_gather_with_detector_nans():
    """The compiled gather against numpy's fancy indexing, view by view: non-finite joints and box entries zeroed."""
    rng = np.random.default_rng(4)
    views = []
    for n in (5, 0, 3):
        kp, boxes = rng.uniform(0, 500, (n, 23, 3)), rng.uniform(0, 90, (n, 4))
        kp[rng.random(kp.shape) < 0.05] = np.nan
        kp[rng.random(kp.shape) < 0.02] = np.inf
        boxes[rng.random(boxes.shape) < 0.2] = -np.inf
        views.append(ViewDetections(kp, boxes, np.ones(n), -np.ones(n, dtype=np.int64)))
    assignment = np.array([[0, -1, 2], [4, -1, -1], [-1, -1, 0], [2, -1, 1]])
    poses2d, bboxes = gather_views(views, assignment)
    want, want_boxes = np.zeros((3, 4, 23, 3)), np.zeros((3, 4, 4))
    for v, dets in enumerate(views):
        have = assignment[:, v] >= 0
        want[v, have] = dets.keypoints[assignment[have, v]]
        want_boxes[v, have] = dets.bboxes[assignment[have, v]]
    want = np.where(np.isfinite(want).all(axis=-1, keepdims=True), want, 0.0)
    np.testing.assert_array_equal(poses2d, want)
    np.testing.assert_array_equal(bboxes, np.nan_to_num(want_boxes, nan=0.0, posinf=0.0, neginf=0.0))
    assert (poses2d[..., 2] > 0).sum() < (want_boxes[..., :1] != 0).sum() * 23  # some joints were zeroed
